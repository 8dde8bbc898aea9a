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
import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import imageio_ffmpeg
import numpy as np
from PIL import Image, ImageSequence

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["Video", "read_video", "read_masks", "read_mask", "read_image", "write_video", "write_image"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".flv", ".gif")
#: Frame rate of a folder of frames when none is given.
DEFAULT_FOLDER_FPS = 30.0
#: Frame rate of a GIF whose frames carry no delay (what browsers show).
_DEFAULT_GIF_FPS = 10.0
#: H.264 constant rate factor: visually lossless for our renders, small files.
_MP4_CRF = 18
#: Log lines that explain an ffmpeg failure, most specific first.
_FFMPEG_REASONS = (r"partial file|moov atom not found", r"Invalid data found", r"No such file|Permission denied",
                   r"[Ee]rror")
#: Names of the frames written to a folder, e.g. ``00012.png``.
_FRAME_NAME = re.compile(r"\d{5,}\.png")


@dataclass(frozen=True)
class Video:
    """Decoded frames of a video or a folder of frames.

    Attributes
    ----------
    frames : (T, H, W, 3) uint8
        RGB frames, T >= 2.
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

    frames: np.ndarray
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
        stream = ((files[i].name, read_image(files[i])[..., :3]) for i in indices)  # alpha, if any, is dropped
        native_fps = DEFAULT_FOLDER_FPS
    elif source.suffix.lower() in VIDEO_SUFFIXES:
        frames_of = _gif_frames if source.suffix.lower() == ".gif" else _ffmpeg_frames
        all_frames, native_fps = frames_of(source)
        stream = itertools.islice(all_frames, selection.start, selection.stop, selection.step)
    else:
        raise InputError(f"{source}: unsupported video format '{source.suffix}' "
                         f"(use {', '.join(VIDEO_SUFFIXES)} or a folder of frames)")

    frames, names, scale = _collect(source, stream, max_side)
    if len(frames) < 2:
        chosen = "" if (start, end, stride) == (0, None, 1) else " in the selected range"
        raise InputError(f"{source} has {len(frames)} frame(s){chosen}; a video needs at least 2")
    if source.is_dir():
        names_out = names
    else:
        indices = list(range(selection.start, selection.start + selection.step * len(frames), selection.step))
        names_out = [str(i) for i in indices]
    return Video(frames=np.stack(frames), fps=float(fps or native_fps / selection.step), scale=scale,
                 names=names_out, indices=indices[:len(frames)])


def _frame_selection(start: int, end: int | None, stride: int) -> slice:
    """Check a frame range; the slice of frame numbers it selects."""
    for name, value, low in (("start", start, 0), ("stride", stride, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise InputError(f"{name} must be an integer >= {low}, got {value!r}")
    if end is not None and (isinstance(end, bool) or not isinstance(end, (int, np.integer)) or end <= start):
        raise InputError(f"end must be an integer > start ({start}), got {end!r}")
    return slice(int(start), None if end is None else int(end), int(stride))


def read_masks(folder: str | Path, *, count: int, size: tuple[int, int],
               indices: list[int] | None = None) -> np.ndarray:
    """Read ``count`` per-frame object masks of ``size`` (W, H) → (T, H, W) bool.

    One image per frame in natural name order; a pixel is object where any
    colour channel is non-zero (JPEG: above 127, to ignore compression noise;
    RGBA: the alpha channel when it is not uniform). Masks at the original
    resolution of a downscaled video are resized (nearest neighbour). When
    the video was read with a frame range (``indices``: its frame numbers,
    :attr:`Video.indices`), a folder with a mask for every source frame is
    sampled the same way; one with exactly ``count`` masks is taken as it is.
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
    masks = np.empty((count, height, width), dtype=bool)
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
    # JPEGs have neither alpha nor 16 bits; IMREAD_COLOR applies their EXIF orientation
    flags = cv2.IMREAD_COLOR if suffix in (".jpg", ".jpeg") else cv2.IMREAD_UNCHANGED
    try:
        image = cv2.imdecode(np.fromfile(path, dtype=np.uint8), flags)
    except cv2.error:
        image = None
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


def _collect(source: Path, stream: Iterator[tuple[str, np.ndarray]],
             max_side: int | None) -> tuple[list[np.ndarray], list[str], float]:
    """Downscale and size-check frames as they arrive → (frames, names, scale)."""
    frames: list[np.ndarray] = []
    names: list[str] = []
    scale, first, target = 1.0, None, None
    for name, frame in stream:
        h, w = frame.shape[:2]
        if first is None:
            first, target = (w, h, name), (w, h)
            if max_side is not None and max(w, h) > max_side:
                scale, target = max_side / max(w, h), _scaled_size(w, h, max_side)
        elif (w, h) != first[:2]:
            raise InputError(f"{source}: frame {name} is {w}x{h} but frame {first[2]} is {first[0]}x{first[1]}")
        if (w, h) != target:
            frame = cv2.resize(frame, target, interpolation=cv2.INTER_AREA)
        frames.append(frame)
        names.append(name)
    return frames, names, scale


def _gif_frames(path: Path) -> tuple[Iterator[tuple[str, np.ndarray]], float]:
    """RGB frames of an animated GIF (Pillow composites disposal) and its frame rate."""
    try:
        image = Image.open(path)
        durations = [frame.info.get("duration", 0) for frame in ImageSequence.Iterator(image)]
    except Exception as exc:  # Pillow raises several types for corrupt files
        raise InputError(f"cannot read GIF {path}: {_one_line(exc)}") from exc
    positive = [d for d in durations if d and d > 0]
    fps = 1000.0 / float(np.median(positive)) if positive else _DEFAULT_GIF_FPS

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
        raise InputError(f"cannot read video {path} (corrupt, truncated or unsupported): "
                         f"{_ffmpeg_reason(exc)}") from exc
    finally:
        logger.setLevel(level)
    width, height = meta["size"]
    fps = meta.get("fps") or 0.0
    fps = fps if math.isfinite(fps) and fps > 0 else DEFAULT_FOLDER_FPS

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        try:
            for t, data in enumerate(reader):
                yield str(t), np.frombuffer(data, np.uint8).reshape(height, width, 3)
        except RuntimeError as exc:
            raise InputError(f"cannot read video {path}: {_ffmpeg_reason(exc)}") from exc
        finally:
            reader.close()

    return frames(), fps


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
    needs even sizes); ``.gif`` loops forever (Pillow merges identical
    consecutive frames into one longer frame); no suffix, or an existing
    folder, gives a folder of ``00000.png, 00001.png, …``. Frames are
    streamed from ``frames`` (Pillow keeps a GIF's palettised frames until
    it writes the file; MP4 and PNG frames are not kept).
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
            process.wait()
            raise
        if code != 0:
            log.seek(0)
            reason = log.read().decode(errors="replace").strip().splitlines() or [f"exit code {code}"]
            raise OSError(f"ffmpeg could not write {path}: {reason[-1]}")


def _write_gif(path: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    """Animated GIF looping forever; Pillow quantises each frame to 256 colours."""
    first = Image.fromarray(next(frames))
    rest = (Image.fromarray(frame) for frame in frames)
    # GIF delays are in 1/100 s, so the rate is rounded to the nearest centisecond delay
    first.save(path, format="GIF", save_all=True, append_images=rest, loop=0,
               duration=max(10, round(100.0 / fps) * 10))


def _write_frame_folder(path: Path, frames: Iterator[np.ndarray]) -> None:
    """Write ``00000.png, …`` into a temporary folder, then rename it onto ``path``.

    An existing folder at ``path`` is replaced only if it is empty or holds
    nothing but frames of this form (an earlier output).
    """
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError(f"output folder {parent} is not writable")
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} is a file; a folder of frames needs a new or existing folder path")
    if path.is_dir():
        others = sorted(f.name for f in path.iterdir() if not _FRAME_NAME.fullmatch(f.name))
        if others:
            raise InputError(f"output folder {path} is not empty (it holds {others[0]}); "
                             "give a new or empty folder")
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=parent))
    try:
        for t, frame in enumerate(frames):
            (tmp / f"{t:05d}.png").write_bytes(_encode(frame, ".png"))
        if path.is_dir():
            old = tmp.with_name(tmp.name + ".old")
            os.replace(path, old)
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old, path)
                raise
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


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
