"""Velocity-field refinement: single parts untouched, the hinge stays attached, propagation, shape matching."""

import numpy as np
import pytest

from marionette import pipeline
from marionette.geometry import axis_angle_to_matrix
from marionette.synthetic import make_scene, render_object_image
from marionette.target.lift import LiftOptions, lift_image
from marionette.transfer.metrics import trajectory_quality
from marionette.transfer.parts import labels_from_seeds, seeds_from_layout
from marionette.transfer.refine import RefineOptions, Refiner
from marionette.transfer.velocity import integrate, joint_tree


@pytest.fixture(scope="module")
def hinge():
    """Ground-truth hinge prior and a lifted hinged target with parts matched from the source layout."""
    scene = make_scene("hinge", object="hinge", num_frames=24, size=(160, 120), seed=0)
    prior = scene.ground_truth_prior().aimed_at_object()
    target = lift_image(render_object_image("hinge", size=(128, 128), seed=1),
                        options=LiftOptions(relative_depth=pipeline.relative_depth(prior)))
    labels = labels_from_seeds(target.gaussians.means, target.pixel_of,
                               seeds_from_layout(scene.part_masks[0], target.mask))
    return prior, target.gaussians.means, labels


def test_single_part_is_not_refined(hinge):
    prior, means, _ = hinge
    one = prior.__class__.from_poses(prior.poses[1:], prior.centroids[1:], prior.radii[1:], fps=prior.fps,
                                     image_size=tuple(prior.image_size), intrinsics=prior.intrinsics)
    zeros = np.zeros(len(means), int)
    plain = integrate(means, zeros, one)
    refined = integrate(means, zeros, one, refine=RefineOptions())
    np.testing.assert_array_equal(plain.means, refined.means)


def test_hinge_stays_attached_and_rigid(hinge):
    prior, means, labels = hinge
    raw = trajectory_quality(integrate(means, labels, prior))
    refined = trajectory_quality(integrate(means, labels, prior, refine=RefineOptions()))
    assert raw.detached_seam > 0.5  # each part about its own centre: the lid flies off
    assert refined.detached_seam <= 0.01
    assert refined.rigidity_error <= 0.01


def grid(n=6, spacing=0.1):
    xs = np.arange(n) * spacing
    return np.stack(np.meshgrid(xs, xs, xs, indexing="ij"), axis=-1).reshape(-1, 3)


def test_propagation_moves_a_static_point_between_moving_ones():
    pts = grid()
    labels = np.zeros(len(pts), int)
    u = np.tile([0.01, 0.0, 0.0], (len(pts), 1))
    centre = np.argmin(np.linalg.norm(pts - pts.mean(axis=0), axis=1))
    u[centre] = 0.0
    only = RefineOptions(kinematic=False, topological=False, shape_matching=False)
    v = Refiner(pts, labels, only).velocity(u)
    np.testing.assert_allclose(v[centre], [0.01, 0, 0])
    np.testing.assert_array_equal(np.delete(v, centre, 0), np.delete(u, centre, 0))
    off = Refiner(pts, labels, RefineOptions(kinematic=False, topological=False, propagation=False))
    np.testing.assert_array_equal(off.velocity(u), u)


def reference_projection(rest, mu, refiner):
    """Slow shape matching: one SVD Kabsch per patch, goals averaged per Gaussian, active ones moved."""
    goals = [[] for _ in range(len(mu))]
    for patch in refiner.patch:
        p0, p = rest[patch], mu[patch]
        c0, c = p0.mean(axis=0), p.mean(axis=0)
        u, _, vt = np.linalg.svd((p0 - c0).T @ (p - c))
        r = (u @ np.diag([1, 1, np.sign(np.linalg.det(u @ vt))]) @ vt).T
        for i, g in zip(patch, (p0 - c0) @ r.T + c):
            goals[i].append(g)
    out = mu.copy()
    out[refiner.active] = [np.mean(goals[i], axis=0) for i in refiner.active]
    return out


def test_shape_matching_restores_a_noisy_deformed_patch():
    rest = grid(5)
    labels = (rest[:, 0] > 0.2).astype(int)
    refiner = Refiner(rest, labels, RefineOptions())
    rot = axis_angle_to_matrix([0.3, -0.2, 0.5])
    rigid = rest @ rot.T + [0.3, 0.1, -0.2]
    noisy = rigid + np.random.default_rng(0).normal(scale=0.01, size=rest.shape)
    for _ in range(20):  # the rotations are warm-started: repeated projections converge to Kabsch's
        projected = refiner.project(noisy)
    np.testing.assert_allclose(projected, reference_projection(rest, noisy, refiner), atol=1e-10)
    act = refiner.active
    before = np.linalg.norm(noisy[act] - rigid[act], axis=1).mean()
    after = np.linalg.norm(projected[act] - rigid[act], axis=1).mean()
    assert after < 0.5 * before


def chain_prior(bar: np.ndarray, labels: np.ndarray, frames: int = 12):
    """A 3-part chain along x (parts 0 | 1 | 2): part 0 still, 1 turns about z at x = 1, 2 bends further at x = 2."""
    def about(pivot, angle):
        m = np.eye(4)
        m[:3, :3] = axis_angle_to_matrix(np.array([0.0, 0.0, angle]))
        m[:3, 3] = pivot - m[:3, :3] @ pivot
        return m

    angles = np.linspace(0, 0.6, frames)
    poses = np.tile(np.eye(4), (3, frames, 1, 1))
    for t, a in enumerate(angles):
        poses[1, t] = about(np.array([1.0, 0.25, 0.0]), a)
        poses[2, t] = poses[1, t] @ about(np.array([2.0, 0.25, 0.0]), a)
    rest = np.stack([bar[labels == k].mean(axis=0) for k in range(3)])
    cents = np.einsum("ktij,kj->kti", poses[..., :3, :3], rest) + poses[..., :3, 3]
    radii = np.array([np.sqrt(((bar[labels == k] - rest[k]) ** 2).sum(axis=1).mean()) for k in range(3)])
    from marionette.prior import SpatPrior
    return SpatPrior.from_poses(poses, cents, radii, fps=10.0, image_size=(64, 64), intrinsics=np.eye(3))


def test_joints_hold_a_chain_of_parts():
    # A grandchild must turn about its joint with its parent too, not fly off about its own centre.
    xs, ys = np.meshgrid(np.arange(0, 3, 0.05), np.arange(0, 0.5, 0.05), indexing="ij")
    bar = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    labels = np.minimum(bar[:, 0] // 1, 2).astype(int)
    prior = chain_prior(bar, labels)
    # The target's last part is twice as long as the source's: moving it by its own centre would tear it off.
    target = bar.copy()
    target[labels == 2, 0] = 2 + 2 * (bar[labels == 2, 0] - 2)
    joints_only = RefineOptions(kinematic=False, topological=False, propagation=False, shape_matching=False)
    order, parent, _ = joint_tree(target, labels, prior, Refiner(target, labels, joints_only).near)
    assert order == [0, 1, 2] and parent.tolist() == [-1, 0, 1]
    held = trajectory_quality(integrate(target, labels, prior, refine=joints_only))
    free = trajectory_quality(integrate(target, labels, prior))
    assert held.detached_seam == 0.0 and held.rigidity_error < 1e-5  # float32 means
    assert free.detached_seam > 0.2


def test_joint_tree_keeps_the_longest_seams_of_a_cycle():
    # Three parts that all touch (a square cut into a long left half and two right quarters): rigid parts
    # can hold only two seams, and the short one (between the two quarters) is the one to leave open.
    xs, ys = np.meshgrid(np.arange(0, 2, 0.05), np.arange(0, 2, 0.05), indexing="ij")
    square = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    labels = np.where(square[:, 0] < 1.5, 0, np.where(square[:, 1] < 1, 1, 2))
    prior = chain_prior(square, labels)
    near = Refiner(square, labels, RefineOptions()).near
    order, parent, _ = joint_tree(square, labels, prior, near)
    # Seams: 0-1 and 0-2 are 1 long, 1-2 only 0.5: the tree is 1 - 0 - 2 from the steadiest part 0.
    assert order[0] == 0 and parent.tolist() == [-1, 0, 0]


def test_a_slider_keeps_its_travel_under_the_joints():
    """A drawer sliding out of its cabinet along x: turned about a joint with the cabinet, its travel would be
    dropped; marked a slider in the prior's metadata it slides (its own motion), still rigid."""
    from marionette.prior import SpatPrior

    xs, ys = np.meshgrid(np.arange(0, 2, 0.05), np.arange(0, 0.5, 0.05), indexing="ij")
    bar = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    labels = (bar[:, 0] >= 1).astype(int)
    frames = 12
    poses = np.tile(np.eye(4), (2, frames, 1, 1))
    poses[1, :, 0, 3] = np.linspace(0, 0.6, frames)
    rest = np.stack([bar[labels == k].mean(axis=0) for k in range(2)])
    cents = np.einsum("ktij,kj->kti", poses[..., :3, :3], rest) + poses[..., :3, 3]
    radii = np.array([np.sqrt(((bar[labels == k] - rest[k]) ** 2).sum(axis=1).mean()) for k in range(2)])
    joints_only = RefineOptions(kinematic=False, topological=False, propagation=False, shape_matching=False)

    def travel(metadata):
        prior = SpatPrior.from_poses(poses, cents, radii, fps=10.0, image_size=(64, 64), intrinsics=np.eye(3),
                                     metadata=metadata)
        moved = integrate(bar, labels, prior, refine=joints_only)
        return moved.means[-1][labels == 1] - bar[labels == 1]

    slid = travel({"joints": {"1": {"model": "slider", "on_part": 0, "axis": [1.0, 0.0, 0.0], "range": [0, 0.6]}}})
    np.testing.assert_allclose(slid, np.broadcast_to([0.6, 0.0, 0.0], slid.shape), atol=1e-5)
    assert np.abs(travel({})).max() < 0.05  # held by a joint, the drawer stays put
