"""The joint fit of poses and object (marionette.reconstruct.joint): its terms' gradients, and poses put right."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from marionette.errors import InputError
from marionette.eval.silhouette import silhouette_frame
from marionette.geometry import axis_angle_to_matrix, matrix_to_axis_angle, rotation_angle_deg
from marionette.prior import SpatPrior
from marionette.reconstruct import ReconstructOptions, reconstruct_object
from marionette.reconstruct import joint
from marionette.reconstruct.joint import (JointOptions, PoseFit, TrackObservations, joint_fit, placed_on_masks,
                                         triangulate_tracks)
from marionette.source.tracks import track
from marionette.synthetic import make_scene, perturbed_prior


def _random_poses(rng: np.random.Generator, k: int, t: int) -> np.ndarray:
    poses = np.tile(np.eye(4), (k, t, 1, 1))
    poses[:, :, :3, :3] = axis_angle_to_matrix(rng.normal(scale=0.3, size=(k, t, 3)).reshape(-1, 3)).reshape(k, t, 3, 3)
    poses[:, :, :3, 3] = rng.normal(scale=0.2, size=(k, t, 3)) + [0.0, 0.0, 4.0]
    return poses


def _nudged(fit: PoseFit, t: int, x: np.ndarray) -> PoseFit:
    """A copy of the fit with frame t's poses moved by the left twists x (K, 6) about the pivots."""
    other = PoseFit.__new__(PoseFit)
    other.__dict__.update(fit.__dict__)
    other.poses = fit.poses.copy()
    pivots = fit.pivots(t)
    rot = axis_angle_to_matrix(x[:, :3])
    other.poses[:, t, :3, :3] = rot @ fit.poses[:, t, :3, :3]
    other.poses[:, t, :3, 3] = np.einsum("kij,kj->ki", rot, fit.poses[:, t, :3, 3] - pivots) + pivots + x[:, 3:]
    return other


def _energy_at_frame(fit: PoseFit, t: int) -> float:
    """The smoothness, anchor and track terms that involve frame t, summed (what the gradients differentiate)."""
    o = fit.options
    rot = fit.poses[..., :3, :3]
    steps = matrix_to_axis_angle(rot[:, 1:] @ np.swapaxes(rot[:, :-1], -1, -2))  # (K, T-1, 3)
    centres = (np.einsum("ktij,kj->kti", rot, fit.centres) + fit.poses[..., :3, 3]) / fit.radius
    acc = steps[:, 1:] - steps[:, :-1]
    second = centres[:, 2:] - 2 * centres[:, 1:-1] + centres[:, :-2]
    energy = o.acceleration * (np.sum(acc ** 2) + np.sum(second ** 2))
    energy += o.velocity * (np.sum(steps ** 2) + np.sum((centres[:, 1:] - centres[:, :-1]) ** 2))
    if o.anchor > 0:
        omega = matrix_to_axis_angle(rot[:, t] @ np.swapaxes(fit.start[:, t, :3, :3], -1, -2))
        start_c = np.einsum("kij,kj->ki", fit.start[:, t, :3, :3], fit.centres) + fit.start[:, t, :3, 3]
        xi = np.concatenate([omega, (centres[:, t] * fit.radius - start_c) / fit.radius], axis=1)
        energy += o.anchor * o.anchor_scale ** 2 * np.sum(np.log1p(np.sum(xi * xi, axis=1) / o.anchor_scale ** 2))
    s2 = o.track_scale ** 2
    for k, (ids, points) in enumerate(fit.points):
        seen = fit.tracks.visible[t, ids]
        p = points[seen] @ fit.poses[k, t, :3, :3].T + fit.poses[k, t, :3, 3]
        uv = p[:, :2] / p[:, 2:] * [fit.K[0, 0], fit.K[1, 1]] + fit.K[:2, 2]
        r = uv - fit.tracks.uv[t, ids[seen]]
        energy += o.track_weight * np.mean(s2 * np.log1p(np.sum(r * r, axis=1) / s2)) if len(r) else 0.0
    return float(energy)


@pytest.mark.parametrize("t", [0, 1, 3, 5])
def test_the_pose_terms_gradients_match_finite_differences(t):
    rng = np.random.default_rng(3)
    k_count, t_count = 2, 6
    poses = _random_poses(rng, k_count, t_count)
    points = rng.normal(scale=0.5, size=(30, 3))
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    parts = np.repeat([0, 1], 15)
    cam = np.stack([(points[parts == k] @ poses[k, :, :3, :3].swapaxes(-1, -2)) + poses[k, :, None, :3, 3]
                    for k in range(k_count)], axis=1).reshape(t_count, 30, 3)
    uv = cam[..., :2] / cam[..., 2:] * 300.0 + [160, 120] + rng.normal(scale=1.5, size=(t_count, 30, 2))
    visible = rng.random((t_count, 30)) > 0.2
    tracks = TrackObservations(uv, visible, parts)
    options = JointOptions(acceleration=0.7, velocity=0.2, anchor=3.0, anchor_scale=0.05, track_weight=0.01)
    fit = PoseFit(poses, rng.normal(scale=0.1, size=(k_count, 3)), 0.8, K, options, tracks)
    fit.start = _nudged(fit, t, rng.normal(scale=0.03, size=(k_count, 6))).poses  # the anchor off its minimum
    analytic = fit.prior_gradient(t) + fit.track_gradient(t)
    numeric = np.zeros_like(analytic)
    h = 1e-6
    for k in range(k_count):
        for i in range(6):
            x = np.zeros((k_count, 6))
            x[k, i] = h
            plus, minus = _energy_at_frame(_nudged(fit, t, x), t), _energy_at_frame(_nudged(fit, t, -x), t)
            numeric[k, i] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-7 * np.abs(numeric).max())


def test_triangulation_finds_the_points_seen_from_many_poses():
    rng = np.random.default_rng(0)
    poses = _random_poses(rng, 1, 8)[0]
    points = rng.normal(scale=0.5, size=(40, 3))
    cam = points @ poses[:, :3, :3].swapaxes(-1, -2) + poses[:, None, :3, 3]
    K = np.array([[400.0, 0, 200], [0, 400.0, 150], [0, 0, 1]])
    uv = cam[..., :2] / cam[..., 2:] * 400.0 + [200, 150]
    visible = rng.random((8, 40)) > 0.3
    visible[:2, 0] = True
    visible[2:, 0] = False  # seen twice only: no point
    uv[~visible] = np.nan
    found, ok = triangulate_tracks(poses, uv, visible, K)
    assert not ok[0]
    assert ok[1:].sum() >= 35
    np.testing.assert_allclose(found[ok], points[ok], atol=1e-6)


@pytest.mark.parametrize("motion, seed", [("outofplane", 2), ("oscillation", 1)])
def test_poses_perturbed_on_a_third_of_the_frames_come_back_within_half_a_degree(motion, seed):
    """3° and 3 % of the radius off on frames 1, 4, 7, …; benchmarks/bench_joint_fit.py runs 16 scenes."""
    scene = make_scene(motion, num_frames=18, size=(256, 192), seed=seed)
    truth = scene.ground_truth_prior()
    start, bad = perturbed_prior(truth, 3.0, 0.03)
    tracked = track(scene.frames, scene.masks, strict=True)
    tracks = TrackObservations(tracked.uv, tracked.visible, np.zeros(tracked.num_tracks, int))
    fit = joint_fit(scene.frames, scene.masks, start, tracks=tracks)
    error = rotation_angle_deg(fit.prior.poses[0, :, :3, :3] @ truth.poses[0, :, :3, :3].swapaxes(-1, -2))
    before = rotation_angle_deg(start.poses[0, :, :3, :3] @ truth.poses[0, :, :3, :3].swapaxes(-1, -2))
    assert before[bad].min() > 2.9
    assert error[bad].max() <= 0.5, error.round(2)
    assert error.max() <= 0.75, error.round(2)  # the frames left alone stay
    moved = np.linalg.norm(fit.prior.centroids[0] - truth.centroids[0], axis=1) / truth.radii[0]
    assert moved.max() < 0.02
    assert fit.change_deg.shape == (1, 18) and fit.change_deg[0, bad].min() > 2.0


def test_a_single_model_cannot_absorb_the_pose_errors_when_the_poses_are_held():
    """The twin of the test above: the same fit with the poses held still leaves the perturbed frames
    unexplained (the model does not bend to them), so the fit's silhouettes are worse there."""
    scene = make_scene("outofplane", num_frames=12, size=(192, 144), seed=2)
    truth = scene.ground_truth_prior()
    start, bad = perturbed_prior(truth, 6.0, 0.05)
    held = joint_fit(scene.frames, scene.masks, start,
                     options=JointOptions(visits=30, lr_rotation=0.0, lr_translation=0.0))
    freed = joint_fit(scene.frames, scene.masks, start, options=JointOptions(visits=30))
    assert np.all(held.change_deg == 0)
    assert held.reconstruction.quality.summary()["silhouette_iou_worst"] \
        < freed.reconstruction.quality.summary()["silhouette_iou_worst"]


def test_bad_joint_options_are_refused():
    for bad in (dict(visits=0), dict(warmup=1.0), dict(anchor=-1.0), dict(object_side=8), dict(track_scale=0.0)):
        with pytest.raises(InputError):
            dataclasses.replace(JointOptions(), **bad).check()


def test_a_lost_frame_far_from_its_mask_is_placed_on_it():
    """Frames the tracks lost (listed in the metadata, their interpolated poses far off) come back onto
    their masks: centred there, then fitted."""
    scene = make_scene("translation", num_frames=12, size=(192, 144), seed=3)
    truth = scene.ground_truth_prior()
    poses = truth.poses.copy()
    lost = [5, 6]
    for t in lost:  # a third of the way across the frame, and turned
        poses[0, t, :3, 3] += [1.2 * truth.radii[0], 0.4 * truth.radii[0], 0.0]
        poses[0, t, :3, :3] = axis_angle_to_matrix(np.radians([4.0, 0.0, 3.0])) @ poses[0, t, :3, :3]
    start = SpatPrior.from_poses(poses, truth.centroids, truth.radii, fps=truth.fps,
                                 image_size=tuple(truth.image_size), intrinsics=truth.intrinsics,
                                 metadata={"failed_frames": {f"0:{t}": "lost" for t in lost}})
    fit = joint_fit(scene.frames, scene.masks, start, options=JointOptions(visits=40))
    filmed = fit.prior.motion_in("filmed")
    for t in lost:
        iou, stray = silhouette_frame(fit.reconstruction.render_filmed(filmed, t).alpha, scene.masks[t])
        assert iou > 0.9 and stray <= 0.005, (t, iou, stray)
    error = rotation_angle_deg(fit.prior.poses[0, lost, :3, :3] @ truth.poses[0, lost, :3, :3].swapaxes(-1, -2))
    assert error.max() < 1.0


@pytest.mark.parametrize("cover", ["none", "middle", "side"])
def test_a_lost_frame_is_placed_at_its_depth_when_something_in_front_hides_part_of_it(cover):
    """The depth of a lost frame comes from its mask's box against the nearest tracked frame's: a trunk across
    the middle, or over one side, of the object leaves one of its sides whole (by the area, the object would be
    put ~1.4 times too far)."""
    scene = make_scene("translation", num_frames=12, size=(192, 144), seed=3)
    truth = scene.ground_truth_prior()
    masks = np.array(scene.masks)
    lost = 6
    ys, xs = np.nonzero(masks[lost])
    x0, x1 = xs.min(), xs.max()
    band = {"none": slice(0, 0), "middle": slice((2 * x0 + x1) // 3, (x0 + 2 * x1) // 3),
            "side": slice(x0, (x0 + x1) // 2)}[cover]
    masks[lost][:, band] = False
    poses = truth.poses.copy()
    poses[0, lost, :3, 3] += [1.2 * truth.radii[0], 0.4 * truth.radii[0], 0.5 * truth.radii[0]]
    centre = truth.centroids[0, 0]
    placed = placed_on_masks(poses, centre, masks, truth.intrinsics, [lost])
    depth = (placed[0, lost, :3, :3] @ centre + placed[0, lost, :3, 3])[2]
    assert depth == pytest.approx(truth.centroids[0, lost, 2], rel=0.1), cover
    others = [t for t in range(truth.num_frames) if t != lost]
    np.testing.assert_array_equal(placed[:, others], poses[:, others])


def test_lost_frames_mostly_hidden_stay_on_what_shows_of_them():
    """A fast object lost for three frames behind something that hides two thirds of it: those frames are
    drawn over what shows of them (their loss stands out, and they try their neighbours' poses)."""
    scene = make_scene("translation", num_frames=48, size=(192, 144), seed=3)
    every = slice(None, None, 4)  # a fast object: its neighbours' poses are far off
    truth = scene.ground_truth_prior()
    masks = np.array(scene.masks[every])
    lost = [5, 6, 7]
    for t in lost:
        xs = np.nonzero(masks[t].any(axis=0))[0]
        masks[t][:, : xs.min() + 2 * (xs.max() - xs.min()) // 3] = False
    start = SpatPrior.from_poses(truth.poses[:, every], truth.centroids[:, every], truth.radii, fps=truth.fps,
                                 image_size=tuple(truth.image_size), intrinsics=truth.intrinsics,
                                 metadata={"failed_frames": {f"0:{t}": "lost" for t in lost}})
    fit = joint_fit(scene.frames[every], masks, start, options=JointOptions(visits=40))
    filmed = fit.prior.motion_in("filmed")
    for t in lost:
        drawn = fit.reconstruction.render_filmed(filmed, t).alpha >= 0.5
        assert (drawn & masks[t]).sum() / masks[t].sum() > 0.9, t


def test_no_frame_draws_anything_far_from_its_mask_after_a_fit():
    """Every fitted frame rendered in full: at most 0.5 % of its pixels drawn farther than 15 px from the mask,
    after the plain fit and after the joint fit from perturbed poses."""
    scene = make_scene("oscillation", num_frames=10, size=(192, 144), seed=4)
    truth = scene.ground_truth_prior()
    start, _ = perturbed_prior(truth, 4.0, 0.05)
    plain = reconstruct_object(scene.frames, scene.masks, truth, options=ReconstructOptions(iterations=300))
    joint = joint_fit(scene.frames, scene.masks, start, options=JointOptions(visits=30))
    for reconstruction, prior in ((plain, truth), (joint.reconstruction, joint.prior)):
        for t in range(truth.num_frames):
            _, stray = silhouette_frame(reconstruction.render_filmed(prior, t).alpha, scene.masks[t])
            assert stray <= 0.005, (t, stray)


def test_the_outside_term_is_the_silhouette_term_past_the_crop():
    """A Gaussian outside the crop costs what its footprint would on the mask's zeros; its gradient matches
    finite differences; inside the crop, or outside the frame, it costs nothing."""
    from marionette.camera import Camera
    from marionette.reconstruct._views import FitView
    from marionette.reconstruct.fit import _outside

    camera = Camera(np.array([[100.0, 0, 20], [0, 100.0, 15], [0, 0, 1]]), np.eye(4), 40, 30)
    view = FitView(0, camera, np.ones((30, 40, 3), np.float32), np.zeros((30, 40), np.float32), (-50, -40, 90, 70))
    means = np.array([[0.0, 0.0, 2.0], [0.8, 0.0, 2.0], [5.0, 0.0, 2.0]])  # in the crop, beside it, off the frame
    params = {"logits": np.array([0.3, -0.2, 1.0]), "log_scales": np.log(np.full((3, 3), 0.02))}
    loss, grad = _outside(params, means, view, 0.5)
    assert grad[0] == 0 and grad[2] == 0 and grad[1] > 0
    h = 1e-6
    moved = dict(params, logits=params["logits"] + [0, h, 0])
    np.testing.assert_allclose((_outside(moved, means, view, 0.5)[0] - loss) / h, grad[1], rtol=1e-4)
    sigma = 100.0 * 0.02 / 2.0
    o = 1 / (1 + np.exp(0.2))
    assert loss == pytest.approx(0.5 * o * o * np.pi * sigma ** 2 / (40 * 30))


def test_extract_fits_jointly_by_default_and_says_so_unless_told_not_to(tmp_path, capsys):
    from marionette.cli import main
    from marionette.io import read_prior
    from test_cli import write_clip

    frames, masks = write_clip(tmp_path, make_scene("outofplane", num_frames=10, size=(160, 120), seed=0))
    for flag, name in (([], "joint.npz"), (["--no-joint-fit"], "tracks.npz")):
        assert main(["extract", str(frames), "--masks", str(masks), "-o", str(tmp_path / name), "--verbose",
                     *flag]) == 0
    said = capsys.readouterr().err
    assert "fitting poses and object together" in said
    joint, tracks = read_prior(tmp_path / "joint.npz"), read_prior(tmp_path / "tracks.npz")
    fit = joint.metadata["joint_fit"]
    assert fit["seconds"] > 0 and fit["gaussians"] > 100 and 0.9 < fit["silhouette_iou"] <= 1
    assert 0 < fit["turn_deg_median"] <= fit["turn_deg_max"] and "joint" in joint.metadata["timings"]
    assert "joint_fit" not in tracks.metadata and "joint" not in tracks.metadata["timings"]
    assert not np.allclose(joint.poses, tracks.poses)


def test_the_joint_fit_steps_aside_for_several_parts():
    from marionette.source.extract import ExtractOptions, extract_prior

    scene = make_scene("hinge", num_frames=16, size=(200, 150), seed=0)
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts=2))
    assert any(joint["model"] == "hinge" for joint in prior.metadata["joints"].values())
    assert "skipped" in prior.metadata["joint_fit"] and "joint" not in prior.metadata["timings"]


def test_a_first_frame_the_tracks_got_wrong_takes_its_neighbours_pose(monkeypatch):
    """Tracks that slipped between frames 0 and 1 leave every later pose off by the same 25° turn of the model
    (as drift-chicane's smoke does): too far for a gradient; frame 0 takes frame 1's pose, and the motion comes
    back relative to it. Its twin, with no frame ever an outlier, keeps the slip."""
    scene = make_scene("outofplane", num_frames=12, size=(256, 192), seed=2)
    truth = scene.ground_truth_prior()
    slip = np.eye(4)
    slip[:3, :3] = axis_angle_to_matrix(np.radians(25.0) * np.array([0.0, 1.0, 0.0]))
    centre = truth.centroids[0, 0]
    slip[:3, 3] = centre - slip[:3, :3] @ centre
    poses = truth.poses.copy()
    poses[:, 1:] = poses[:, 1:] @ slip
    start = truth.with_poses(poses, truth.centroids[:, 0])

    def error(prior: SpatPrior) -> np.ndarray:
        return rotation_angle_deg(prior.poses[0, :, :3, :3] @ truth.poses[0, :, :3, :3].swapaxes(-1, -2))

    assert error(start)[1:].min() > 20
    fit = joint_fit(scene.frames, scene.masks, start, options=JointOptions(track_weight=0.0))
    assert error(fit.prior).max() < 1.5 and np.median(error(fit.prior)) < 1.0, error(fit.prior).round(2)
    silhouettes = [silhouette_frame(fit.reconstruction.render_filmed(fit.prior, t).alpha, scene.masks[t])[0]
                   for t in range(scene.num_frames)]
    assert min(silhouettes) > 0.9
    monkeypatch.setattr(joint, "OUTLIER_LOSS", np.inf)
    held = joint_fit(scene.frames, scene.masks, start, options=JointOptions(track_weight=0.0))
    assert np.median(error(held.prior)) > 15
