"""Videos, frame folders, images and masks (marionette.io.video)."""

from __future__ import annotations

import gc
import re
import subprocess
import warnings

import cv2
import imageio_ffmpeg
import numpy as np
import pytest

from marionette.errors import InputError
from marionette.io import Video, read_image, read_masks, read_video, write_image, write_video
from marionette.io.video import open_video


def smooth_frames(t: int, h: int, w: int) -> np.ndarray:
    """(T, H, W, 3) uint8 slowly varying colour waves drifting over time."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    frames = [np.stack([128 + 90 * np.sin(x / 9 + i / 3), 128 + 90 * np.cos(y / 7 - i / 4),
                        128 + 70 * np.sin((x + y) / 13 + i / 5)], axis=-1) for i in range(t)]
    return np.rint(frames).astype(np.uint8)


def box_masks(t: int, h: int, w: int) -> np.ndarray:
    """(T, H, W) bool, a box moving right by one pixel per frame."""
    masks = np.zeros((t, h, w), bool)
    for i in range(t):
        masks[i, h // 4: h // 2, w // 8 + i: w // 2 + i] = True
    return masks


def write_masks(folder, masks: np.ndarray, suffix: str = ".png") -> None:
    folder.mkdir()
    for i, mask in enumerate(masks):
        write_image(folder / f"m{i}{suffix}", mask)


def ffmpeg_stream_info(path) -> str:
    """The ``Stream … Video: …`` line that ffmpeg prints for ``path``."""
    log = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                         capture_output=True, text=True).stderr
    return next(line for line in log.splitlines() if re.search(r"Stream .*Video:", line))


# ---------------------------------------------------------------- videos


def test_mp4_round_trip(tmp_path):
    frames = smooth_frames(10, 48, 64)
    write_video(tmp_path / "v.mp4", frames, 24)
    video = read_video(tmp_path / "v.mp4")
    assert isinstance(video, Video)
    assert video.frames.shape == frames.shape and video.frames.dtype == np.uint8
    assert video.fps == pytest.approx(24) and video.scale == 1.0
    assert video.names == [str(i) for i in range(10)] and video.size == (64, 48)
    # lossy H.264 with 4:2:0 chroma: a few levels of error on smooth content
    assert np.abs(video.frames.astype(int) - frames).mean() < 6


def test_mp4_is_h264_yuv420p_with_faststart(tmp_path):
    write_video(tmp_path / "v.mp4", smooth_frames(3, 32, 32), 30)
    info = ffmpeg_stream_info(tmp_path / "v.mp4")
    assert "Video: h264" in info and "yuv420p" in info
    data = (tmp_path / "v.mp4").read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")  # +faststart: index before the media data


def test_mp4_odd_size_is_padded_by_edge_replication(tmp_path):
    frames = smooth_frames(3, 33, 47)
    write_video(tmp_path / "v.mp4", frames, 30)
    video = read_video(tmp_path / "v.mp4")
    assert video.frames.shape == (3, 34, 48, 3)
    assert np.abs(video.frames[:, :33, :47].astype(int) - frames).mean() < 6
    assert np.abs(video.frames[:, 33, :47].astype(int) - frames[:, 32]).mean() < 8  # copy of the last row


def test_gif_round_trip(tmp_path):
    frames = smooth_frames(6, 40, 50)
    write_video(tmp_path / "v.gif", frames, 20)
    video = read_video(tmp_path / "v.gif")
    assert video.frames.shape == frames.shape
    assert video.fps == pytest.approx(20)  # 50 ms is a whole number of centiseconds
    # each frame is quantised to a 256-colour palette
    assert np.abs(video.frames.astype(int) - frames).mean() < 10


def test_png_folder_round_trip_is_exact(tmp_path):
    frames = smooth_frames(4, 20, 30)
    write_video(tmp_path / "frames", frames, 12)
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [f"{i:05d}.png" for i in range(4)]
    video = read_video(tmp_path / "frames", fps=12)
    np.testing.assert_array_equal(video.frames, frames)
    assert video.fps == 12 and video.names == [f"{i:05d}.png" for i in range(4)]
    assert read_video(tmp_path / "frames").fps == 30  # default for folders


def test_write_video_accepts_float_frames_and_generators(tmp_path):
    frames = smooth_frames(3, 8, 8)
    write_video(tmp_path / "out", (f / 255.0 for f in frames), 10)
    np.testing.assert_array_equal(read_video(tmp_path / "out").frames, frames)


def test_png_folder_replaces_an_earlier_output_but_not_other_files(tmp_path):
    write_video(tmp_path / "frames", smooth_frames(5, 8, 8), 10)
    write_video(tmp_path / "frames", smooth_frames(2, 8, 8), 10)  # an earlier output is replaced
    assert len(list((tmp_path / "frames").iterdir())) == 2
    (tmp_path / "frames" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        write_video(tmp_path / "frames", smooth_frames(2, 8, 8), 10)
    assert (tmp_path / "frames" / "notes.txt").read_text() == "mine"


def test_folder_is_read_in_natural_order(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in (10, 2, 1):
        write_image(folder / f"frame{i}.png", np.full((4, 6, 3), i, np.uint8))
    write_image(folder / "._frame3.png", np.zeros((4, 6, 3), np.uint8))  # hidden: skipped
    (folder / "notes.txt").write_text("ignored")
    video = read_video(folder)
    assert video.names == ["frame1.png", "frame2.png", "frame10.png"]
    assert video.frames[:, 0, 0, 0].tolist() == [1, 2, 10]


def test_max_side_downscales_with_area_interpolation(tmp_path):
    frames = smooth_frames(3, 48, 64)
    write_video(tmp_path / "frames", frames, 10)
    video = read_video(tmp_path / "frames", max_side=32)
    assert video.frames.shape == (3, 24, 32, 3) and video.scale == 0.5
    np.testing.assert_array_equal(video.frames[1], cv2.resize(frames[1], (32, 24), interpolation=cv2.INTER_AREA))
    assert read_video(tmp_path / "frames", max_side=64).scale == 1.0


def test_read_video_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_video(tmp_path / "missing.mp4")
    (tmp_path / "clip.xyz").write_bytes(b"data")
    with pytest.raises(InputError, match="unsupported video format '.xyz'"):
        read_video(tmp_path / "clip.xyz")
    (tmp_path / "bad.mp4").write_bytes(b"not a video" * 100)
    with pytest.raises(InputError, match="cannot read video"):
        read_video(tmp_path / "bad.mp4")
    (tmp_path / "bad.gif").write_bytes(b"GIF89a" + b"\x00" * 50)
    with pytest.raises(InputError, match="cannot read GIF"):
        read_video(tmp_path / "bad.gif")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="holds no images"):
        read_video(tmp_path / "empty")
    with pytest.raises(InputError, match="max_side"):
        read_video(tmp_path / "empty", max_side=0)


def test_truncated_mp4_is_an_input_error(tmp_path):
    write_video(tmp_path / "v.mp4", smooth_frames(5, 32, 32), 10)
    data = (tmp_path / "v.mp4").read_bytes()
    (tmp_path / "t.mp4").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="cannot read video"):
        read_video(tmp_path / "t.mp4")


def test_folder_frame_errors(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    write_image(folder / "0.png", np.zeros((4, 6, 3), np.uint8))
    with pytest.raises(InputError, match="at least 2"):
        read_video(folder)
    write_image(folder / "1.png", np.zeros((5, 6, 3), np.uint8))
    with pytest.raises(InputError, match="frame 1.png is 6x5 but frame 0.png is 6x4"):
        read_video(folder)
    (folder / "1.png").write_bytes(b"junk")
    with pytest.raises(InputError, match="cannot read image"):
        read_video(folder)


@pytest.mark.parametrize("name", ["v.mp4", "v.gif", "frames"])
@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_interrupted_write_leaves_nothing_and_keeps_the_old_output(tmp_path, name, error):
    def frames():
        yield from smooth_frames(3, 16, 16)
        raise error("stop")

    with pytest.raises(error):
        write_video(tmp_path / name, frames(), 10)
    assert list(tmp_path.iterdir()) == []

    write_video(tmp_path / name, smooth_frames(2, 8, 8), 10)
    before = read_video(tmp_path / name).frames
    with pytest.raises(error):
        write_video(tmp_path / name, frames(), 10)
    np.testing.assert_array_equal(read_video(tmp_path / name).frames, before)
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary left behind


def test_write_video_errors(tmp_path):
    frame = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(InputError, match="unsupported video format '.avi'"):
        write_video(tmp_path / "v.avi", [frame, frame], 10)
    with pytest.raises(InputError, match="no frames"):
        write_video(tmp_path / "v.mp4", [], 10)
    with pytest.raises(InputError, match="frame 1 has shape"):
        write_video(tmp_path / "v.mp4", [frame, frame[:4]], 10)
    with pytest.raises(InputError, match="fps"):
        write_video(tmp_path / "v.mp4", [frame], 0)
    with pytest.raises(InputError, match="does not exist"):
        write_video(tmp_path / "missing" / "v.mp4", [frame], 10)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- images


def test_image_round_trips(tmp_path):
    rgb = smooth_frames(1, 12, 16)[0]
    write_image(tmp_path / "a.png", rgb)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgb)
    rgba = np.dstack([rgb, np.arange(12 * 16).reshape(12, 16).astype(np.uint8)])
    write_image(tmp_path / "b.png", rgba)
    np.testing.assert_array_equal(read_image(tmp_path / "b.png"), rgba)
    write_image(tmp_path / "c.jpg", rgb)
    assert np.abs(read_image(tmp_path / "c.jpg").astype(int) - rgb).mean() < 3  # JPEG quality 95


def test_read_image_converts_grey_and_16_bit(tmp_path):
    grey = np.arange(20, dtype=np.uint8).reshape(4, 5) * 10
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.dstack([grey] * 3))
    deep = np.full((3, 3, 3), 65535, np.uint16)
    deep[0, 0] = (257 * 10, 257 * 20, 257 * 30)  # BGR on disk
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    image = read_image(tmp_path / "d.png")
    assert image.dtype == np.uint8 and image[0, 0].tolist() == [30, 20, 10] and image[1, 1].tolist() == [255] * 3


def test_image_errors(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_image(tmp_path / "a.png")
    (tmp_path / "a.png").write_bytes(b"garbage")
    with pytest.raises(InputError, match="cannot read image"):
        read_image(tmp_path / "a.png")
    with pytest.raises(InputError, match="unsupported image format"):
        write_image(tmp_path / "a.webp", np.zeros((2, 2, 3), np.uint8))
    with pytest.raises(InputError, match="alpha"):
        write_image(tmp_path / "a.jpg", np.zeros((2, 2, 4), np.uint8))


# ---------------------------------------------------------------- masks


def test_masks_read_back(tmp_path):
    masks = box_masks(4, 12, 16)
    write_masks(tmp_path / "masks", masks)
    out = read_masks(tmp_path / "masks", count=4, size=(16, 12))
    assert out.dtype == bool
    np.testing.assert_array_equal(out, masks)


def test_jpeg_masks_ignore_compression_noise(tmp_path):
    masks = box_masks(2, 32, 32)
    write_masks(tmp_path / "masks", masks, suffix=".jpg")
    out = read_masks(tmp_path / "masks", count=2, size=(32, 32))
    assert (out != masks).mean() < 0.01  # JPEG ringing stays far below the 127 threshold


def test_rgb_mask_any_channel_counts(tmp_path):
    (tmp_path / "masks").mkdir()
    for i in range(2):
        image = np.zeros((4, 4, 3), np.uint8)
        image[1, 1, i] = 1  # only red, then only green, barely non-zero
        write_image(tmp_path / "masks" / f"{i}.png", image)
    out = read_masks(tmp_path / "masks", count=2, size=(4, 4))
    assert out.sum() == 2 and out[:, 1, 1].all()


def test_full_resolution_masks_follow_a_downscaled_video(tmp_path):
    masks = box_masks(3, 48, 64)
    write_masks(tmp_path / "masks", masks)
    out = read_masks(tmp_path / "masks", count=3, size=(32, 24))
    assert out.shape == (3, 24, 32)
    np.testing.assert_array_equal(out, masks[:, ::2, ::2])  # nearest neighbour on an even grid
    with pytest.raises(InputError, match="is 64x48 but the frames are 32x20"):
        read_masks(tmp_path / "masks", count=3, size=(32, 20))


def test_mask_errors(tmp_path):
    masks = box_masks(3, 8, 8)
    write_masks(tmp_path / "masks", masks)
    with pytest.raises(InputError, match="holds 3 masks but the video has 5 frames"):
        read_masks(tmp_path / "masks", count=5, size=(8, 8))
    with pytest.raises(InputError, match="does not exist"):
        read_masks(tmp_path / "nope", count=3, size=(8, 8))
    write_image(tmp_path / "masks" / "m0.png", np.zeros((8, 8), np.uint8))
    with pytest.raises(InputError, match="mask of frame 0 is empty"):
        read_masks(tmp_path / "masks", count=3, size=(8, 8))
    write_masks(tmp_path / "empty", np.zeros((3, 8, 8), bool))
    with pytest.raises(InputError, match="all masks .* are empty"):
        read_masks(tmp_path / "empty", count=3, size=(8, 8))


@pytest.mark.parametrize("name", ["frames", "v.gif", "v.mp4"])
def test_frame_range_and_stride(tmp_path, name):
    frames = smooth_frames(12, 24, 32)
    write_video(tmp_path / name, frames, 10.0)
    video = read_video(tmp_path / name, start=2, end=11, stride=3)
    assert video.indices == [2, 5, 8]
    native = 30.0 if name == "frames" else 10.0  # a folder has no rate of its own
    assert video.fps == pytest.approx(native / 3)
    tolerance = 0 if name == "frames" else 12  # lossy formats
    assert np.abs(video.frames.astype(int) - frames[[2, 5, 8]]).mean() <= tolerance
    with pytest.raises(InputError, match="selected range"):
        read_video(tmp_path / name, start=11)
    with pytest.raises(InputError, match="stride"):
        read_video(tmp_path / name, stride=0)
    with pytest.raises(InputError, match="end"):
        read_video(tmp_path / name, start=4, end=4)


def test_masks_follow_a_frame_range(tmp_path):
    masks = box_masks(10, 24, 32)
    write_masks(tmp_path / "m", masks)
    picked = read_masks(tmp_path / "m", count=3, size=(32, 24), indices=[1, 4, 7])
    assert np.array_equal(picked, masks[[1, 4, 7]])
    write_masks(tmp_path / "few", masks[[1, 4, 7]])  # exactly the selected frames
    assert np.array_equal(read_masks(tmp_path / "few", count=3, size=(32, 24), indices=[1, 4, 7]), picked)


def test_gif_lasts_as_long_as_its_frames_and_stays_small(tmp_path):
    """GIF delays are whole centiseconds: 1/24 s alternates 4 and 5 cs instead of rounding to 4 (4 % fast)."""
    from PIL import Image, ImageSequence

    from marionette.synthetic import make_scene

    frames = make_scene("inplane", num_frames=48, size=(160, 120), seed=0, background="plain").frames
    write_video(tmp_path / "clip.gif", frames, 24)
    with Image.open(tmp_path / "clip.gif") as gif:
        delays = [frame.info["duration"] for frame in ImageSequence.Iterator(gif)]
    assert sum(delays) == pytest.approx(2000, rel=0.01)  # 48 frames at 24 fps: 2 s
    assert set(delays) <= {40, 50} | {d for d in delays if d > 50}  # 4 or 5 cs, or still frames merged
    assert read_video(tmp_path / "clip.gif").fps == pytest.approx(24, rel=0.02)
    # one palette without dithering: 0.14 byte per pixel here, per-frame dithered palettes took 0.27
    assert (tmp_path / "clip.gif").stat().st_size < 0.18 * frames.size / 3
    write_video(tmp_path / "fast.gif", frames, 60)  # browsers slow down delays under 2 cs: frames are left out
    with Image.open(tmp_path / "fast.gif") as gif:
        delays = [frame.info["duration"] for frame in ImageSequence.Iterator(gif)]
    assert min(delays) >= 20 and sum(delays) == pytest.approx(800, rel=0.01)


def test_reading_or_writing_a_video_leaves_no_pipe_to_the_garbage_collector(tmp_path):
    """ffmpeg's pipes are closed when a pass ends, reads to the end or fails, and when a write is interrupted:
    none is left to be found unclosed."""
    write_video(tmp_path / "v.mp4", smooth_frames(5, 32, 32), 10)
    (tmp_path / "bad.mp4").write_bytes(b"not a video" * 100)

    def interrupted():
        yield from smooth_frames(3, 16, 16)
        raise RuntimeError("stop")

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        with pytest.raises(RuntimeError):
            write_video(tmp_path / "w.mp4", interrupted(), 10)
        video = read_video(tmp_path / "v.mp4")
        opened = open_video(tmp_path / "v.mp4")
        opened.frames[3]
        opened.frames.close()
        with pytest.raises(InputError, match="cannot read video"):
            read_video(tmp_path / "bad.mp4")
        del video, opened
        gc.collect()
    assert [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)] == []
