"""Frames the tracks lose, recovered by alignment (marionette.source.recover), on synthetic scenes.

The lost frames are made by a strong horizontal motion blur (61 px): the LK
tracks die there, and the frames after them start with tracks of their own.
"""

import warnings

import cv2
import numpy as np
import pytest

from marionette.geometry import axis_angle_to_matrix, rotation_angle_deg
from marionette.source import ExtractOptions, extract_prior
from marionette.source.recover import FrameRecovery, RecoverOptions
from marionette.synthetic import make_scene

pytestmark = pytest.mark.heavy

BLURRED = [12, 13, 14, 15]


@pytest.fixture(scope="module")
def scene():
    return make_scene("outofplane", num_frames=32, seed=0)


@pytest.fixture(scope="module")
def blurred(scene):
    """The scene's frames (T, H, W, 3) with BLURRED smeared sideways."""
    frames = scene.frames.copy()
    kernel = np.zeros((61, 61), np.float32)
    kernel[30, :] = 1 / 61
    for t in BLURRED:
        frames[t] = cv2.filter2D(frames[t], -1, kernel)
    return frames


def _true_depths(scene, t: int, count: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) on the object in frame t and their camera depths (n,), from the scene's depth map."""
    ys, xs = np.nonzero(scene.masks[t])
    pick = np.random.default_rng(0).choice(len(xs), count, replace=False)
    return np.column_stack([xs[pick], ys[pick]]).astype(np.float64), scene.depths[t][ys[pick], xs[pick]]


def _rotation_error(pose: np.ndarray, truth: np.ndarray) -> float:
    return float(rotation_angle_deg(pose[:3, :3] @ truth[:3, :3].T))


def test_a_frame_turned_away_from_its_model_is_aligned_closer_than_its_guess(scene):
    truth = scene.poses[0]
    recovery = FrameRecovery(scene.frames, scene.masks, scene.camera.K, scene.centroids()[0, 0])
    guess = truth[16].copy()
    guess[:3, :3] = axis_angle_to_matrix(np.radians([0.0, 3.0, 0.0])) @ guess[:3, :3]
    pose, note = recovery(16, 11, truth[11], guess, *_true_depths(scene, 11))
    assert pose is not None, note
    assert "model of frame 11" in note
    # The model is one frame's lift, turned 14° away: it cannot be exact, but it must beat the 3° guess.
    assert _rotation_error(pose, truth[16]) < 2.0


def test_a_guess_that_overshoots_falls_back_to_the_model_frames_pose(scene):
    """A constant-velocity guess from a wrong last step, 60° off and half the radius away: the alignment
    starts again from the model frame's own pose (frames 11 and 12 are 3.1° apart)."""
    truth = scene.poses[0]
    recovery = FrameRecovery(scene.frames, scene.masks, scene.camera.K, scene.centroids()[0, 0])
    wild = truth[12].copy()
    wild[:3, :3] = axis_angle_to_matrix(np.radians([0.0, 60.0, 20.0])) @ wild[:3, :3]
    wild[:3, 3] += 0.5 * scene.radii()[0]
    pose, note = recovery(12, 11, truth[11], wild, *_true_depths(scene, 11))
    assert pose is not None, note
    assert "from its pose" in note
    assert _rotation_error(pose, truth[12]) < 1.5


def test_a_rough_relief_falls_back_to_the_silhouettes(scene):
    """Depths scattered by a badly fitted frame would raise walls of many times the body's area (a 210x blow-up
    on the backpack clip, 40 s per alignment): the model takes the silhouette's relief and keeps its size."""
    recovery = FrameRecovery(scene.frames, scene.masks, scene.camera.K, scene.centroids()[0, 0])
    uv, depth = _true_depths(scene, 11)
    smooth = len(recovery._model(11, scene.poses[0, 11], uv, depth)[0])
    rough = depth * np.random.default_rng(1).choice([0.5, 2.0], len(depth))
    assert len(FrameRecovery(scene.frames, scene.masks, scene.camera.K, scene.centroids()[0, 0],
                             RecoverOptions(max_area=1e9))._model(11, scene.poses[0, 11], uv, rough)[0]) > 3 * smooth
    cells = scene.masks[11].sum() / max(1, round(np.sqrt(scene.masks[11].sum() / RecoverOptions().cells))) ** 2
    assert len(recovery._model(11, scene.poses[0, 11], uv, rough)[0]) <= RecoverOptions().max_area * cells


def test_an_object_out_of_view_is_not_recovered(scene):
    masks = scene.masks.copy()
    masks[5] = False
    recovery = FrameRecovery(scene.frames, masks, scene.camera.K, scene.centroids()[0, 0])
    pose, note = recovery(5, 4, scene.poses[0, 4], scene.poses[0, 5], *_true_depths(scene, 4))
    assert pose is None and "not in view" in note


def test_a_mask_the_model_cannot_cover_leaves_the_frame_failed(scene):
    # A mask of a different object (a wide bar) where the box should be: no pose makes them agree.
    masks = scene.masks.copy()
    ys, xs = np.nonzero(scene.masks[6])
    bar = np.zeros_like(masks[6])
    bar[(ys.min() + ys.max()) // 2 - 4:(ys.min() + ys.max()) // 2 + 4, :] = True
    masks[6] = bar
    recovery = FrameRecovery(scene.frames, masks, scene.camera.K, scene.centroids()[0, 0],
                             RecoverOptions(min_iou=0.8))
    pose, note = recovery(6, 5, scene.poses[0, 5], scene.poses[0, 6], *_true_depths(scene, 5))
    assert pose is None and "silhouette IoU" in note


def _extract(frames, scene, recover: bool):
    """The one-part prior of the frames, and the warnings extraction gave (the tracks' poses: no joint fit)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        prior = extract_prior(frames, scene.masks, scene.camera.K, fps=24.0,
                              options=ExtractOptions(parts=1, camera_motion=False, recover_frames=recover,
                                                     joint_fit=False))
    return prior, [str(w.message) for w in caught]


def test_blurred_frames_are_recovered_not_interpolated(scene, blurred):
    interpolated, said = _extract(blurred, scene, recover=False)
    recovered, said_recovered = _extract(blurred, scene, recover=True)
    assert any("interpolated" in m for m in said) and not any("interpolated" in m for m in said_recovered)
    lost = {f"0:{t}" for t in BLURRED}
    assert lost <= set(interpolated.metadata["failed_frames"])
    assert recovered.metadata["failed_frames"] == {}
    assert lost <= set(recovered.metadata["recovered_frames"])
    assert all("silhouette IoU" in note for note in recovered.metadata["recovered_frames"].values())
    assert recovered.metadata["timings"]["recover"] > 0
    truth = scene.poses[0]

    def error_after_the_gap(prior) -> float:
        return float(np.median([_rotation_error(prior.poses[0, t], truth[t]) for t in range(12, 32)]))

    # Interpolated, the gap's pose error (5.4° here) carries into every later frame; recovered, less of it.
    assert error_after_the_gap(recovered) < error_after_the_gap(interpolated) - 0.5


def test_a_measured_pose_gives_way_only_to_a_clearly_better_one(scene):
    truth = scene.poses[0]
    recovery = FrameRecovery(scene.frames, scene.masks, scene.camera.K, scene.centroids()[0, 0])
    samples = _true_depths(scene, 11)
    pose, note = recovery(13, 11, truth[11], truth[13], *samples, replace=True)
    assert pose is None and "need" in note  # already right: the alignment cannot cover the mask better
    off = truth[13].copy()
    off[:3, 3] += [0.25, 0.0, 0.0]  # a weak pose a quarter of a unit off sideways
    pose, note = recovery(13, 11, truth[11], off, *samples, replace=True)
    assert pose is not None, note
    assert np.linalg.norm(pose[:3, 3] - truth[13, :3, 3]) < 0.1
