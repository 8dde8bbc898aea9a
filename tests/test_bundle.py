"""The Schur-complement bundle adjustment (``marionette.source.bundle``) against a dense, obviously correct twin.

The twin is ``scipy.optimize.least_squares`` on the same Huber cost, with a
finite-difference Jacobian over plain (rotation vector, translation, point)
parameters and tight tolerances: the fast solver must reach its optimum.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.sparse.linalg import spsolve

from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle, rotation_angle_deg
from marionette.source import bundle
from marionette.source.bundle import bundle_adjust, huber_cost

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
CENTRE = np.array([0.0, 0.0, 5.0])
PRIOR = 2.0  # depth prior weight: strong enough that the optimum is sharp in every direction
SCALE = 1.0  # Huber scale, pixels


def project(cam: np.ndarray) -> np.ndarray:
    return cam[..., :2] / cam[..., 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def problem(seed: int = 0, frames: int = 7, count: int = 30):
    """A turning, drifting body, tracks with noise and 5 % gross outliers, partial visibility, a perturbed start."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, frames)[:, None]
    rot = axis_angle_to_matrix(np.radians(35.0) * s * np.array([0.3, 1.0, 0.1]) / np.linalg.norm([0.3, 1.0, 0.1]))
    truth = make_transform(rot, CENTRE - rot @ CENTRE + s * [0.3, -0.2, 0.4])
    unit = rng.normal(size=(count, 3))
    points = unit / np.linalg.norm(unit, axis=1, keepdims=True) * [1.2, 0.9, 0.7] + CENTRE
    uv = project(np.einsum("tij,nj->tni", truth[:, :3, :3], points) + truth[:, None, :3, 3])
    uv += rng.normal(scale=0.5, size=uv.shape)
    observed = rng.random((frames, count)) < 0.8
    observed[0] = True
    outliers = rng.random((frames, count)) < 0.05
    uv[outliers] += rng.normal(scale=25.0, size=(outliers.sum(), 2))
    start = truth.copy()
    for t in range(1, frames):
        start[t] = make_transform(axis_angle_to_matrix(rng.normal(scale=0.03, size=3)) @ truth[t, :3, :3],
                                  truth[t, :3, 3] + rng.normal(scale=0.05, size=3))
    lifted = points + rng.normal(scale=0.05, size=points.shape)
    directions = lifted / np.linalg.norm(lifted, axis=1, keepdims=True)
    return observed, uv, start, lifted, directions


def total_cost(observed, uv, poses, points, lifted, directions, known) -> float:
    t, i = np.nonzero(observed & known[:, None])
    cam = np.einsum("oij,oj->oi", poses[t, :3, :3], points[i]) + poses[t, :3, 3]
    prior = PRIOR * np.einsum("ni,ni->n", directions, points - lifted)
    return huber_cost(project(cam) - uv[t, i], SCALE) + huber_cost(prior, SCALE)


def twin(observed, uv, start, lifted, directions, free, held=()):
    """The dense reference: least_squares with loss="huber" over (rotation vectors, translations, points)."""
    t_count, n = len(start), len(lifted)
    known = np.zeros(t_count, bool)
    known[0] = True
    known[free] = True
    known[list(held)] = True
    obs_t, obs_i = np.nonzero(observed & known[:, None])

    def unpack(x):
        poses = start.copy()
        poses[free, :3, :3] = axis_angle_to_matrix(x[:3 * len(free)].reshape(-1, 3))
        poses[free, :3, 3] = x[3 * len(free):6 * len(free)].reshape(-1, 3)
        return poses, x[6 * len(free):].reshape(n, 3)

    def residuals(x):
        poses, pts = unpack(x)
        cam = np.einsum("oij,oj->oi", poses[obs_t, :3, :3], pts[obs_i]) + poses[obs_t, :3, 3]
        return np.concatenate([(project(cam) - uv[obs_t, obs_i]).ravel(),
                               PRIOR * np.einsum("ni,ni->n", directions, pts - lifted)])

    x0 = np.concatenate([matrix_to_axis_angle(start[free, :3, :3]).ravel(), start[free, :3, 3].ravel(),
                         lifted.ravel()])
    ref = least_squares(residuals, x0, loss="huber", f_scale=SCALE, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return unpack(ref.x), ref.cost


@pytest.mark.parametrize("seed, layout", [(0, "dense"), (1, "dense"), (0, "dense by cost"), (0, "sparse"),
                                          (0, "sparse, solved dense")])
def test_reaches_the_optimum_of_the_dense_twin(seed, layout, monkeypatch):
    """Every way of forming and solving the reduced system: dense (short clips, or long ones where a BLAS product
    is cheaper), block-sparse and solved by SuperLU, or block-sparse and solved dense (long tracks fill it)."""
    if layout != "dense":
        monkeypatch.setattr(bundle, "_DENSE_FRAMES", 0)
        monkeypatch.setattr(bundle, "_BLAS_SPEEDUP", 1e12 if layout == "dense by cost" else 1e-12)
        monkeypatch.setattr(bundle, "_DENSE_SOLVE", 0.0 if layout == "sparse, solved dense" else 1.1)
        monkeypatch.setattr(bundle, "_SLAB_BYTES", 1)  # formed one frame's row of blocks at a time
    sparse_solves, dense_solves, solve = [], [], bundle.linalg.solve
    monkeypatch.setattr(bundle, "spsolve", lambda *a, **kw: sparse_solves.append(1) or spsolve(*a, **kw))

    def in_place(a, b, **kwargs):  # LAPACK overwrites only a Fortran-ordered matrix; scipy copies any other
        dense_solves.append(a.flags.f_contiguous and kwargs["overwrite_a"])
        return solve(a, b, **kwargs)

    monkeypatch.setattr(bundle.linalg, "solve", in_place)
    observed, uv, start, lifted, directions = problem(seed)
    free = np.arange(1, len(start))
    # Listed backwards, the block-sparse rows are sorted into frame order; in order, they are used as they come.
    listed = free[::-1] if layout == "sparse" else free
    poses, points = bundle_adjust(observed, uv, K, start, lifted, directions, listed, PRIOR, SCALE, 200, ftol=1e-14)
    (ref_poses, ref_points), ref_cost = twin(observed, uv, start, lifted, directions, free)
    known = np.ones(len(start), bool)
    cost = total_cost(observed, uv, poses, points, lifted, directions, known)
    assert cost == pytest.approx(ref_cost, rel=1e-6)
    assert total_cost(observed, uv, ref_poses, ref_points, lifted, directions, known) == pytest.approx(ref_cost)
    assert rotation_angle_deg(np.swapaxes(poses[:, :3, :3], -1, -2) @ ref_poses[:, :3, :3]).max() < 1e-3
    assert np.abs(poses[:, :3, 3] - ref_poses[:, :3, 3]).max() < 1e-4
    assert np.abs(points - ref_points).max() < 1e-4
    # and the start was far from it: the solver did real work
    assert total_cost(observed, uv, start, lifted, lifted, directions, known) > 2 * cost
    assert bool(sparse_solves) == (layout == "sparse")
    assert dense_solves == ([True] * len(dense_solves) if layout == "sparse, solved dense" else [])
    assert bool(dense_solves) == (layout == "sparse, solved dense")


def test_held_and_unlisted_frames_keep_their_poses_and_their_observations_count():
    observed, uv, start, lifted, directions = problem(2, frames=8)
    free, held = np.array([1, 2, 4, 5]), np.array([3])  # frames 6 and 7 are neither: their tracks do not count
    poses, points = bundle_adjust(observed, uv, K, start, lifted, directions, free, PRIOR, SCALE, 200,
                                  held=held, ftol=1e-14)
    for t in (0, 3, 6, 7):
        assert np.array_equal(poses[t], start[t])
    assert not np.array_equal(poses[free], start[free])
    # The held frame's observations pull on the points: dropping them changes the answer.
    without = bundle_adjust(observed, uv, K, start, lifted, directions, free, PRIOR, SCALE, 200, ftol=1e-14)[1]
    assert np.abs(without - points).max() > 1e-3
    (ref_poses, ref_points), ref_cost = twin(observed, uv, start, lifted, directions, free, held)
    known = np.zeros(8, bool)
    known[[0, 1, 2, 3, 4, 5]] = True
    assert total_cost(observed, uv, poses, points, lifted, directions, known) == pytest.approx(ref_cost, rel=1e-6)
    assert rotation_angle_deg(np.swapaxes(poses[:6, :3, :3], -1, -2) @ ref_poses[:6, :3, :3]).max() < 1e-3


def test_a_point_without_observations_stays_and_the_cost_never_rises():
    observed, uv, start, lifted, directions = problem(3)
    observed[:, 5] = False
    free = np.arange(1, len(start))
    known = np.ones(len(start), bool)
    costs = [total_cost(observed, uv, start, lifted, lifted, directions, known)]
    for evaluations in (1, 2, 3, 5, 10, 40):
        poses, points = bundle_adjust(observed, uv, K, start, lifted, directions, free, PRIOR, SCALE, evaluations)
        assert np.all(np.isfinite(poses)) and np.all(np.isfinite(points))
        assert np.array_equal(points[5], lifted[5])
        costs.append(total_cost(observed, uv, poses, points, lifted, directions, known))
    assert costs[1] == costs[0]  # one evaluation: the start
    assert all(b <= a for a, b in zip(costs, costs[1:]))
    assert costs[-1] < 0.5 * costs[0]


def test_huber_cost_is_scipys():
    rng = np.random.default_rng(0)
    r = rng.normal(scale=3.0, size=50)
    ref = least_squares(lambda x: r + 0 * x, np.zeros(1), loss="huber", f_scale=1.7, max_nfev=1).cost
    assert huber_cost(r, 1.7) == pytest.approx(ref, rel=1e-12)
