"""Rigid poses from tracks (``marionette.source.rigid``): the bundle adjustment and ``fit_rigid``.

Tracks here are exact projections of points on a turning ellipsoid (visible
where its surface faces the camera), so the answer is known; noise and
scrambled tracks are added on top.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle, rotation_angle_deg
from marionette.source import Tracks, rigid
from marionette.source.rigid import (
    RigidOptions,
    ShapePrior,
    _bundle_adjust,
    _chain_errors,
    _choose_tracks,
    _project,
    _reprojection_errors,
    carved_centroid,
    fit_rigid,
)

pytestmark = pytest.mark.heavy

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
W, H = 320, 240
CENTRE = np.array([0.0, 0.0, 5.0])
AXES = np.array([1.2, 0.9, 0.7])
LONG = np.array([0.6, 0.5, 1.5])  # a body seen end-on at frame 0, like a car from the front


def turning_poses(num_frames: int, degrees: float, axis=(0.3, 1.0, 0.1), shift=(0.4, -0.2, 0.3)) -> np.ndarray:
    """Poses (T, 4, 4): a turn by up to ``degrees`` about ``axis`` through CENTRE plus a drift ``shift``."""
    s = np.linspace(0.0, 1.0, num_frames)
    axis = np.asarray(axis) / np.linalg.norm(axis)
    r = axis_angle_to_matrix(np.radians(degrees) * s[:, None] * axis)
    return make_transform(r, CENTRE - r @ CENTRE + s[:, None] * np.asarray(shift))


def ellipsoid_tracks(poses: np.ndarray, count: int = 3000, seed: int = 0, axes: np.ndarray = AXES,
                     reseeded: bool = False) -> tuple[Tracks, np.ndarray]:
    """Tracks of ``count`` surface points of the ``axes`` ellipsoid at CENTRE moved by ``poses``; and the points (M, 3).

    A point is visible where its outward normal faces the camera. Each track
    is one visible run: from frame 0, or with ``reseeded`` from whenever its
    point turns into view (as the tracker re-seeds surface that appears).
    """
    rng = np.random.default_rng(seed)
    unit = rng.normal(size=(count, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    points = unit * axes + CENTRE
    normals = unit / axes
    cam = np.einsum("tij,nj->tni", poses[:, :3, :3], points) + poses[:, None, :3, 3]
    facing = np.einsum("tij,nj->tni", poses[:, :3, :3], normals)
    visible = np.einsum("tni,tni->tn", facing, -cam) > 0.05 * np.linalg.norm(cam, axis=2)
    uv = np.stack([_project(K, c) for c in cam])
    visible &= (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    start = visible.argmax(axis=0) if reseeded else np.zeros(count, np.int64)
    frames = np.arange(len(poses))[:, None]
    visible &= np.cumsum(visible & (frames >= start), axis=0) == frames - start + 1  # one run from its start
    keep = visible.any(axis=0)
    visible = visible[:, keep]
    uv = np.where(visible[..., None], uv[:, keep], np.nan).astype(np.float32)
    return Tracks(uv=uv, visible=visible, start=start[keep]), points[keep]


def ellipsoid_masks(poses: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Silhouettes (T, H, W) of the ``axes`` ellipsoid at CENTRE moved by ``poses``: pixels whose ray meets it."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    masks = []
    for pose in poses:
        # In body coordinates the camera sits at c = Rᵀ(0 - t) and looks along Rᵀ d.
        d = rays @ pose[:3, :3] / axes
        c = (pose[:3, :3].T @ -pose[:3, 3] - CENTRE) / axes
        a, b, q = (d * d).sum(-1), 2 * (d @ c), c @ c - 1
        masks.append(b * b - 4 * a * q > 0)
    return np.stack(masks)


def ellipsoid_shape(axes: np.ndarray = AXES) -> ShapePrior:
    """The exact frame-0 volume of the ellipsoid."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1) / axes
    c = CENTRE / axes
    a, b, q = (d * d).sum(-1), -2 * (d * c).sum(-1), (c * c).sum() - 1
    disc = b * b - 4 * a * q
    root = np.sqrt(np.where(disc > 0, disc, np.nan))
    return ShapePrior.from_depths((-b - root) / (2 * a), (-b + root) / (2 * a), K)


def median_rotation_error(poses: np.ndarray, truth: np.ndarray) -> float:
    return float(np.median(rotation_angle_deg(np.swapaxes(poses[1:, :3, :3], -1, -2) @ truth[1:, :3, :3])))


def add_noise(tracks: Tracks, sigma: float, seed: int = 1) -> Tracks:
    noise = np.random.default_rng(seed).normal(scale=sigma, size=tracks.uv.shape)
    return dataclasses.replace(tracks, uv=(tracks.uv + noise).astype(np.float32))


# --- the bundle adjustment -------------------------------------------------------------------------------------


def small_problem(sigma: float):
    """Six frames, 40 points seen in all of them, a perturbed start; returns BA arguments and the truth."""
    rng = np.random.default_rng(3)
    truth = turning_poses(6, 40.0)
    unit = rng.normal(size=(40, 3))
    points = unit / np.linalg.norm(unit, axis=1, keepdims=True) * AXES + CENTRE
    uv = np.einsum("tij,nj->tni", truth[:, :3, :3], points) + truth[:, None, :3, 3]
    uv = np.stack([_project(K, c) for c in uv]) + rng.normal(scale=sigma, size=(6, 40, 2))
    start = truth.copy()
    for t in range(1, 6):
        start[t] = make_transform(axis_angle_to_matrix(rng.normal(scale=0.02, size=3)) @ truth[t, :3, :3],
                                  truth[t, :3, 3] + rng.normal(scale=0.05, size=3))
    lifted = points + rng.normal(scale=0.05, size=points.shape)
    directions = lifted / np.linalg.norm(lifted, axis=1, keepdims=True)
    return np.ones((6, 40), bool), uv, start, lifted, directions, np.arange(1, 6), truth, points


def test_bundle_adjustment_reprojects_noise_free_observations_exactly():
    observed, uv, start, lifted, directions, free, truth, _ = small_problem(0.0)
    poses, points = _bundle_adjust(observed, uv, K, start, lifted, directions, free, 1.0, RigidOptions(), 200)
    cam = np.einsum("tij,nj->tni", poses[:, :3, :3], points) + poses[:, None, :3, 3]
    err = np.linalg.norm(np.stack([_project(K, c) for c in cam]) - uv, axis=2)
    assert err.max() < 1e-4
    # Exact reprojection leaves only the scale free (fixed by the depth prior): the rotations are the truth.
    assert rotation_angle_deg(np.swapaxes(poses[:, :3, :3], -1, -2) @ truth[:, :3, :3]).max() < 1e-3


def test_bundle_adjustment_matches_a_dense_reference():
    """The same robust cost, minimised with a dense finite-difference Jacobian over plain (rotation vector, t)."""
    observed, uv, start, lifted, directions, free, _, _ = small_problem(0.7)
    options = RigidOptions()
    poses, points = _bundle_adjust(observed, uv, K, start, lifted, directions, free, 1.0, options, 200)

    def residuals(x):
        rvec, trans = x[:15].reshape(5, 3), x[15:30].reshape(5, 3)
        rot = np.concatenate([[np.eye(3)], axis_angle_to_matrix(rvec)])
        t = np.concatenate([[np.zeros(3)], trans])
        pts = x[30:].reshape(-1, 3)
        cam = np.einsum("tij,nj->tni", rot, pts) + t[:, None]
        err = np.stack([_project(K, c) for c in cam]) - uv
        prior = options.depth_prior_weight * np.einsum("ni,ni->n", directions, pts - lifted)
        return np.concatenate([err.ravel(), prior])

    x0 = np.concatenate([matrix_to_axis_angle(start[1:, :3, :3]).ravel(), start[1:, :3, 3].ravel(), lifted.ravel()])
    ref = least_squares(residuals, x0, loss="huber", f_scale=options.refine_loss_scale, xtol=1e-12, ftol=1e-12,
                        gtol=1e-12)
    ref_rot = axis_angle_to_matrix(ref.x[:15].reshape(5, 3))
    # The same optimum up to the scale, which only the weak depth prior fixes (a flat valley where the
    # tolerances stop either solver): the same rotations and, within 1 %, the same cost.
    assert rotation_angle_deg(np.swapaxes(poses[1:, :3, :3], -1, -2) @ ref_rot).max() < 0.1
    x = np.concatenate([matrix_to_axis_angle(poses[1:, :3, :3]).ravel(), poses[1:, :3, 3].ravel(), points.ravel()])
    r = np.abs(residuals(x))
    cost = 0.5 * np.sum(np.where(r <= 1, r**2, 2 * r - 1))  # Huber with f_scale 1, as least_squares
    assert cost == pytest.approx(ref.cost, rel=0.01)


# --- fit_rigid ---------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene():
    truth = turning_poses(24, 60.0)
    tracks, _ = ellipsoid_tracks(truth)
    return truth, tracks


def test_fit_rigid_meets_the_rotation_target(scene):
    truth, tracks = scene
    fit = fit_rigid(tracks, ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K))
    assert not fit.failed_frames
    assert median_rotation_error(fit.poses, truth) < 0.5
    assert fit.reprojection_rms < 0.1


def test_fit_rigid_with_one_pixel_of_noise(scene):
    truth, tracks = scene
    fit = fit_rigid(add_noise(tracks, 1.0), ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K))
    assert median_rotation_error(fit.poses, truth) < 1.0
    assert 0.8 < fit.reprojection_rms < 1.6  # the noise, neither fitted away nor inflated


def test_poses_do_not_follow_rounding_noise_in_the_refinement(scene, monkeypatch):
    """Another BLAS kernel moves the bundle adjustment's results by ~1e-13, and RANSAC in the next frames turned
    that into other poses (the backpack clip: degrees apart). What the next frames start from is rounded onto a
    grid (:mod:`marionette.reproducible`): the poses come out the same bits."""
    truth, tracks = scene
    tracks, shape = add_noise(tracks, 1.0), ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    reference = fit_rigid(tracks, shape)
    rng, adjust = np.random.default_rng(0), rigid.bundle_adjust

    def nudged(*args, **kwargs):
        poses, points = adjust(*args, **kwargs)
        return (poses * (1 + 1e-13 * rng.standard_normal(poses.shape)),
                points * (1 + 1e-13 * rng.standard_normal(points.shape)))

    monkeypatch.setattr(rigid, "bundle_adjust", nudged)
    perturbed = fit_rigid(tracks, shape)
    assert np.array_equal(perturbed.poses, reference.poses)
    assert perturbed.failed_frames == reference.failed_frames


def test_the_sequential_pass_refines_a_window_of_recent_frames(scene, monkeypatch):
    """A long clip's refinements during the sequential pass move only the last ``refine_window`` frames, the
    earlier ones held with their tracks (their cost does not grow with the clip); the final one moves every
    frame, and the poses come out as well as with every refinement whole."""
    truth, tracks = scene
    tracks, shape = add_noise(tracks, 0.5), ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    adjust, calls = rigid.bundle_adjust, []

    def spy(observed, uv, k, poses, points, directions, free, prior, scale, iterations, held):
        calls.append((free, held))
        return adjust(observed, uv, k, poses, points, directions, free, prior, scale, iterations, held)

    monkeypatch.setattr(rigid, "bundle_adjust", spy)
    windowed = fit_rigid(tracks, shape, options=RigidOptions(refine_window=6))
    for free, held in calls[:-2]:  # the sequential pass's, at frames 8 and 16
        upto = free.max()
        np.testing.assert_array_equal(free, np.arange(max(1, upto - 5), upto + 1))
        np.testing.assert_array_equal(held, np.arange(0, upto - 5) if upto > 5 else [])
    assert [free.max() for free, _ in calls[:-2]] == [8, 16]
    for free, held in calls[-2:]:  # the final refinement
        np.testing.assert_array_equal(free, np.arange(1, 24))
        assert len(held) == 0
    calls.clear()
    whole = fit_rigid(tracks, shape, options=RigidOptions(refine_window=0))
    assert [len(free) for free, _ in calls] == [8, 16, 23, 23]
    assert median_rotation_error(windowed.poses, truth) < 0.5
    assert abs(median_rotation_error(windowed.poses, truth) - median_rotation_error(whole.poses, truth)) < 0.1


def test_points_left_out_of_the_refinement_are_fitted_in_chunks_to_the_same_bits(scene, monkeypatch):
    truth, tracks = scene
    tracks, shape = add_noise(tracks, 0.5), ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    whole = fit_rigid(tracks, shape)
    monkeypatch.setattr(rigid, "_POINT_CHUNK", 7)
    chunked = fit_rigid(tracks, shape)
    assert np.array_equal(chunked.poses, whole.poses)
    assert np.array_equal(chunked.points, whole.points, equal_nan=True)


def test_ransac_rejects_scrambled_tracks(scene):
    truth, tracks = scene
    rng = np.random.default_rng(5)
    bad = rng.random(tracks.num_tracks) < 0.2
    uv = tracks.uv.copy()
    # Scrambled: at each frame after 0, each bad track jumps to where some other bad track is.
    ids = np.nonzero(bad)[0]
    visible = tracks.visible.copy()
    for t in range(1, len(uv)):
        other = rng.permutation(ids)
        uv[t, ids] = tracks.uv[t, other]
        visible[t, ids] &= tracks.visible[t, other]
    uv = np.where(visible[..., None], uv, np.nan)
    scrambled = Tracks(uv=uv.astype(np.float32), visible=visible, start=tracks.start)
    fit = fit_rigid(scrambled, ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K))
    assert median_rotation_error(fit.poses, truth) < 0.5
    # Inlier observations after frame 0: most of the good tracks', few of the scrambled ones'.
    good_rate = fit.inliers[1:, ~bad].sum() / visible[1:, ~bad].sum()
    bad_rate = fit.inliers[1:, bad].sum() / visible[1:, bad].sum()
    assert good_rate > 0.9 and bad_rate < 0.3


def test_fit_rigid_keeps_the_scale_of_the_frame_zero_shape():
    """Tracks re-seeded on a long body turning 100° carry the scale along a chain; it must not drift.

    With the exact frame-0 volume as the prior, the truth is the answer at
    scale 1: the bundle adjustment's scale is free (only the weak depth prior
    holds it), so the fit has to restore the one of the frame-0 shape.
    """
    truth = turning_poses(32, 100.0, axis=(0.0, 1.0, 0.1), shift=(0.3, 0.0, -1.5))
    tracks, _ = ellipsoid_tracks(truth, axes=LONG, reseeded=True)
    assert (tracks.start > 0).sum() > 0.3 * tracks.num_tracks
    fit = fit_rigid(tracks, ellipsoid_shape(LONG))
    assert median_rotation_error(fit.poses, truth) < 0.1
    assert np.abs(fit.poses[:, :3, 3] - truth[:, :3, 3]).max() < 0.01  # of a body 3 units long, 5 away


def test_points_seen_from_one_direction_are_not_triangulated(scene):
    _, tracks = scene
    fit = fit_rigid(tracks, ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K))
    assert fit.triangulated.mean() > 0.9  # a 60° turn
    # Turning about the optical axis: the camera stays on the axis in body coordinates, no parallax.
    spin = turning_poses(12, 40.0, axis=(0.0, 0.0, 1.0), shift=(0.0, 0.0, 0.0))
    fit = fit_rigid(ellipsoid_tracks(spin)[0], ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K))
    assert not fit.triangulated.any()


def test_carving_finds_the_centre_of_a_body_longer_than_its_prior():
    """Seen end-on, a long body gets a shallow prior; the silhouettes of its turn and its points correct it."""
    truth = turning_poses(16, 100.0, axis=(0.0, 1.0, 0.1), shift=(0.3, 0.0, -1.5))
    masks = ellipsoid_masks(truth, LONG)
    exact = ellipsoid_shape(LONG)
    prior = ShapePrior.from_depths(exact.front, exact.front + 0.4 * (exact.back - exact.front), K)
    frames = np.arange(len(truth))
    _, points = ellipsoid_tracks(truth, axes=LONG, reseeded=True)
    shallow = carved_centroid(prior, masks, truth, frames) - CENTRE
    centre = carved_centroid(prior, masks, truth, frames, points=points) - CENTRE
    # The visual hull of a 100° turn leaves some of the far side uncarved: within 10 % of the half-length.
    assert np.linalg.norm(centre) < 0.15
    assert np.linalg.norm(shallow) > 0.5
    # Points within the prior's depth range hardly change it.
    inside = prior.centroid + 0.01 * np.random.default_rng(0).normal(size=(50, 3))
    assert np.allclose(carved_centroid(prior, masks, truth, frames, points=inside) - CENTRE, shallow, atol=0.01)


# --- frames the tracks lose -------------------------------------------------------------------------------------


def gap_tracks(truth: np.ndarray, lost: range, weak: int | None = None) -> Tracks:
    """Tracks of the ellipsoid that all end before ``lost`` and new ones from its end on (none carries
    across); with ``weak``, that many of the old tracks survive one frame into the gap."""
    before, _ = ellipsoid_tracks(truth, seed=0)
    after, _ = ellipsoid_tracks(truth, seed=1, reseeded=True)
    cut_before = before.visible & (np.arange(len(truth))[:, None] < lost.start)
    if weak:
        cut_before[lost.start, :weak] = before.visible[lost.start, :weak]
    late = np.arange(len(truth))[:, None] >= lost.stop
    cut_after = after.visible & late & (np.cumsum(after.visible & late, axis=0) > 0)
    keep = cut_after.any(axis=0)
    start = cut_after[:, keep].argmax(axis=0)
    visible = np.concatenate([cut_before, cut_after[:, keep]], axis=1)
    uv = np.concatenate([before.uv, after.uv[:, keep]], axis=1)
    return Tracks(uv=np.where(visible[..., None], uv, np.nan).astype(np.float32), visible=visible,
                  start=np.concatenate([np.zeros(before.num_tracks, np.int64), start]))


class Oracle:
    """A ``recover`` that knows the true poses, and records what it was asked."""

    def __init__(self, truth: np.ndarray) -> None:
        self.truth, self.calls, self.source_errors = truth, [], []

    def __call__(self, t, source, source_pose, guess, uv, depth, replace=False):
        self.calls.append((t, source, len(uv)))
        self.source_errors.append(rotation_angle_deg(source_pose[:3, :3] @ self.truth[source, :3, :3].T))
        return self.truth[t].copy(), f"oracle from {source}"


def test_frames_the_tracks_lose_are_recovered_and_held():
    truth = turning_poses(24, 60.0)
    tracks = gap_tracks(truth, range(10, 13))
    shape = ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    interpolated = fit_rigid(tracks, shape)
    assert set(interpolated.failed_frames) == {10, 11, 12, 13}  # 13: only tracks born there, none lifted yet
    oracle = Oracle(truth)
    fit = fit_rigid(tracks, shape, recover=oracle)
    assert fit.failed_frames == {}
    assert set(fit.recovered_frames) == {10, 11, 12, 13}
    assert "lifted tracks visible" in fit.recovered_frames[10] and "oracle from 9" in fit.recovered_frames[10]
    # Each lost frame is aligned from the last strong one, with the fitted points seen there.
    assert [(t, s) for t, s, _ in oracle.calls] == [(10, 9), (11, 9), (12, 9), (13, 9)]
    assert all(n > 50 for _, _, n in oracle.calls)
    # Held in the adjustment: the recovered rotations are the oracle's, up to their rounding onto a grid.
    rounding = np.degrees(np.sqrt(3) / 2 * rigid._RECOVERED_STEP)
    for t in range(10, 14):
        assert rotation_angle_deg(fit.poses[t, :3, :3] @ truth[t, :3, :3].T) < rounding + 1e-6
    # Tracks born in a recovered frame carry its pose on: the frames after the gap stay right.
    after = slice(14, None)
    assert median_rotation_error(fit.poses[after], truth[after]) < 0.5
    assert median_rotation_error(fit.poses[after], truth[after]) < \
        median_rotation_error(interpolated.poses[after], truth[after])


def test_a_recovery_starts_from_a_refined_pose():
    """A recovered pose is its source frame's pose times the alignment's step, held from then on: the source is
    refined first. Between refinements (every 8 frames) PnP rests on points lifted onto the shape prior, which is
    not the ellipsoid: the code before handed frame 13's pose on 1.5° off."""
    truth = turning_poses(24, 60.0)
    oracle = Oracle(truth)
    fit = fit_rigid(gap_tracks(truth, range(14, 17)), ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K),
                    recover=oracle)
    assert [s for _, s, _ in oracle.calls] == [13, 13, 13, 13]
    assert max(oracle.source_errors) < 0.05
    assert rotation_angle_deg(fit.poses[13, :3, :3] @ truth[13, :3, :3].T) < 0.05


def test_a_frame_where_few_tracks_survive_is_aligned_from_its_weak_pose():
    truth = turning_poses(24, 60.0)
    tracks = gap_tracks(truth, range(10, 12), weak=40)
    shape = ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    fit = fit_rigid(tracks, shape, recover=Oracle(truth))
    assert fit.recovered_frames[10].startswith("PnP kept only")
    without = fit_rigid(tracks, shape, recover=None)
    assert 10 not in without.failed_frames and 10 not in without.recovered_frames


def test_a_frame_the_sequential_pass_lost_is_posed_after_the_refinement(monkeypatch):
    """PnP fails at frame 12 in the sequential pass (as it does from a guess hundreds of pixels off, after a few
    poorly posed frames: the backpack clip's end); after the refinement it is tried again and placed, and the
    tracks born there, lifted with the guessed pose, are lifted again with the found one."""
    truth = turning_poses(24, 60.0)
    tracks, _ = ellipsoid_tracks(truth, reseeded=True)
    assert (tracks.start == 12).sum() > 15
    shape = ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    pnp, calls = rigid._pnp, []

    def lost_once_at_frame_12(points, uv, k, guess, options):
        calls.append(len(points))
        if len(calls) == 12:  # one call per frame from frame 1 on: the sequential pass at frame 12
            return None, np.zeros(len(points), bool), "PnP RANSAC found 0 inliers, need 6"
        return pnp(points, uv, k, guess, options)

    monkeypatch.setattr(rigid, "_pnp", lost_once_at_frame_12)
    fit = fit_rigid(tracks, shape)
    assert len(calls) == 24  # frames 1-23, then frame 12 once more
    assert fit.failed_frames == {}
    assert list(fit.retried_frames) == [12] and fit.recovered_frames == {}
    assert fit.retried_frames[12].startswith(rigid.RETRIED_NOTE)
    assert fit.retried_frames[12].endswith("(first: PnP RANSAC found 0 inliers, need 6)")
    assert median_rotation_error(fit.poses, truth) < 0.05
    assert rotation_angle_deg(fit.poses[12, :3, :3] @ truth[12, :3, :3].T) < 0.05
    born = tracks.start == 12
    assert fit.inliers[12:, born].sum() > 0.9 * tracks.visible[12:, born].sum()


def test_the_refinement_draws_whole_chains_of_strict_tracks():
    # 60 tracks in 20 chains of 3 pieces (frames 0-3, 4-7, 8-11): a draw of 5 takes all 3 pieces of 5 chains,
    # as many observations as 5 long tracks would give.
    visible = np.zeros((12, 60), bool)
    for m in range(60):
        visible[4 * (m % 3):4 * (m % 3) + 4, m] = True
    ids, chains = np.arange(60), np.arange(60) // 3
    picked = _choose_tracks(visible, 5, 0, ids, chains, per_frame=0)
    assert len(np.unique(chains[picked])) == 5 and len(picked) == 15
    # One piece per chain (anchored tracks): the random sample of the tracks themselves, as before chains.
    sample = np.sort(np.random.default_rng(0).choice(60, 5, replace=False))
    np.testing.assert_array_equal(_choose_tracks(visible, 5, 0, ids, ids, per_frame=0), sample)


def test_pieces_are_scored_by_their_chain():
    # Frames 0-3, the body sliding sideways. Track 0 (frames 0-1) follows a point 5 units deep; track 1 carries on
    # from it (frames 2-3) but moves as a point 2 units deep would (another part): each fits a point of its own,
    # their chain fits none. Track 2, a long track of its own, is scored as before.
    k = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    poses = np.stack([make_transform(np.eye(3), np.array([0.2 * t, 0.0, 0.0])) for t in range(4)])
    near, far = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, 5.0])
    points = np.stack([far, near, far])
    uv = np.full((4, 3, 2), np.nan)
    uv[:2, 0] = _project(k, far[None] + poses[:2, :3, 3])
    uv[2:, 1] = _project(k, near[None] + poses[2:, :3, 3])
    uv[:, 2] = _project(k, far[None] + poses[:, :3, 3])
    observed = np.isfinite(uv[..., 0])
    own = _reprojection_errors(k, poses, points, uv)
    chained = _chain_errors(observed, uv, k, poses, points, np.array([0, 0, 1]), 1.0)
    assert own[observed].max() < 1e-9
    assert chained[:, :2][observed[:, :2]].max() > 1.0
    np.testing.assert_array_equal(chained[:, 2], own[:, 2])


def test_reprojection_errors_in_chunks_are_the_whole_computation(monkeypatch):
    """A few frames at a time (long clips' camera points would take gigabytes), with the same bits as at once; a
    point behind the camera, an unknown point and an unseen observation are infinite."""
    rng = np.random.default_rng(3)
    k = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    poses = make_transform(axis_angle_to_matrix(rng.normal(0, 0.2, (7, 3))), rng.normal([0, 0, 6], 0.3, (7, 3)))
    points = rng.normal(0, 1, (5, 3))
    points[3] = np.nan
    points[4] = [0.0, 0.0, -40.0]  # behind every camera
    uv = rng.uniform(0, 300, (7, 5, 2)).astype(np.float32)
    uv[2, 1] = np.nan
    whole = _reprojection_errors(k, poses, points, uv)
    monkeypatch.setattr(rigid, "_ERROR_CHUNK", 10)  # two frames of five points per chunk, the last one shorter
    np.testing.assert_array_equal(_reprojection_errors(k, poses, points, uv), whole)
    assert np.isinf(whole[:, 3:]).all() and np.isinf(whole[2, 1]) and np.isfinite(whole[:, :3]).sum() == 20
    cam = np.einsum("tij,nj->tni", poses[:, :3, :3], points[:3]) + poses[:, None, :3, 3]
    expected = np.linalg.norm(cam[..., :2] / cam[..., 2:] * [300.0, 300.0] + [160.0, 120.0] - uv[:, :3], axis=2)
    np.testing.assert_allclose(whole[:, :3][np.isfinite(whole[:, :3])], expected[np.isfinite(expected)], rtol=1e-12)


def lagging_pieces(truth: np.ndarray, lag: float, count: int = 1500, length: int = 3) -> Tracks:
    """Tracks of ``count`` ellipsoid points, each cut into strict pieces of ``length`` frames; every piece after
    the first lags its point by ``lag`` of the motion since it began (its window matches poorly where it sits)."""
    whole, _ = ellipsoid_tracks(truth, count=count, seed=5)
    uv, visible, start, continues = [], [], [], []
    for m in range(whole.num_tracks):
        frames = np.nonzero(whole.visible[:, m])[0]
        before = -1
        for s in range(frames[0], frames[-1] + 1, length):
            piece = np.zeros(len(truth), bool)
            piece[s:min(s + length, frames[-1] + 1)] = True
            true = whole.uv[piece, m].astype(np.float64)
            uv.append(np.full((len(truth), 2), np.nan))
            uv[-1][piece] = true - (lag if before >= 0 else 0.0) * (true - true[0])
            visible.append(piece), start.append(s), continues.append(before)
            before = len(uv) - 1
    return Tracks(np.stack(uv, axis=1).astype(np.float32), np.stack(visible, axis=1), np.array(start), True, None,
                  np.array(continues))


def joined(first: Tracks, second: Tracks) -> Tracks:
    """Both sets of tracks as one, ``second``'s continuations renumbered after ``first``'s tracks."""
    shift = np.where(second.continues >= 0, second.continues + first.num_tracks, -1)
    return Tracks(np.concatenate([first.uv, second.uv], axis=1), np.concatenate([first.visible, second.visible], 1),
                  np.concatenate([first.start, second.start]), True, None,
                  np.concatenate([first.continues, shift]))


def test_brief_pieces_that_lag_are_left_out_of_clean_tracks():
    # 300 exact tracks (seeded as surface turns into view) among 1,500 chains of 3-frame pieces, each piece after
    # the first lagging by a tenth of its motion: the refinement leaves the lagging pieces out.
    truth = turning_poses(24, 60.0)
    exact, _ = ellipsoid_tracks(truth, count=300, reseeded=True)
    tracks = joined(exact, lagging_pieces(truth, 0.1))
    shape = ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    errors = {n: median_rotation_error(fit_rigid(tracks, shape, options=RigidOptions(
        min_piece_frames=n, refine_tracks=5000)).poses, truth) for n in (0, 12)}
    assert errors[12] < 0.005
    assert errors[0] > 0.015  # kept, they pull the poses


def test_noisy_tracks_keep_their_brief_pieces():
    # With 1 px of noise the pieces' number counts more than their lag: the same poses as with all pieces kept.
    truth = turning_poses(24, 60.0)
    exact, _ = ellipsoid_tracks(truth, count=300, reseeded=True)
    tracks = add_noise(joined(exact, lagging_pieces(truth, 0.1)), 1.0)
    shape = ShapePrior.inflate(np.isfinite(ellipsoid_shape().front), K)
    poses = [fit_rigid(tracks, shape, options=RigidOptions(min_piece_frames=n)).poses for n in (0, 12)]
    np.testing.assert_array_equal(poses[0], poses[1])
