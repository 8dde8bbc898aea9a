"""Videos, frame folders, images and masks.

Arrays are RGB(A) ``uint8`` with shape (H, W, 3) per frame, (T, H, W, 3) per
video; sizes are given as (W, H). Video files are decoded by the ffmpeg
binary that imageio-ffmpeg ships (it honours rotation metadata), GIFs by
Pillow, images by OpenCV. Every writer is atomic: on error or Ctrl-C nothing
is left at the output path and an existing file there is kept intact.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import operator
import re
import subprocess
import tempfile
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
from PIL import Image, ImageSequence

from ..errors import InputError
from .atomic import atomic_folder, atomic_path

__all__ = ["Video", "VideoFrames", "PackedMasks", "open_video", "read_video", "read_masks", "read_mask", "read_image",
           "write_masks", "MASK_FRAME_NAME",
           "write_video", "write_image"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".flv", ".gif")
#: Most pixels of all frames together (T x H x W) of a video opened by
#: :func:`open_video`; more are downscaled. What extraction keeps grows with it
#: (masks, tracks): 2**29 is 1036 frames of 960 x 540, 1310 of 854 x 480, and
#: keeps ``marionette extract`` within 2 GB (docs/benchmarks/memory.md).
DEFAULT_MAX_PIXELS = 2**29
#: Long side above which source frames are downscaled (intrinsics follow).
DEFAULT_MAX_SIDE = 960
#: Shortest frame side :func:`open_video` downscales to.
_MIN_SIDE = 16
#: Most pixels of one image :func:`read_image` decodes (a guard against
#: decompression bombs: an RGBA image of this size takes 512 MiB).
MAX_IMAGE_PIXELS = 2**27
#: Frame rate of a folder of frames when none is given.
DEFAULT_FOLDER_FPS = 30.0
#: Frame rate of a GIF whose frames carry no delay (what browsers show).
_DEFAULT_GIF_FPS = 10.0
#: Colours of the palette all frames of a GIF we write share.
_GIF_COLOURS = 128
#: H.264 constant rate factor: visually lossless for our renders, small files.
_MP4_CRF = 18
#: Log lines that explain an ffmpeg failure, most specific first.
_FFMPEG_REASONS = (r"partial file|moov atom not found", r"Invalid data found", r"No such file|Permission denied",
                   r"[Ee]rror")
#: Names of the frames written to a folder, e.g. ``00012.png``.
_FRAME_NAME = re.compile(r"\d{5,}\.png")


@dataclass(frozen=True)
class Video:
    """Frames of a video or a folder of frames.

    Attributes
    ----------
    frames : (T, H, W, 3) uint8 ndarray, or VideoFrames
        RGB frames, T >= 2: decoded (:func:`read_video`) or decoded on
        demand (:func:`open_video`).
    fps : float
        Frame rate.
    scale : float
        Downscale factor applied to the original frames (1.0 if none): the
        original size is about ``(W, H) / scale``.
    names : list[str]
        T frame names: file names for a folder, indices ``"0", "1", …`` for a file.
    indices : list[int]
        T frame numbers in the source (they differ from ``0 … T-1`` when a
        frame range or stride was selected).
    """

    frames: np.ndarray | VideoFrames
    fps: float
    scale: float
    names: list[str]
    indices: list[int] | None = None

    def __post_init__(self) -> None:
        if self.indices is None:
            object.__setattr__(self, "indices", list(range(self.frames.shape[0])))

    def __len__(self) -> int:
        return self.frames.shape[0]

    @property
    def size(self) -> tuple[int, int]:
        """Frame size (W, H)."""
        return self.frames.shape[2], self.frames.shape[1]


class VideoFrames:
    """The frames of a video, decoded on demand: a read-only (T, H, W, 3) uint8 sequence.

    ``frames[t]`` decodes frame t (resized to the video's size); a pass in
    order decodes each frame once, and asking for a frame before the last one
    opens the source again. Only the last frame is kept. ``np.asarray(frames)``
    decodes them all. Made by :func:`open_video`.
    """

    dtype = np.dtype(np.uint8)
    ndim = 4

    def __init__(self, open_stream: Callable[[], Iterator[np.ndarray]], count: int, size: tuple[int, int]) -> None:
        self._open = open_stream
        self.shape = (count, size[1], size[0], 3)
        self._stream: Iterator[np.ndarray] | None = None
        self._next = 0  # frame number the stream yields next
        self._last: tuple[int, np.ndarray | None] = (-1, None)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, t: int) -> np.ndarray:
        """Frame ``t`` (H, W, 3) uint8; negative indices count from the end."""
        count = self.shape[0]
        t = operator.index(t)
        t = t + count if t < 0 else t
        if not 0 <= t < count:
            raise IndexError(f"frame {t} out of range for a video of {count} frames")
        if t == self._last[0]:
            return self._last[1]
        if self._stream is None or t < self._next:
            self.close()
            self._stream, self._next = self._open(), 0
        for _ in range(t - self._next):
            next(self._stream)
        frame = next(self._stream)
        self._next = t + 1
        h, w = self.shape[1:3]
        if frame.shape[:2] != (h, w):
            frame = cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA)
        frame.flags.writeable = False  # the same array is handed out again for the same t
        self._last = (t, frame)
        return frame

    def __iter__(self) -> Iterator[np.ndarray]:
        return (self[t] for t in range(len(self)))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        frames = np.stack(list(self))
        return frames if dtype is None else frames.astype(dtype)

    def close(self) -> None:
        """Stop the decoder (it is opened again when a frame is asked for)."""
        if self._stream is not None:
            self._stream.close()
        self._stream, self._next, self._last = None, 0, (-1, None)


def check_frames(frames: np.ndarray | VideoFrames, *, min_frames: int = 1, min_side: int = 8) -> None:
    """Raise InputError unless ``frames`` is (T, H, W, 3) uint8 (an array or VideoFrames) with
    T >= ``min_frames`` and H, W >= ``min_side``."""
    if not isinstance(frames, (np.ndarray, VideoFrames)) or frames.ndim != 4 or frames.shape[3] != 3:
        raise InputError(f"frames must be an array (T, H, W, 3), got shape {np.shape(frames)}")
    if frames.dtype != np.uint8:
        raise InputError(f"frames must be uint8, got {frames.dtype}")
    if frames.shape[0] < min_frames or min(frames.shape[1:3]) < min_side:
        count = "one frame" if min_frames == 1 else f"{min_frames} frames"
        raise InputError(f"frames must hold at least {count} of at least {min_side}x{min_side} pixels, "
                         f"got shape {frames.shape}")


class PackedMasks:
    """(T, H, W) bool masks stored as packed bits, an eighth of a bool array; frames unpack on demand.

    ``masks[t]`` is a fresh (H, W) bool array; ``masks[t] = mask`` stores one;
    ``np.asarray(masks)`` unpacks all.
    """

    dtype = np.dtype(bool)
    ndim = 3

    def __init__(self, count: int, height: int, width: int) -> None:
        self.shape = (count, height, width)
        self._bits = np.zeros((count, -(-height * width // 8)), np.uint8)

    @classmethod
    def from_array(cls, masks: np.ndarray) -> PackedMasks:
        """Pack (T, H, W) masks (non-zero = object)."""
        out = cls(*masks.shape)
        for t, mask in enumerate(masks):
            out[t] = mask
        return out

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, t: int) -> np.ndarray:
        h, w = self.shape[1:]
        return np.unpackbits(self._bits[t], count=h * w).view(bool).reshape(h, w)

    def __setitem__(self, t: int, mask: np.ndarray) -> None:
        if np.shape(mask) != self.shape[1:]:
            raise ValueError(f"mask of shape {self.shape[1:]} expected, got {np.shape(mask)}")
        self._bits[t] = np.packbits(np.asarray(mask, dtype=bool).ravel())

    def __iter__(self) -> Iterator[np.ndarray]:
        return (self[t] for t in range(len(self)))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        h, w = self.shape[1:]
        masks = np.unpackbits(self._bits, axis=1, count=h * w).view(bool).reshape(self.shape)
        return masks if dtype is None else masks.astype(dtype)

    def any(self) -> bool:
        """Whether any mask has an object pixel."""
        return bool(self._bits.any())


# ---------------------------------------------------------------- reading


def read_video(source: str | Path, *, max_side: int | None = None, fps: float | None = None,
               start: int = 0, end: int | None = None, stride: int = 1) -> Video:
    """Read a video file (mp4, mov, avi, mkv, webm, gif …) or a folder of frames.

    A folder holds one image per frame (png, jpg, jpeg, bmp, tif), taken in
    natural name order (``2.png`` before ``10.png``). Frames ``start, start +
    stride, …`` before ``end`` (exclusive; None: to the end) are kept; the
    frame rate is divided by ``stride``. Frames whose long side exceeds
    ``max_side`` are downscaled (``cv2.INTER_AREA``) to a long side of
    ``max_side``. ``fps`` overrides the frame rate: the file's own rate, or
    30 for a folder. Raises :class:`InputError` for anything unreadable.
    All frames are decoded into memory; :func:`open_video` decodes them on demand.
    """
    source, stream, rate = _open_source(source, max_side, fps, start, end, stride)
    frames, names, indices, target, scale = [], [], [], None, 1.0
    for index, name, frame in _same_size(source, stream()):
        if target is None:
            target, scale = _target_size(frame.shape[1], frame.shape[0], max_side)
        frames.append(frame if frame.shape[1::-1] == target else
                      cv2.resize(frame, target, interpolation=cv2.INTER_AREA))
        names.append(name)
        indices.append(index)
    _check_count(source, len(frames), (start, end, stride))
    return Video(frames=np.stack(frames), fps=rate, scale=scale, names=names, indices=indices)


def open_video(source: str | Path, *, max_side: int | None = None, max_pixels: int | None = DEFAULT_MAX_PIXELS,
               fps: float | None = None, start: int = 0, end: int | None = None, stride: int = 1) -> Video:
    """Open a video like :func:`read_video`, with frames decoded on demand (:class:`VideoFrames`).

    One pass decodes the selected frames to count and check them, keeping
    none. ``max_pixels`` bounds the pixels of all frames together (T x H x W,
    after ``max_side``): a longer or larger video is downscaled further so
    that it fits, with a warning (what is kept per pixel downstream, masks
    and tracks, then stays bounded). None: no bound.

    Warns
    -----
    UserWarning
        When the video is downscaled to fit ``max_pixels``.
    """
    if max_pixels is not None and (isinstance(max_pixels, bool) or not isinstance(max_pixels, (int, np.integer))
                                   or max_pixels < 1):
        raise InputError(f"max_pixels must be a positive integer, got {max_pixels!r}")
    source, stream, rate = _open_source(source, max_side, fps, start, end, stride)
    names, indices, size = [], [], None
    for index, name, frame in _same_size(source, stream()):
        size = size or frame.shape[1::-1]
        names.append(name)
        indices.append(index)
    _check_count(source, len(names), (start, end, stride))
    count, (width, height) = len(names), size
    target, scale = _target_size(width, height, max_side)
    if max_pixels is not None and count * target[0] * target[1] > max_pixels:
        side = math.floor(max(width, height) * math.sqrt(max_pixels / (count * width * height)))
        while side > 1 and count * math.prod(_scaled_size(width, height, side)) > max_pixels:
            side -= 1  # the short side was rounded up
        smaller, scale = _target_size(width, height, max(side, 1))
        if min(smaller) < _MIN_SIDE:
            raise InputError(f"{source}: {count} frames do not fit max_pixels={max_pixels} even at "
                             f"{smaller[0]}x{smaller[1]}; select fewer frames (start, end, stride)")
        warnings.warn(f"{source}: {count} frames of {target[0]}x{target[1]} exceed the limit of {max_pixels} "
                      f"pixels in all; downscaled to {smaller[0]}x{smaller[1]}", stacklevel=2)
        target = smaller
    frames = VideoFrames(lambda: _frames_of(stream()), count, target)
    return Video(frames=frames, fps=rate, scale=scale, names=names, indices=indices)


def _frames_of(stream: Iterator[tuple[int, str, np.ndarray]]) -> Iterator[np.ndarray]:
    """The frames of a pass, closing the pass when closed."""
    with contextlib.closing(stream):
        for _, _, frame in stream:
            yield frame


def _open_source(source: str | Path, max_side: int | None, fps: float | None, start: int, end: int | None,
                 stride: int) -> tuple[Path, Callable[[], Iterator[tuple[int, str, np.ndarray]]], float]:
    """Check a video's arguments → (path, a function opening a pass over its selected frames, frame rate).

    A pass yields ``(frame number in the source, name, (H, W, 3) uint8 frame)``.
    """
    source = Path(source)
    if max_side is not None and (not isinstance(max_side, (int, np.integer)) or max_side < 1):
        raise InputError(f"max_side must be a positive integer, got {max_side!r}")
    selection = _frame_selection(start, end, stride)
    if fps is not None:
        fps = _check_fps(fps)
    if not source.exists():
        raise InputError(f"{source} does not exist")

    if source.is_dir():
        files = _image_files(source)
        if not files:
            raise InputError(f"{source} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        indices = list(range(len(files)))[selection]

        def stream() -> Iterator[tuple[int, str, np.ndarray]]:
            return ((i, files[i].name, read_image(files[i])[..., :3]) for i in indices)  # alpha, if any, is dropped

        native_fps = DEFAULT_FOLDER_FPS
    elif source.suffix.lower() in VIDEO_SUFFIXES:
        frames_of = _gif_frames if source.suffix.lower() == ".gif" else _ffmpeg_frames
        first, native_fps = frames_of(source)

        def stream() -> Iterator[tuple[int, str, np.ndarray]]:
            nonlocal first
            frames, first = first or frames_of(source)[0], None  # the reader opened to check the file comes first
            with contextlib.closing(frames):  # a pass stopped early still stops its decoder
                for name, frame in itertools.islice(frames, selection.start, selection.stop, selection.step):
                    yield int(name), name, frame
    else:
        raise InputError(f"{source}: unsupported video format '{source.suffix}' "
                         f"(use {', '.join(VIDEO_SUFFIXES)} or a folder of frames)")
    return source, stream, float(fps or native_fps / selection.step)


def _same_size(source: Path, stream: Iterator[tuple[int, str, np.ndarray]]) -> Iterator[tuple[int, str, np.ndarray]]:
    """Pass the frames of ``stream`` on, raising InputError when one differs in size from the first."""
    first = None
    for index, name, frame in stream:
        h, w = frame.shape[:2]
        if first is None:
            first = (w, h, name)
        elif (w, h) != first[:2]:
            raise InputError(f"{source}: frame {name} is {w}x{h} but frame {first[2]} is {first[0]}x{first[1]}")
        yield index, name, frame


def _target_size(width: int, height: int, max_side: int | None) -> tuple[tuple[int, int], float]:
    """Size (W, H) of frames of ``width`` x ``height`` brought to a long side of at most ``max_side``, and the scale."""
    if max_side is None or max(width, height) <= max_side:
        return (width, height), 1.0
    return _scaled_size(width, height, max_side), max_side / max(width, height)


def _check_count(source: Path, count: int, selection: tuple[int, int | None, int]) -> None:
    if count < 2:
        chosen = "" if selection == (0, None, 1) else " in the selected range"
        raise InputError(f"{source} has {count} frame(s){chosen}; a video needs at least 2")


def _frame_selection(start: int, end: int | None, stride: int) -> slice:
    """Check a frame range; the slice of frame numbers it selects."""
    for name, value, low in (("start", start, 0), ("stride", stride, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise InputError(f"{name} must be an integer >= {low}, got {value!r}")
    if end is not None and (isinstance(end, bool) or not isinstance(end, (int, np.integer)) or end <= start):
        raise InputError(f"end must be an integer > start ({start}), got {end!r}")
    return slice(int(start), None if end is None else int(end), int(stride))


def read_masks(folder: str | Path, *, count: int, size: tuple[int, int],
               indices: list[int] | None = None, packed: bool = False) -> np.ndarray | PackedMasks:
    """Read ``count`` per-frame object masks of ``size`` (W, H) → (T, H, W) bool.

    One image per frame in natural name order; a pixel is object where any
    colour channel is non-zero (JPEG: above 127, to ignore compression noise;
    RGBA: the alpha channel when it is not uniform). Masks at the original
    resolution of a downscaled video are resized (nearest neighbour). When
    the video was read with a frame range (``indices``: its frame numbers,
    :attr:`Video.indices`), a folder with a mask for every source frame is
    sampled the same way; one with exactly ``count`` masks is taken as it is.
    ``packed``: return :class:`PackedMasks` (an eighth of the memory).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"mask folder {folder} does not exist" if not folder.exists()
                         else f"masks must be a folder of images, got the file {folder}")
    files = _image_files(folder)
    if indices is not None and len(files) != count and len(files) > max(indices):
        files = [files[i] for i in indices]
    if len(files) != count:
        raise InputError(f"{folder} holds {len(files)} masks but the video has {count} frames")
    width, height = size
    masks = PackedMasks(count, height, width) if packed else np.empty((count, height, width), dtype=bool)
    for t, file in enumerate(files):
        mask = _mask_from_image(read_image(file), lossy=file.suffix.lower() in (".jpg", ".jpeg"))
        h0, w0 = mask.shape
        if (w0, h0) != (width, height):
            if _scaled_size(w0, h0, max(width, height)) != (width, height):
                raise InputError(f"mask {file.name} is {w0}x{h0} but the frames are {width}x{height}")
            mask = cv2.resize(mask.view(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST) > 0
        masks[t] = mask
    if not masks.any():
        raise InputError(f"all masks in {folder} are empty")
    if not masks[0].any():
        raise InputError(f"mask of frame 0 is empty ({files[0].name})")
    return masks


def read_image(path: str | Path) -> np.ndarray:
    """Read an image → (H, W, 3) RGB or (H, W, 4) RGBA uint8.

    Greyscale becomes RGB; 16-bit and float images are converted to 8 bits
    (floats are taken as [0, 1]). JPEG orientation metadata is applied.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise InputError(f"{path}: unsupported image format '{path.suffix}' (use {', '.join(IMAGE_SUFFIXES)})")
    if path.stat().st_size > 8 * MAX_IMAGE_PIXELS:  # more than 16-bit RGBA of the largest image uncompressed
        raise InputError(f"image {path} is larger than {8 * MAX_IMAGE_PIXELS >> 20} MiB")
    _check_pixel_count(path)
    # JPEGs have neither alpha nor 16 bits; IMREAD_COLOR applies their EXIF orientation
    flags = cv2.IMREAD_COLOR if suffix in (".jpg", ".jpeg") else cv2.IMREAD_UNCHANGED
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # its log on a corrupt file is ours to give
    try:
        image = cv2.imdecode(np.fromfile(path, dtype=np.uint8), flags)
    except cv2.error:
        image = None
    except OSError as exc:
        raise InputError(f"cannot read image {path}: {exc.strerror}") from None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise InputError(f"cannot read image {path} (corrupt or not a {suffix[1:].upper()} file)")

    if image.dtype == np.uint16:
        image = ((image.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    elif image.dtype.kind == "f":
        image = _float_to_uint8(image, f"image {path}")
    elif image.dtype != np.uint8:
        raise InputError(f"{path}: unsupported pixel type {image.dtype}")
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    if image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA)
    raise InputError(f"{path}: unsupported number of channels {image.shape[2]}")


def _check_pixel_count(path: Path) -> None:
    """Refuse an image whose header declares more than :data:`MAX_IMAGE_PIXELS`, before decoding it."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with open(path, "rb") as handle, Image.open(handle) as image:  # closed even when a read fails
                width, height = image.size
    except Image.DecompressionBombError as exc:  # beyond Pillow's own limit, so beyond ours
        raise InputError(f"image {path} is too large: {_one_line(exc)}") from None
    except Exception:  # Pillow raises many types on files it cannot parse; OpenCV then tries and reports
        return
    if width * height > MAX_IMAGE_PIXELS:
        raise InputError(f"image {path} is {width}x{height}, more than the limit of {MAX_IMAGE_PIXELS} pixels; "
                         "downscale it first")


def _image_files(folder: Path) -> list[Path]:
    """Image files of a folder in natural name order; hidden files (``._x.png``) skipped."""
    files = [f for f in folder.iterdir()
             if f.suffix.lower() in IMAGE_SUFFIXES and not f.name.startswith(".") and f.is_file()]
    return sorted(files, key=lambda f: (_natural_key(f.name), f.name))


def _natural_key(name: str) -> list:
    """Sort key that orders digit runs by value: ``2.png`` < ``10.png``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def read_mask(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """One mask image → (H, W) bool (rules of :func:`read_masks`), resized to ``size`` (W, H) if given."""
    path = Path(path)
    mask = _mask_from_image(read_image(path), lossy=path.suffix.lower() in (".jpg", ".jpeg"))
    if size is not None and (mask.shape[1], mask.shape[0]) != tuple(size):
        mask = cv2.resize(mask.view(np.uint8), tuple(size), interpolation=cv2.INTER_NEAREST) > 0
    if not mask.any():
        raise InputError(f"mask {path.name} is empty")
    return mask


def _mask_from_image(image: np.ndarray, *, lossy: bool) -> np.ndarray:
    """(H, W, 3|4) uint8 → (H, W) bool object mask."""
    alpha = image[..., 3] if image.shape[2] == 4 else None
    if alpha is not None and alpha.min() != alpha.max():
        values = alpha  # a cut-out: transparency marks the background
    else:
        values = image[..., :3].max(axis=2)
    return values > (127 if lossy else 0)


def _scaled_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """Size (W, H) after scaling the long side to ``max_side`` (rule of :func:`read_video`)."""
    scale = max_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def _gif_frames(path: Path) -> tuple[Iterator[tuple[str, np.ndarray]], float]:
    """RGB frames of an animated GIF (Pillow composites disposal) and its frame rate."""
    try:
        image = Image.open(path)
        durations = [frame.info.get("duration", 0) for frame in ImageSequence.Iterator(image)]
    except Exception as exc:  # Pillow raises several types for corrupt files
        raise InputError(f"cannot read GIF {path}: {_one_line(exc)}") from exc
    positive = np.array([d for d in durations if d and d > 0], dtype=np.float64)  # ms
    # A rate that is no whole number of centiseconds alternates delays a centisecond apart (4 and 5 cs at
    # 24 fps): average those, but not the long delays of merged still frames.
    typical = positive[np.abs(positive - np.median(positive)) <= 10] if len(positive) else positive
    fps = 1000.0 / float(typical.mean()) if len(typical) else _DEFAULT_GIF_FPS

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        with image:
            try:
                for t, frame in enumerate(ImageSequence.Iterator(image)):
                    yield str(t), np.asarray(frame.convert("RGB"))
            except (OSError, ValueError, EOFError) as exc:
                raise InputError(f"cannot read GIF {path}: {_one_line(exc)}") from exc

    return frames(), fps


def _ffmpeg_frames(path: Path) -> tuple[Iterator[tuple[str, np.ndarray]], float]:
    """RGB frames of a video file decoded by ffmpeg, and its frame rate (0 → default)."""
    # passthrough: every decoded frame once, no duplicates for variable frame rates
    reader = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24", output_params=["-fps_mode", "passthrough"])
    logger = logging.getLogger("imageio_ffmpeg")
    level = logger.level
    logger.setLevel(logging.ERROR)  # it warns that rotated videos change size, which is expected
    try:
        meta = next(reader)
    except Exception as exc:  # OSError with ffmpeg's log, or a parse error on odd streams
        reader.close()
        _close_pipes(_ffmpeg_process(frame for frame, _ in traceback.walk_tb(exc.__traceback__)))
        raise InputError(f"cannot read video {path} (corrupt, truncated or unsupported): "
                         f"{_ffmpeg_reason(exc)}") from exc
    finally:
        logger.setLevel(level)
    width, height = meta["size"]
    fps = meta.get("fps") or 0.0
    fps = fps if math.isfinite(fps) and fps > 0 else DEFAULT_FOLDER_FPS
    # imageio-ffmpeg closes ffmpeg's stdin and stdout only when it stops a process still running; a video read
    # to its end left both pipes to the garbage collector (a ResourceWarning, two file descriptors per pass)
    process = _ffmpeg_process([reader.gi_frame])

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        try:
            for t, data in enumerate(reader):
                yield str(t), np.frombuffer(data, np.uint8).reshape(height, width, 3)
        except RuntimeError as exc:
            raise InputError(f"cannot read video {path}: {_ffmpeg_reason(exc)}") from exc
        finally:
            reader.close()
            _close_pipes(process)

    return frames(), fps


def _ffmpeg_process(frames: Iterable) -> subprocess.Popen | None:
    """The ffmpeg process held by one of these Python frames (imageio-ffmpeg's reader calls it ``process``)."""
    for frame in frames:
        process = frame.f_locals.get("process") if frame is not None else None
        if isinstance(process, subprocess.Popen):
            return process
    return None


def _close_pipes(process: subprocess.Popen | None) -> None:
    """Close a finished ffmpeg process's stdin and stdout, and reap it."""
    if not isinstance(process, subprocess.Popen):
        return
    for pipe in (process.stdin, process.stdout):
        if pipe is not None and not pipe.closed:
            pipe.close()
    try:
        process.wait(timeout=5)
    except subprocess.TimeoutExpired:  # imageio-ffmpeg has asked it to stop; it is killed rather than waited for
        process.kill()


def _ffmpeg_reason(exc: BaseException) -> str:
    """The most telling line of ffmpeg's log in an imageio-ffmpeg error, without ``[tag @ 0x…]``."""
    if not isinstance(exc, (OSError, RuntimeError)) or "does not contain any stream" in str(exc):
        return "no video stream found"  # an audio-only file, or a header imageio-ffmpeg cannot parse
    lines = [re.sub(r"^(\[[^\]]*\]\s*)+", "", line.strip()) for line in str(exc).splitlines()]
    lines = [line for line in lines if line and "===" not in line]
    for pattern in _FFMPEG_REASONS:
        for line in lines:
            if re.search(pattern, line):
                return line
    return lines[-1] if lines else type(exc).__name__


# ---------------------------------------------------------------- writing


def write_video(path: str | Path, frames: Iterable[np.ndarray] | np.ndarray, fps: float) -> None:
    """Write frames (H, W, 3) uint8, or float in [0, 1], as a video, atomically.

    The format follows ``path``: ``.mp4`` is H.264 yuv420p (odd widths or
    heights are padded by one pixel, replicating the edge, since yuv420p
    needs even sizes); ``.gif`` loops forever, timed to the centisecond,
    on one palette (see :func:`_write_gif`; Pillow merges identical
    consecutive frames into one longer frame); no suffix, or an existing
    folder, gives a folder of ``00000.png, 00001.png, …``. Frames are
    streamed from ``frames`` (a GIF's frames are kept until the file is
    written; MP4 and PNG frames are not kept).
    """
    path = Path(path)
    fps = _check_fps(fps)
    suffix = path.suffix.lower()
    if path.is_dir() or not path.suffix:
        _write_frame_folder(path, _checked_frames(frames))
    elif suffix == ".mp4":
        with atomic_path(path) as tmp:
            _write_mp4(tmp, _checked_frames(frames), fps)
    elif suffix == ".gif":
        with atomic_path(path) as tmp:
            _write_gif(tmp, _checked_frames(frames), fps)
    else:
        raise InputError(f"{path}: unsupported video format '{path.suffix}' (use .mp4, .gif or a folder)")


#: Names of the per-frame files of :func:`write_masks` (a folder of only these may be replaced).
MASK_FRAME_NAME = r"\d{5,}\.png"


def write_masks(folder: str | Path, masks: np.ndarray | PackedMasks) -> None:
    """Write (T, H, W) bool masks as ``folder/00000.png`` … (0 / 255), the layout :func:`read_masks` reads.

    The folder appears complete or not at all (see :func:`~marionette.io.atomic.atomic_folder`).
    """
    with atomic_folder(folder, MASK_FRAME_NAME) as tmp:
        for t in range(len(masks)):
            (tmp / f"{t:05d}.png").write_bytes(_encode(np.asarray(masks[t], bool).astype(np.uint8) * 255, ".png"))


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image (H, W), (H, W, 3) RGB or (H, W, 4) RGBA as PNG or JPEG, atomically.

    ``image`` is uint8, bool, or float in [0, 1]. JPEG cannot hold alpha.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"{path}: unsupported image format '{path.suffix}' (use .png, .jpg or .jpeg)")
    image = _to_uint8(np.asarray(image), "image")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (3, 4))):
        raise InputError(f"image must have shape (H, W), (H, W, 3) or (H, W, 4), got {image.shape}")
    if image.ndim == 3 and image.shape[2] == 4 and suffix != ".png":
        raise InputError(f"{path}: JPEG cannot store an alpha channel; use .png")
    with atomic_path(path) as tmp:
        tmp.write_bytes(_encode(image, suffix))


def _encode(image: np.ndarray, suffix: str) -> bytes:
    """(H, W[, 3|4]) RGB(A) uint8 → PNG or JPEG bytes (OpenCV wants BGR(A))."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR if image.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if suffix in (".jpg", ".jpeg") else []
    ok, data = cv2.imencode(suffix, image, params)
    if not ok:
        raise OSError(f"OpenCV could not encode a {image.shape} image as {suffix}")
    return data.tobytes()


def _checked_frames(frames: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """Frames as contiguous (H, W, 3) uint8, all of the first frame's size; at least one."""
    shape = None
    for t, frame in enumerate(frames):
        frame = _to_uint8(np.asarray(frame), f"frame {t}")
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise InputError(f"frame {t} must have shape (H, W, 3), got {frame.shape}")
        if shape is None:
            shape = frame.shape
        elif frame.shape != shape:
            raise InputError(f"frame {t} has shape {frame.shape} but frame 0 has {shape}")
        yield np.ascontiguousarray(frame)
    if shape is None:
        raise InputError("no frames to write")


def _to_uint8(image: np.ndarray, what: str) -> np.ndarray:
    """uint8 as is, bool → 0/255, float in [0, 1] → rounded uint8."""
    if image.dtype == np.uint8:
        return image
    if image.dtype == bool:
        return image.astype(np.uint8) * 255
    if image.dtype.kind == "f":
        return _float_to_uint8(image, what)
    raise InputError(f"{what} must be uint8 or float in [0, 1], got {image.dtype}")


def _float_to_uint8(image: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(image)):
        raise InputError(f"{what} has NaN or infinite values")
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _write_mp4(path: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    """Encode frames with libx264 through the ffmpeg binary of imageio-ffmpeg."""
    first = next(frames)
    h, w = first.shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    rate = Fraction(fps).limit_denominator(1001)  # exact for 30000/1001 and the like
    cmd = [
        imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error",
        "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w + w % 2}x{h + h % 2}", "-r", str(rate), "-i", "-",
        "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", str(_MP4_CRF),
        "-movflags", "+faststart", "-f", "mp4", str(path),
    ]
    with tempfile.TemporaryFile() as log:
        # own session: Ctrl-C reaches only us, and we stop ffmpeg ourselves
        process = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log,
                                   start_new_session=True)
        try:
            for frame in itertools.chain([first], frames):
                try:
                    process.stdin.write(np.pad(frame, pad, mode="edge").data if any(pad[0] + pad[1])
                                        else frame.data)
                except BrokenPipeError:
                    break  # ffmpeg stopped; its log says why
            with contextlib.suppress(BrokenPipeError):
                process.stdin.close()
            code = process.wait()
        except BaseException:
            process.kill()
            with contextlib.suppress(OSError):  # what is left in the buffer has nowhere to go
                process.stdin.close()
            process.wait()
            raise
        if code != 0:
            log.seek(0)
            reason = log.read().decode(errors="replace").strip().splitlines() or [f"exit code {code}"]
            raise OSError(f"ffmpeg could not write {path}: {reason[-1]}")


def _gif_timing(count: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Which of ``count`` frames at ``fps`` a GIF shows, (K,) indices, and their delays, (K,) centiseconds.

    GIF delays are whole centiseconds, so frame ``i`` starts at
    ``round(100 i / fps)`` cs and the delays alternate where ``100 / fps`` is
    no whole number (4 and 5 cs at 24 fps): the clip lasts as long as it
    should. Browsers show delays under 2 cs as 10 cs, so above 50 fps the
    frames that would start less than 2 cs after the previous one are left out.
    """
    starts = np.rint(100.0 * np.arange(count + 1) / fps).astype(np.int64)  # (count+1,): the last is the end
    keep = [0]
    for i in range(1, count):
        if starts[i] - starts[keep[-1]] >= 2:
            keep.append(i)
    keep = np.array(keep)
    return keep, np.maximum(np.diff(np.append(starts[keep], starts[count])), 2)


def _write_gif(path: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    """Animated GIF looping forever, timed by :func:`_gif_timing`, on one palette.

    Every frame is mapped without dithering onto one palette of
    ``_GIF_COLOURS`` colours taken from frames spread over the clip, so still
    pixels keep their index from frame to frame and Pillow stores only the
    rectangle that changed (a quarter of the size of per-frame dithered
    palettes on a rendered turn, and twenty times faster).
    """
    frames = list(frames)
    keep, delays = _gif_timing(len(frames), fps)
    sample = np.linspace(0, len(frames) - 1, min(len(frames), 8)).round().astype(int)
    palette = Image.fromarray(np.concatenate([frames[i] for i in sample])).quantize(
        _GIF_COLOURS, method=Image.Quantize.MAXCOVERAGE, dither=Image.Dither.NONE)
    images = [Image.fromarray(frames[i]).quantize(palette=palette, dither=Image.Dither.NONE) for i in keep]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], loop=0,
                   duration=[10 * int(d) for d in delays])  # Pillow takes milliseconds


def _write_frame_folder(path: Path, frames: Iterator[np.ndarray]) -> None:
    """Write ``00000.png, …`` into a folder that appears complete or not at all.

    An existing folder at ``path`` is replaced only if it is empty or holds
    nothing but frames of this form (an earlier output).
    """
    with atomic_folder(path, _FRAME_NAME.pattern) as tmp:
        for t, frame in enumerate(frames):
            (tmp / f"{t:05d}.png").write_bytes(_encode(frame, ".png"))


def _check_fps(fps: float) -> float:
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise InputError(f"fps must be a positive number, got {fps!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    return value


def _one_line(exc: BaseException) -> str:
    """The first line of an exception's message, or its type name."""
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__
