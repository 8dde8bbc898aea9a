"""Streamed extraction: frames decoded on demand and packed masks give what the in-memory path gives."""

import warnings

import numpy as np
import pytest

from marionette import pipeline
from marionette.errors import InputError
from marionette.io import write_image, write_video
from marionette.io.video import PackedMasks, VideoFrames, open_video, read_masks, read_video
from marionette.segment import Prompt, SalientModel
from marionette.source import extract_prior
from marionette.source.depth import DepthMaps, poses_from_depth, read_depths
from marionette.source.prompted import prompted_masks
from marionette.source.tracks import track
from marionette.synthetic import make_scene

pytestmark = pytest.mark.heavy


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 20-frame 160x120 scene written as an mp4, a frame folder and a mask folder."""
    scene = make_scene("inplane", num_frames=20, size=(160, 120), seed=0)
    root = tmp_path_factory.mktemp("clip")
    write_video(root / "clip.mp4", scene.frames, scene.fps)
    write_video(root / "frames", scene.frames, scene.fps)
    (root / "masks").mkdir()
    for t, mask in enumerate(scene.masks):
        write_image(root / "masks" / f"{t:05d}.png", mask)
    return scene, root


@pytest.mark.parametrize("name", ["clip.mp4", "frames"])
@pytest.mark.parametrize("kwargs", [{}, dict(max_side=100, start=2, end=17, stride=3)])
def test_lazy_frames_match_read_video(clip, name, kwargs):
    _, root = clip
    eager, lazy = read_video(root / name, **kwargs), open_video(root / name, **kwargs)
    assert isinstance(lazy.frames, VideoFrames)
    assert lazy.frames.shape == eager.frames.shape and len(lazy) == len(eager)
    assert (lazy.fps, lazy.scale, lazy.names, lazy.indices) == (eager.fps, eager.scale, eager.names, eager.indices)
    for t in range(len(eager)):  # in order: one decoding pass
        np.testing.assert_array_equal(lazy.frames[t], eager.frames[t])
    for t in (3, 0, -1, 1):  # backwards: the source is opened again
        np.testing.assert_array_equal(lazy.frames[t], eager.frames[t])
    np.testing.assert_array_equal(np.asarray(lazy.frames), eager.frames)
    with pytest.raises(IndexError):
        lazy.frames[len(eager)]


def test_max_pixels_downscales_with_a_warning(clip):
    _, root = clip
    with pytest.warns(UserWarning, match="exceed the limit of 100000 pixels"):
        video = open_video(root / "clip.mp4", max_pixels=100_000)
    t, h, w = video.frames.shape[:3]
    assert t == 20 and t * h * w <= 100_000 and (w, h) == (81, 61)  # the largest long side that fits
    assert video.scale == 81 / 160
    assert video.frames[5].shape == (61, 81, 3)
    video.frames.close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # within the limit: no warning, full size
        full = open_video(root / "clip.mp4", max_pixels=20 * 160 * 120)
    full.frames.close()
    assert full.size == (160, 120)
    with pytest.raises(InputError, match="select fewer frames"):
        open_video(root / "clip.mp4", max_pixels=100)
    with pytest.raises(InputError, match="max_pixels"):
        open_video(root / "clip.mp4", max_pixels=0)


def test_packed_masks_round_trip():
    rng = np.random.default_rng(0)
    masks = rng.random((5, 13, 7)) > 0.5  # H * W not a multiple of 8
    packed = PackedMasks.from_array(masks)
    assert packed.shape == masks.shape and len(packed) == 5 and packed.any()
    for t in range(5):
        np.testing.assert_array_equal(packed[t], masks[t])
    np.testing.assert_array_equal(np.asarray(packed), masks)
    packed[2] = np.zeros((13, 7), bool)
    assert not packed[2].any() and packed[3].any()
    assert not PackedMasks(2, 4, 4).any()
    with pytest.raises(ValueError):
        packed[0] = np.zeros((7, 13), bool)


def test_packed_read_masks_match(clip):
    scene, root = clip
    packed = read_masks(root / "masks", count=20, size=(160, 120), packed=True)
    assert isinstance(packed, PackedMasks)
    np.testing.assert_array_equal(np.asarray(packed), scene.masks)


def _assert_same_prior(a, b):
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.centroids, b.centroids)
    np.testing.assert_array_equal(a.radii, b.radii)
    assert a.extras.keys() == b.extras.keys()
    for key in a.extras:
        np.testing.assert_array_equal(a.extras[key], b.extras[key])


def test_streamed_extraction_matches_in_memory(clip):
    _, root = clip
    video = read_video(root / "clip.mp4")
    masks = read_masks(root / "masks", count=len(video), size=video.size)
    k = pipeline.source_intrinsics(*video.size)
    in_memory = extract_prior(video.frames, masks, k, video.fps)
    streamed = pipeline.extract(root / "clip.mp4", masks=root / "masks")
    _assert_same_prior(streamed, in_memory)
    assert in_memory.extras["tracks_uv"].shape[1] > 50  # a real extraction, not the identity fallback
    assert not in_memory.metadata.get("no_motion")


def test_streamed_foreground_matches_in_memory(clip, monkeypatch):
    _, root = clip
    model = SalientModel(threads=1)
    monkeypatch.setattr("marionette.segment._u2net.default_model", lambda: model)
    short = read_video(root / "clip.mp4", end=8, max_side=120)
    lazy = open_video(root / "clip.mp4", end=8, max_side=120)
    k = pipeline.source_intrinsics(*short.size)
    _assert_same_prior(extract_prior(lazy.frames, None, k, short.fps), extract_prior(short.frames, None, k, short.fps))


def test_streamed_prompted_masks_match_in_memory(clip):
    """The clicked object's masks read the frames once per pass (nothing kept but grey images) and give what the
    frames in memory give."""
    scene, root = clip
    short = read_video(root / "clip.mp4", end=10)
    lazy = open_video(root / "clip.mp4", end=10)
    rows, cols = np.nonzero(scene.masks[0])
    prompt = Prompt(points=((float(cols.mean()), float(rows.mean())),))
    streamed = prompted_masks(lazy.frames, prompt)
    np.testing.assert_array_equal(streamed, prompted_masks(short.frames, prompt))
    assert (streamed[0] & ~scene.masks[0]).sum() < 0.05 * scene.masks[0].sum()  # the object, not the floor

def test_lazy_depths_match(clip, tmp_path):
    scene, _ = clip
    for t, depth in enumerate(scene.depths[:6]):
        np.save(tmp_path / f"{t:03d}.npy", np.where(np.isfinite(depth), depth, 0))  # background: unknown
    eager = read_depths(tmp_path, count=6, size=(160, 120))
    lazy = read_depths(tmp_path, count=6, size=(160, 120), lazy=True)
    assert isinstance(lazy, DepthMaps) and lazy.shape == eager.shape
    np.testing.assert_array_equal(np.asarray(lazy), eager)
    tracks = track(scene.frames[:6], scene.masks[:6])
    np.testing.assert_array_equal(poses_from_depth(tracks, lazy, scene.camera.K),
                                  poses_from_depth(tracks, eager, scene.camera.K))
