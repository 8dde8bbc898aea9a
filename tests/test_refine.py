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
from marionette.transfer.velocity import integrate


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
    assert raw.boundary_separation > 0.5  # each part about its own centre: the lid flies off
    assert refined.boundary_separation <= 0.01
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
