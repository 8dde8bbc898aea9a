"""Trajectory quality metrics against brute-force references and known motions."""

import numpy as np
import pytest

from marionette.geometry import axis_angle_to_matrix
from marionette.trajectory import Trajectory
from marionette.transfer.metrics import knn_edges, trajectory_quality


def make_trajectory(means, labels):
    t = len(means)
    return Trajectory(np.asarray(means, np.float32), np.tile(np.eye(3, dtype=np.float32), (t, 2, 1, 1)),
                      np.asarray(labels, np.int32))


def test_knn_edges_match_brute_force():
    pts = np.random.default_rng(0).normal(size=(60, 3))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    expected = set()
    for i in range(len(pts)):
        for j in np.argsort(d[i])[1:6]:
            expected.add((min(i, j), max(i, j)))
    assert set(map(tuple, knn_edges(pts, 5).tolist())) == expected


def test_rigid_motion_scores_zero_and_a_tear_is_found():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, size=(400, 3))
    labels = (pts[:, 0] > 0).astype(int)
    frames = [pts @ axis_angle_to_matrix([0, 0.1 * t, 0]).T + [0.05 * t, 0, 0] for t in range(6)]
    q = trajectory_quality(make_trajectory(frames, labels))
    assert q.rigidity_error < 1e-6 and q.boundary_separation == 0.0 and q.detached_seam == 0.0 and q.jerk < 1e-3
    assert q.edges_within > 0 and q.edges_across > 0
    # Pull part 1 away by one unit: every edge across the boundary (shorter than 2/3) stretches > 50 %.
    torn = [np.where(labels[:, None] == 1, pts + [t / 5, 0, 0], pts) for t in range(6)]
    q = trajectory_quality(make_trajectory(torn, labels))
    assert q.rigidity_error < 1e-6 and q.boundary_separation > 0.9 and q.detached_seam > 0.9


def test_rigidity_error_of_a_uniform_stretch_and_jerk_of_a_cubic():
    pts = np.random.default_rng(2).normal(size=(200, 3))
    frames = [pts * (1 + 0.1 * t) for t in range(3)]
    q = trajectory_quality(make_trajectory(frames, np.zeros(200)))
    assert q.rigidity_error == pytest.approx((0 + 0.1 + 0.2) / 3)
    shift = np.array([1.0, 0, 0])
    cubic = [pts + shift * t**3 for t in range(5)]
    radius = np.sqrt(((pts - pts.mean(axis=0)) ** 2).sum(axis=1).mean())
    assert trajectory_quality(make_trajectory(cubic, np.zeros(200))).jerk == pytest.approx(6 / radius, rel=1e-5)


def test_a_hinge_opening_keeps_contact_but_a_lid_flying_off_tears():
    xs = np.arange(0, 1.0, 0.05)
    body = np.stack(np.meshgrid(xs, xs, np.arange(-0.2, 0, 0.05), indexing="ij"), axis=-1).reshape(-1, 3)
    lid = body + [0, 0, 0.25]
    labels = np.repeat([0, 1], len(body))
    hinge = np.array([0.0, 0.0, 0.025])  # axis along y at the seam's x = 0 edge
    opened = [np.concatenate([body, (lid - hinge) @ axis_angle_to_matrix([0, -a, 0]).T + hinge])
              for a in np.linspace(0, np.pi / 2, 8)]
    q = trajectory_quality(make_trajectory(opened, labels))
    assert q.detached_seam == 0.0  # most seam edges stretch, but the hinge line holds
    flown = [np.concatenate([body, lid + [0, 0, 0.1 * t]]) for t in range(8)]
    assert trajectory_quality(make_trajectory(flown, labels)).detached_seam > 0.9


def test_boundary_separation_counts_every_seam_edge_that_gapes():
    xs = np.arange(0, 1.0, 0.1)
    body = np.stack(np.meshgrid(xs, xs, [0.0], indexing="ij"), axis=-1).reshape(-1, 3)
    lid = body + [0, 0, 0.1]  # touching layers: every body point has its lid neighbour
    labels = np.repeat([0, 1], len(body))
    opened = [np.concatenate([body, (lid - [0, 0, 0.05]) @ axis_angle_to_matrix([0, -a, 0]).T + [0, 0, 0.05]])
              for a in np.linspace(0, np.pi / 2, 6)]
    q = trajectory_quality(make_trajectory(opened, labels))
    assert q.boundary_separation > 0.5 and q.detached_seam == 0.0  # gaping, yet attached along the hinge line
