"""The compiled normal equations of the part fits (``marionette.source.part_normals``).

Twins: the residuals written as plain NumPy, their Jacobian by central finite
differences, the Gauss–Newton system assembled densely from it and solved in
one piece (no Schur complement), and exact answers on noise-free projections.
"""

from __future__ import annotations

import numpy as np

from marionette.geometry import axis_angle_to_matrix
from marionette.source.part_normals import (
    normal_blocks,
    point_steps,
    reduced_system,
    refine_pose,
    reprojection_cost,
    triangulate_points,
)
from marionette.source.parts import _initial_motion


def project(rot: np.ndarray, trans: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, 3, 3), (T, 3), (N, 3) → normalised projections (T, N, 2), depths floored at 1e-2 as in the kernels."""
    cam = np.einsum("tij,nj->tni", rot, points) + trans[:, None]
    return cam[..., :2] / np.maximum(cam[..., 2:], 1e-2)


def scene(num_frames: int = 5, num_points: int = 9, seed: int = 0):
    """Poses turning and drifting in front of the camera, points near depth 4, observations with noise,
    a visibility pattern with gaps, and priors off the points."""
    rng = np.random.default_rng(seed)
    rot = np.stack([axis_angle_to_matrix(v) for v in rng.normal(0, 0.15, (num_frames, 3))])
    trans = rng.normal(0, 0.2, (num_frames, 3)) + [0.0, 0.0, 4.0]
    points = rng.normal(0, 0.6, (num_points, 3))
    obs = project(rot, trans, points) + rng.normal(0, 0.01, (num_frames, num_points, 2))
    vis = rng.random((num_frames, num_points)) > 0.25
    vis[:2] = True  # every point seen at least twice
    obs[~vis] = 0.0
    prior = points + rng.normal(0, 0.1, points.shape)
    return rot, trans, points, prior, obs, vis


def residuals(rot, trans, points, prior, obs, vis, prior_weight, delta: np.ndarray) -> np.ndarray:
    """All residuals (reprojection where visible, then sqrt(prior_weight) (X - prior)) after the step
    ``delta`` = (T·6 pose twists: left rotation then translation, N·3 point moves)."""
    num_frames, n = vis.shape
    d_cam, d_pt = delta[:6 * num_frames].reshape(num_frames, 6), delta[6 * num_frames:].reshape(n, 3)
    turn = np.stack([axis_angle_to_matrix(d) for d in d_cam[:, :3]])
    new_rot, new_trans = turn @ rot, np.einsum("tij,tj->ti", turn, trans) + d_cam[:, 3:]
    moved = points + d_pt
    reproj = (obs - project(new_rot, new_trans, moved))[vis].ravel()
    return np.concatenate([reproj, np.sqrt(prior_weight) * (moved - prior).ravel()])


def dense_system(rot, trans, points, prior, obs, vis, prior_weight):
    """The Gauss–Newton matrix JᵀJ (6T + 3N square), its right side Jᵀr and the residuals r; J (of the
    model's side, so the step solves JᵀJ d = Jᵀr) by central differences of :func:`residuals`."""
    size = 6 * len(rot) + 3 * len(points)
    base = residuals(rot, trans, points, prior, obs, vis, prior_weight, np.zeros(size))
    jac = np.empty((len(base), size))
    eps = 1e-6
    for k in range(size):
        step = np.zeros(size)
        step[k] = eps
        jac[:, k] = -(residuals(rot, trans, points, prior, obs, vis, prior_weight, step)
                      - residuals(rot, trans, points, prior, obs, vis, prior_weight, -step)) / (2 * eps)
    return jac.T @ jac, jac.T @ base, base


def test_blocks_are_the_finite_difference_normal_equations():
    rot, trans, points, prior, obs, vis = scene()
    pw = 0.3
    u, v, w, g_cam, g_pt = normal_blocks(rot, trans, points, prior, obs, vis, pw)
    hess, grad, base = dense_system(rot, trans, points, prior, obs, vis, pw)
    t, n = vis.shape
    cams, pts = slice(0, 6 * t), slice(6 * t, None)
    for f in range(t):
        np.testing.assert_allclose(u[f], hess[6 * f:6 * f + 6, 6 * f:6 * f + 6], atol=1e-6)
        for m in range(n):
            np.testing.assert_allclose(w[f, m], hess[6 * f:6 * f + 6, 6 * t + 3 * m:6 * t + 3 * m + 3], atol=1e-6)
    for m in range(n):
        np.testing.assert_allclose(v[m], hess[6 * t + 3 * m:6 * t + 3 * m + 3, 6 * t + 3 * m:6 * t + 3 * m + 3],
                                   atol=1e-6)
    np.testing.assert_allclose(g_cam.ravel(), grad[cams], atol=1e-6)
    np.testing.assert_allclose(g_pt.ravel(), grad[pts], atol=1e-6)
    assert not w[~vis].any()  # an unseen observation has no block
    # The cost is the sum of the squared residuals.
    assert np.isclose(reprojection_cost(rot, trans, points, prior, obs, vis, pw), base @ base, rtol=1e-12)


def test_the_schur_step_is_the_dense_damped_step():
    rot, trans, points, prior, obs, vis = scene(num_frames=6, num_points=12, seed=1)
    pw, damping = 0.3, 0.05
    u, v, w, g_cam, g_pt = normal_blocks(rot, trans, points, prior, obs, vis, pw)
    u[0] += 1e12 * np.eye(6)  # the gauge, as the bundle adjustment holds its first frame
    reduced, rhs, vinv = reduced_system(u, v, w, vis, g_cam, g_pt, damping)
    np.testing.assert_allclose(reduced, reduced.T, rtol=1e-12, atol=1e-12)
    d_cam = np.linalg.solve(reduced, rhs).reshape(-1, 6)
    d_pt = point_steps(vinv, w, vis, g_pt, d_cam)
    # The same step from the whole system, assembled from the blocks and damped the same way.
    t, n = vis.shape
    full = np.zeros((6 * t + 3 * n,) * 2)
    for f in range(t):
        full[6 * f:6 * f + 6, 6 * f:6 * f + 6] = u[f] + damping * np.diag(np.diag(u[f]) + 1e-12)
        for m in range(n):
            full[6 * f:6 * f + 6, 6 * t + 3 * m:6 * t + 3 * m + 3] = w[f, m]
            full[6 * t + 3 * m:6 * t + 3 * m + 3, 6 * f:6 * f + 6] = w[f, m].T
    for m in range(n):
        full[6 * t + 3 * m:6 * t + 3 * m + 3, 6 * t + 3 * m:6 * t + 3 * m + 3] = v[m] + damping * np.diag(np.diag(v[m]))
    step = np.linalg.solve(full, np.concatenate([g_cam.ravel(), g_pt.ravel()]))
    np.testing.assert_allclose(d_cam.ravel(), step[:6 * t], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(d_pt.ravel(), step[6 * t:], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(d_cam[0], 0.0, atol=1e-9)  # the gauge frame does not move


def test_points_are_triangulated_from_exact_projections():
    rot, trans, points, _, _, vis = scene(num_frames=8, num_points=20, seed=2)
    obs = np.where(vis[..., None], project(rot, trans, points), 0.0)
    start = points + np.random.default_rng(3).normal(0, 0.2, points.shape)
    found, err = triangulate_points(rot, trans, start, obs, vis, 1e-12, 8)
    np.testing.assert_allclose(found, points, atol=1e-6)
    assert err.max() < 1e-16 and not err[~vis].any()
    # A strong prior holds the points where it says.
    held, err = triangulate_points(rot, trans, start, obs, vis, 1e9, 3)
    np.testing.assert_allclose(held, start, atol=1e-5)
    assert err[vis].min() > 0


def test_a_perturbed_pose_comes_back_from_exact_projections():
    rot, trans, points, _, _, _ = scene(num_frames=1, num_points=15, seed=5)
    obs = project(rot, trans, points)[0]
    start_rot, start_trans = axis_angle_to_matrix(np.array([0.05, -0.04, 0.03])) @ rot[0], trans[0] + [0.05, 0, -0.1]
    refine_pose(start_rot, start_trans, points, obs, 6)  # in place
    np.testing.assert_allclose(start_rot, rot[0], atol=1e-10)
    np.testing.assert_allclose(start_trans, trans[0], atol=1e-10)


def test_the_initial_motion_recovers_a_fronto_parallel_plane_exactly():
    # Points on the plane z = 1 are where the initial motion lifts frame 0's tracks, so the poses of a
    # small turn and drift come back exactly.
    rng = np.random.default_rng(4)
    points = np.c_[rng.uniform(-0.3, 0.3, (30, 2)), np.ones(30)]
    steps = np.linspace(0, 1, 10)[:, None]
    rot = np.stack([axis_angle_to_matrix(v) for v in steps * [0.05, -0.08, 0.03]])
    trans = steps * [0.04, 0.02, -0.05] + np.einsum("tij,j->ti", np.eye(3) - rot, [0.0, 0.0, 1.0])
    vis = np.ones((10, 30), bool)
    obs = np.where(vis[..., None], project(rot, trans, points), 0.0)
    found_rot, found_trans, depths, known = _initial_motion(obs, vis, 4)
    assert known.all()
    np.testing.assert_allclose(found_rot, rot, atol=1e-8)
    np.testing.assert_allclose(found_trans, trans, atol=1e-8)
    np.testing.assert_allclose(depths, np.median(np.einsum("tj,nj->tn", rot[:, 2], points) + trans[:, 2:3], axis=1),
                               atol=1e-8)
    # Too few tracks in the first frames: those frames are not known and keep the identity.
    sparse_vis = vis.copy()
    sparse_vis[:2, 3:] = False
    found_rot, found_trans, _, known = _initial_motion(np.where(sparse_vis[..., None], obs, 0.0), sparse_vis, 4)
    assert not known[:2].any() and known[2:].all()
    np.testing.assert_array_equal(found_rot[:2], np.tile(np.eye(3), (2, 1, 1)))
