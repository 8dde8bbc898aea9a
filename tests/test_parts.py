"""Rigid part segmentation (``marionette.source.parts``).

Known answers: rigid bodies moved by chosen motions and projected exactly,
and the rendered synthetic scenes of ``marionette.synthetic`` (the hinge's
body and lid, ``part_masks`` per pixel), tracked by ``marionette.source.track``.
"""

from __future__ import annotations

import functools
import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix
from marionette.source.extract import whole_object_poses
from marionette.source.parts import (
    OFF_OBJECT,
    OUTLIER,
    STATIC,
    _errors,
    _fit_motion,
    _Problem,
    segment_parts,
)
from marionette.source.rigid import ShapePrior
from marionette.source.tracks import Tracks, track
from marionette.synthetic import make_scene

pytestmark = pytest.mark.heavy

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
DAVIS_TRAIN = Path(__file__).resolve().parents[2] / "shared" / "data" / "videos" / "davis_train"


def pixel_accuracy(pixel_labels: np.ndarray, part_mask: np.ndarray) -> float:
    """Share of object pixels (``part_mask >= 0``) labelled right, under the best matching of labels to parts."""
    on = part_mask >= 0
    found = [label for label in np.unique(pixel_labels[on])]
    best = 0
    for perm in itertools.permutations(found, min(len(found), int(part_mask.max()) + 1)):
        best = max(best, sum(((pixel_labels == label) & (part_mask == part)).sum() for part, label in enumerate(perm)))
    return best / on.sum()


def rigid_groups(seg) -> int:
    """Moving parts plus the static group when it holds tracks."""
    return seg.num_parts + int((seg.track_labels == STATIC).any())


def projected_body(motion: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (T, N, 2) of frame-0 points (N, 3) moved by poses (T, 4, 4) and projected with K."""
    cam = np.einsum("tij,nj->tni", motion[:, :3, :3], points) + motion[:, None, :3, 3]
    uvw = cam @ K.T
    return uvw[..., :2] / uvw[..., 2:]


def turning(num_frames: int, axis, degrees: float, centre: np.ndarray, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Poses (T, 4, 4): a turn by up to ``degrees`` about ``axis`` through ``centre``, plus a drift ``shift``."""
    s = np.linspace(0.0, 1.0, num_frames)
    rot = axis_angle_to_matrix(np.radians(degrees) * s[:, None] * np.asarray(axis, float) / np.linalg.norm(axis))
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = centre - np.einsum("tij,j->ti", rot, centre) + s[:, None] * np.asarray(shift)
    return poses


@functools.cache
def tracked(motion: str, seed: int):
    """A 32-frame synthetic scene and its tracks, made once for the tests that share them (read only)."""
    scene = make_scene(motion, seed=seed, num_frames=32)
    return scene, track(scene.frames, scene.masks)


@pytest.fixture(scope="module")
def hinge():
    return tracked("hinge", 1)


# --- the rigid motion model ----------------------------------------------------------------------------------------


def test_rigid_motion_explains_its_body_exactly_and_not_another():
    rng = np.random.default_rng(0)
    centre = np.array([0.0, 0.0, 4.0])
    # Points on the front of a unit sphere (tracks lie on visible surfaces): depth relief.
    front = rng.normal(size=(120, 3))
    front /= np.linalg.norm(front, axis=1, keepdims=True)
    front[:, 2] = -np.abs(front[:, 2])
    body, other = centre + front[:60], centre + front[60:]
    uv = np.concatenate([projected_body(turning(12, [1, 1, 0], 40.0, centre, (0.3, 0, 0)), body),
                         projected_body(turning(12, [1, 0, 0], -30.0, centre), other)], axis=1)
    vis = np.ones(uv.shape[:2], bool)
    vis[:6, 50:60] = False  # tracks seen from frame 6 on only
    obs = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], axis=2) @ np.linalg.inv(K).T
    obs = np.where(vis[..., None], obs[..., :2], 0.0)
    problem = _Problem(obs, vis, np.argmax(vis, axis=0), vis.sum(axis=0), 300.0, 16.0 / 300.0**2, 0.5, 4.0, 100,
                       np.random.default_rng(0))
    motion = _fit_motion(obs[:, :60], vis[:, :60], problem.prior_weight)
    rms = np.sqrt(_errors(problem, motion))
    # Exact projections: the body's 40° out-of-plane turn is explained to a few hundredths of a pixel
    # (the weak depth prior is all that is left), the other body's motion by no depth of its points.
    assert np.median(rms[:60]) < 0.02 and rms[:60].max() < 0.1
    assert np.median(rms[60:]) > 5.0


# --- segmentation on rendered scenes -------------------------------------------------------------------------------


def test_hinge_gives_body_and_lid(hinge):
    scene, tracks = hinge
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto")
    assert rigid_groups(seg) == 2
    assert pixel_accuracy(seg.pixel_labels, scene.part_masks[0]) >= 0.95
    assert min(seg.scores, key=seg.scores.get) == seg.num_parts  # the lowest score wins
    # Part 0 is the largest; labels and residuals cover every track.
    moving = seg.track_labels[seg.track_labels >= 0]
    assert np.bincount(moving)[0] == np.bincount(moving).max()
    assert seg.track_labels.shape == seg.residuals.shape == (tracks.num_tracks,)
    assert seg.pixel_labels.dtype == np.int16
    assert (seg.pixel_labels[~scene.masks[0]] == OFF_OBJECT).all()
    assert (seg.pixel_labels[scene.masks[0]] >= STATIC).all()


def test_hinge_with_a_static_body_puts_it_in_the_static_group():
    scene, tracks = tracked("hinge", 0)  # this seed's body does not move
    np.testing.assert_allclose(scene.poses[0], np.tile(np.eye(4), (32, 1, 1)))
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto")
    assert seg.num_parts == 1
    body = scene.part_masks[0] == 0
    assert np.mean(seg.pixel_labels[body] == STATIC) > 0.9
    assert np.mean(seg.pixel_labels[scene.part_masks[0] == 1] == 0) > 0.9


@pytest.mark.parametrize("motion", ["oscillation", "outofplane"])
def test_auto_finds_one_part_on_a_rigid_box(motion):
    scene, tracks = tracked(motion, 0)
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto")
    assert seg.num_parts == 1 and rigid_groups(seg) == 1
    assert (seg.pixel_labels[scene.masks[0]] == 0).all()


def coupled_cars(roll: float, num_frames: int = 24) -> tuple[Tracks, np.ndarray, np.ndarray]:
    """Two cars side by side turning 30° about a common vertical axis; the right one also rolls by ``roll``°.

    Exact projections of points on the cars' fronts (a little relief) plus 0.3 px of noise. Returns the
    tracks, the frame-0 object mask and each track's car (0 left, 1 right).
    """
    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.linspace(-0.95, 0.95, 16), np.linspace(-0.4, 0.4, 8)), axis=-1).reshape(-1, 2)
    cars = [np.c_[grid[:, 0] + x, grid[:, 1], 5.0 + 0.1 * rng.normal(size=len(grid))] for x in (-1.0, 1.0)]
    common = turning(num_frames, [0, 1, 0], 30.0, np.array([0.0, 0.0, 5.0]), (0.3, 0.0, 0.0))
    own = turning(num_frames, [0, 0, 1], roll, np.array([1.0, 0.0, 5.0]))
    uv = np.concatenate([projected_body(common, cars[0]), projected_body(common @ own, cars[1])], axis=1)
    uv += rng.normal(0.0, 0.3, uv.shape)
    mask = np.zeros((240, 320), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(uv[0].astype(np.int32)), 1)
    tracks = Tracks(uv.astype(np.float32), np.ones(uv.shape[:2], bool), np.zeros(uv.shape[1], np.int64))
    return tracks, mask.astype(bool), np.repeat([0, 1], len(grid))


@pytest.mark.parametrize("roll", [0.0, 8.0])
def test_auto_splits_parts_that_one_motion_explains_roughly(roll):
    # An 8° roll of the right car moves its ends by about 8 px over the clip, but one compromise
    # motion explains every track within the threshold (no track is left to seed a second part);
    # the halves of the object, tried as new parts, find it. Without the roll: one part.
    tracks, mask, car = coupled_cars(roll)
    seg = segment_parts(tracks, mask, K, "auto")
    if roll == 0.0:
        assert seg.num_parts == 1 and (seg.track_labels == 0).all()
        return
    assert seg.num_parts == 2 and seg.scores[2] < seg.scores[1]
    assert np.median(seg.residuals) < 2 * 0.3 * np.sqrt(2)  # each car's motion explains it to the noise
    assert max(np.mean(seg.track_labels == car), np.mean(seg.track_labels == 1 - car)) > 0.98


def test_noise_is_estimated_from_the_tracks_and_can_be_given(hinge):
    scene, tracks = hinge
    clean = segment_parts(tracks, scene.masks[0], scene.camera.K, 1)
    assert 0.05 < clean.noise < 1.0 and clean.threshold == pytest.approx(2 * clean.noise)
    # Tracker noise of 1 px per coordinate (1.4 px RMS): the estimate follows it, the local fits
    # see most of it (some is absorbed by the patch's own points).
    jitter = np.random.default_rng(0).normal(0.0, 1.0, tracks.uv.shape).astype(np.float32)
    noisy = segment_parts(Tracks(tracks.uv + jitter, tracks.visible, tracks.start), scene.masks[0],
                          scene.camera.K, 1)
    assert noisy.noise > clean.noise + 1.5
    given = segment_parts(tracks, scene.masks[0], scene.camera.K, 1, noise=0.5, threshold=1.0)
    assert (given.noise, given.threshold) == (0.5, 1.0)


def test_a_drawer_beside_exactly_still_tracks_is_found():
    # A tracker keeps a still, sharp cabinet's tracks exactly still: the noise estimate, a median over patches
    # mostly on it, is 0 there, and a part would have to explain its tracks to nothing (a division by zero).
    rng = np.random.default_rng(3)
    cabinet = rng.uniform(-1.0, 1.0, (400, 2))
    beside = (np.abs(cabinet[:, 0]) > 0.7) | (np.abs(cabinet[:, 1] - 0.6) > 0.3)  # not behind the drawer
    cabinet = np.c_[cabinet[beside][:150], np.full(150, 5.0)]
    drawer = np.c_[rng.uniform(-0.6, 0.6, 50), rng.uniform(0.4, 0.8, 50), np.full(50, 4.8)]
    slide = np.tile(np.eye(4), (24, 1, 1))
    slide[:, 2, 3] = -np.linspace(0.0, 0.6, 24)  # out towards the camera
    still = np.tile(np.eye(4), (24, 1, 1))
    uv = np.concatenate([projected_body(still, cabinet), projected_body(slide, drawer)], axis=1)
    uv[:, 150:] += rng.normal(0.0, 0.02, uv[:, 150:].shape)
    mask = np.zeros((240, 320), np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(uv[0].astype(np.int32)), 1)
    tracks = Tracks(uv.astype(np.float32), np.ones(uv.shape[:2], bool), np.zeros(uv.shape[1], np.int64))
    seg = segment_parts(tracks, mask.astype(bool), K, 2)
    assert seg.noise == pytest.approx(0.08)
    assert seg.num_parts == 1
    assert np.mean(seg.track_labels[:150] == STATIC) > 0.95 and np.mean(seg.track_labels[150:] == 0) > 0.95


def test_one_part_labels_everything_zero(hinge):
    scene, tracks = hinge
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, 1, static=False)
    assert seg.num_parts == 1 and seg.scores.keys() == {1}
    assert set(np.unique(seg.track_labels)) <= {0, OUTLIER}
    assert (seg.pixel_labels[scene.masks[0]] == 0).all()


def test_short_tracks_are_outliers(hinge):
    scene, tracks = hinge
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, 2, min_length=6)
    kept = np.arange(0, tracks.num_frames, 2)  # 32 frames are subsampled to 16 (max_frames=24)
    short = tracks.visible[kept].sum(axis=0) < 6
    assert (seg.track_labels[short] == OUTLIER).all()
    assert np.isnan(seg.residuals[short]).all() and np.isfinite(seg.residuals[~short]).all()


def test_bad_input_is_rejected(hinge):
    scene, tracks = hinge
    mask, k = scene.masks[0], scene.camera.K
    with pytest.raises(InputError, match="num_parts"):
        segment_parts(tracks, mask, k, 0)
    with pytest.raises(InputError, match="num_parts"):
        segment_parts(tracks, mask, k, "many")
    with pytest.raises(InputError, match="object_mask0"):
        segment_parts(tracks, np.zeros_like(mask), k)
    with pytest.raises(InputError, match="noise"):
        segment_parts(tracks, mask, k, noise=-1.0)
    with pytest.raises(InputError, match="K must"):
        segment_parts(tracks, mask, np.eye(2))
    with pytest.raises(InputError, match="tracks must"):
        segment_parts(tracks.uv, mask, k)
    few = Tracks(tracks.uv[:, :3], tracks.visible[:, :3], tracks.start[:3])
    with pytest.raises(InputError, match="tracks are visible"):
        segment_parts(few, mask, k)


@pytest.mark.parametrize("num_parts", [2, "auto"])
def test_tracks_that_miss_the_first_frame_are_a_reason_not_a_crash(hinge, num_parts):
    """Automatic masks can miss the object in the first frame, so no track is on it there, while later frames
    hold many: that is said, where it crashed in the noise estimate (argmin of an empty sequence)."""
    scene, tracks = hinge
    visible = tracks.visible.copy()
    visible[0] = False
    uv = tracks.uv.copy()
    uv[0] = np.nan
    late = Tracks(uv, visible, np.maximum(tracks.start, 1))
    with pytest.raises(InputError, match="no track is on the object in the first frame"):
        segment_parts(late, scene.masks[0], scene.camera.K, num_parts)


# --- real footage --------------------------------------------------------------------------------------------------


def test_davis_train_runs_and_labels_the_whole_train():
    if not DAVIS_TRAIN.is_dir():
        pytest.skip("shared data (davis_train) not available")
    from marionette.camera import Camera
    from marionette.io import read_masks, read_video

    video = read_video(DAVIS_TRAIN / "frames", max_side=320)
    frames, masks = video.frames[:24], read_masks(DAVIS_TRAIN / "masks", count=len(video), size=video.size)[:24]
    tracks = track(frames, masks)
    seg = segment_parts(tracks, masks[0], Camera.from_fov(*video.size).K, "auto")
    assert seg.num_parts >= 1
    assert (seg.pixel_labels[masks[0]] >= STATIC).all() and (seg.pixel_labels[~masks[0]] == OFF_OBJECT).all()


def in_depth_units(poses: np.ndarray, depth: float) -> np.ndarray:
    """Poses (T, 4, 4) with translations divided by ``depth``, as segment_parts takes ``whole``."""
    out = poses.copy()
    out[:, :3, 3] /= depth
    return out


def test_a_whole_object_motion_keeps_a_turning_box_one_part():
    scene, tracks = tracked("outofplane", 0)
    whole = in_depth_units(scene.poses[0], scene.centroids()[0, 0, 2])
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto", whole=whole)
    assert seg.num_parts == 1 and (seg.pixel_labels[scene.masks[0]] == 0).all()
    # The true motion explains the tracks at least as well as the segmentation's own fit does.
    own = segment_parts(tracks, scene.masks[0], scene.camera.K, 1)
    assert seg.scores[1] <= own.scores[1] * 1.001


def test_a_whole_object_motion_does_not_hide_a_moving_part():
    scene, tracks = tracked("hinge", 0)  # the body stays, the lid opens
    # What extract_prior passes: one rigid fit to the body and the lid together, a compromise.
    whole = whole_object_poses(tracks, ShapePrior.inflate(scene.masks[0], scene.camera.K))
    seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto", whole=whole)
    assert seg.num_parts + int((seg.track_labels == STATIC).any()) == 2
    assert pixel_accuracy(seg.pixel_labels, scene.part_masks[0]) > 0.9


def test_a_drawer_sliding_out_of_a_turning_cabinet_is_split_from_it():
    # The cabinet turns 8°; its drawer slides out of it. One compromise motion explains most tracks of both, and
    # the second motion grown from it split the cabinet (its top against its front). The set of local motions
    # that explains the tracks best finds the drawer (measured: 0.84 of the pixels right, 0.60 without it).
    scene = make_scene("slide", object="drawer", seed=100, num_frames=32, size=(400, 300))
    tracks = track(scene.frames, scene.masks)
    whole = whole_object_poses(tracks, ShapePrior.inflate(scene.masks[0], scene.camera.K))
    accuracy = {pool: pixel_accuracy(segment_parts(tracks, scene.masks[0], scene.camera.K, 2, whole=whole,
                                                   pool=pool).pixel_labels, scene.part_masks[0]) for pool in (16, 0)}
    assert accuracy[16] > 0.8 and accuracy[0] < 0.7


@pytest.mark.parametrize("whole", [np.eye(4), np.full((32, 4, 4), np.nan)])
def test_bad_whole_object_motions_are_refused(whole):
    scene, tracks = tracked("outofplane", 0)
    with pytest.raises(InputError, match="whole must be"):
        segment_parts(tracks, scene.masks[0], scene.camera.K, "auto", whole=whole)
