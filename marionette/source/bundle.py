"""Bundle adjustment of one rigid body's poses and tracked points: Levenberg–Marquardt with a Schur complement.

Each reprojection residual depends on one pose (6 parameters) and one point
(3), so the normal equations split into small blocks: per pose ``U`` (6 × 6),
per point ``V`` (3 × 3) and per observation ``W`` (6 × 3). Eliminating the
points leaves the reduced camera system ``S = U - W V⁻¹ Wᵀ`` (6F × 6F, dense),
solved exactly at every step (Triggs et al., "Bundle Adjustment — A Modern
Synthesis", 1999, §6.1). A handful of exact steps replace the hundreds of
iterative (LSMR) inner products a generic sparse trust-region solver spends on
the same problem. The robust loss is Huber, applied by iteratively reweighted
least squares (weights ``ρ′`` per residual, curvature term dropped).
"""

from __future__ import annotations

import numpy as np
from scipy import linalg, sparse
from scipy.sparse.linalg import spsolve
from threadpoolctl import threadpool_limits

from ..geometry import axis_angle_to_matrix, make_transform, skew

__all__ = ["bundle_adjust", "huber_cost"]

# Up to this many free frames the reduced system is formed and solved dense (one BLAS product and a
# Cholesky-sized solve, 0.1 s per call at 50 frames).
_DENSE_FRAMES = 250
# Beyond, it is formed dense only where that is cheaper and small: a BLAS product does the work of
# 6F × 3N × 6F multiply-adds about this many times faster than the block-sparse product does its 6 × 3 × 6
# per pair of observations of a point, and both layouts of W take at most _DENSE_BYTES. Otherwise it is
# formed block-sparse, its cost growing with the frames times the tracks' length rather than with the frames
# cubed, and solved as a sparse matrix (SuperLU) unless more than _DENSE_SOLVE of it is filled (long tracks
# couple every frame with every other, and SuperLU then loses to a dense solve; docs/benchmarks/bundle.md).
_BLAS_SPEEDUP = 30.0
_DENSE_BYTES = 256 * 2 ** 20
_DENSE_SOLVE = 0.25
# A block-sparse S solved dense is formed a slab of frames at a time, each slab's product at most this large, so
# that the product is never held whole next to its dense copy (288 MB each at 1000 frames).
_SLAB_BYTES = 32 * 2 ** 20


def huber_cost(residuals: np.ndarray, scale: float) -> float:
    """``½ Σ s² ρ(r² / s²)`` with Huber's ``ρ(z) = z`` (z ≤ 1), ``2 √z - 1`` (z > 1): the cost
    ``scipy.optimize.least_squares`` minimises with ``loss="huber", f_scale=s``. residuals: any shape."""
    a = np.abs(residuals) / scale
    return float(0.5 * scale ** 2 * np.sum(np.where(a <= 1, a * a, 2 * a - 1)))


def _huber_weights(residuals: np.ndarray, scale: float) -> np.ndarray:
    """IRLS weights ``ρ′(r² / s²)`` (same shape as residuals): 1 inside the scale, ``s / |r|`` beyond."""
    a = np.abs(residuals)
    return np.where(a <= scale, 1.0, scale / np.maximum(a, scale))


def _sum_by(index: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    """Rows of values (M, ...) summed into ``count`` bins by index (M,) → (count, ...), in index order."""
    flat = values.reshape(len(values), -1)
    out = np.stack([np.bincount(index, weights=flat[:, c], minlength=count) for c in range(flat.shape[1])], axis=1)
    return out.reshape((count,) + values.shape[1:])


def _dense_is_cheaper(point_of_observation: np.ndarray, f_count: int, n_count: int) -> bool:
    """Whether the reduced system of F free frames and N points is better formed dense than block-sparse, given
    the point (M,) of each observation of a free frame (see :data:`_BLAS_SPEEDUP`)."""
    pairs = float(np.sum(np.bincount(point_of_observation, minlength=n_count).astype(np.float64) ** 2))
    return f_count ** 2 * n_count / _BLAS_SPEEDUP < pairs and 2 * 18 * 8 * f_count * n_count <= _DENSE_BYTES


def bundle_adjust(observed: np.ndarray, uv: np.ndarray, k: np.ndarray, poses: np.ndarray, points: np.ndarray,
                  directions: np.ndarray, free: np.ndarray, prior_weight: float, loss_scale: float,
                  max_evaluations: int = 30, held: np.ndarray | None = None,
                  ftol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Jointly refine the poses of frames ``free`` (F,) and N points (N, 3) observed at ``uv`` (T, N, 2).

    Minimises the Huber cost (scale ``loss_scale``, pixels) of the reprojection
    errors of the observations marked in ``observed`` (T, N) bool at frame 0, at
    the free frames and at the frames ``held`` (whose poses, like frame 0's, stay
    as they are), plus the depth prior ``prior_weight · n·(X - X₀)`` per point,
    with ``n`` (N, 3) ``directions``, the point's unit lifting ray, and ``X₀`` its
    starting position. ``k`` (3, 3) intrinsics, ``poses`` (T, 4, 4) object to
    camera. A pose is updated as ``R ← exp(ω) R, t ← t + δ``. Stops after
    ``max_evaluations`` cost evaluations, or when a step lowers the cost by less
    than ``ftol`` of it.

    Returns refined poses (T, 4, 4) (other frames unchanged) and points (N, 3).
    """
    f_count, n_count = len(free), len(points)
    slot = np.full(len(poses), -1)
    slot[free] = np.arange(f_count)
    pose_known = slot >= 0
    pose_known[0] = True
    if held is not None:
        pose_known[held] = True
    obs_t, obs_i = np.nonzero(observed & pose_known[:, None])  # (O,) frame and point
    obs_uv = uv[obs_t, obs_i].astype(np.float64)  # (O, 2)
    moving = np.nonzero(slot[obs_t] >= 0)[0]  # observations whose pose is a variable
    obs_slot = slot[obs_t[moving]]
    fxy, cxy = np.array([k[0, 0], k[1, 1]]), np.array([k[0, 2], k[1, 2]])
    start = np.asarray(points, np.float64)
    dense = f_count <= _DENSE_FRAMES or _dense_is_cheaper(obs_i[moving], f_count, n_count)
    if not dense:  # W and W V⁻¹ as block-sparse rows (one 6 × 3 block per moving observation), in frame order
        by_frame = np.lexsort((obs_i[moving], obs_slot))
        if np.array_equal(by_frame, np.arange(len(by_frame))):
            by_frame = slice(None)  # in frame order already (free frames ascending): views, not copies
        block_columns = obs_i[moving][by_frame]
        block_rows = np.searchsorted(obs_slot[by_frame], np.arange(f_count + 1))
        # The pairs of frames that share a point are S's blocks (the product below has these).
        incidence = sparse.csr_matrix((np.ones(len(block_columns)), block_columns, block_rows),
                                      shape=(f_count, n_count))
        solve_dense = (incidence @ incidence.T).nnz > _DENSE_SOLVE * f_count ** 2

    def evaluate(rot: np.ndarray, trans: np.ndarray, pts: np.ndarray):
        rx = np.einsum("oij,oj->oi", rot[obs_t], pts[obs_i])  # (O, 3)
        cam = rx + trans[obs_t]
        reproj = cam[:, :2] / cam[:, 2:3] * fxy + cxy - obs_uv  # (O, 2)
        prior = prior_weight * np.einsum("ni,ni->n", directions, pts - start)  # (N,)
        cost = huber_cost(reproj, loss_scale) + huber_cost(prior, loss_scale)
        return rx, cam, reproj, prior, (cost if np.isfinite(cost) else np.inf)

    def normal_equations(rot, rx, cam, reproj, prior):
        """Blocks of JᵀWJ and JᵀWr: U (F, 6, 6), V (N, 3, 3), W (M, 6, 3) per moving observation, g_p, g_x."""
        z = cam[:, 2]
        j_proj = np.zeros((len(z), 2, 3))  # d pixel / d camera point
        j_proj[:, 0, 0], j_proj[:, 1, 1] = fxy[0] / z, fxy[1] / z
        j_proj[:, :, 2] = -fxy * cam[:, :2] / z[:, None] ** 2
        j_pt = j_proj @ rot[obs_t]  # (O, 2, 3)
        j_pose = np.concatenate([-j_proj[moving] @ skew(rx[moving]), j_proj[moving]], axis=2)  # (M, 2, 6)
        w_obs = _huber_weights(reproj, loss_scale)[..., None]  # (O, 2, 1)
        w_prior = _huber_weights(prior, loss_scale)  # (N,); the prior's Jacobian row is prior_weight · nᵀ
        wj_pt = w_obs * j_pt
        v = _sum_by(obs_i, np.swapaxes(wj_pt, 1, 2) @ j_pt, n_count)
        v += (w_prior * prior_weight ** 2)[:, None, None] * directions[:, :, None] * directions[:, None, :]
        g_x = _sum_by(obs_i, np.einsum("oki,ok->oi", wj_pt, reproj), n_count)
        g_x += (w_prior * prior_weight * prior)[:, None] * directions
        wj_pose = w_obs[moving] * j_pose
        u = _sum_by(obs_slot, np.swapaxes(wj_pose, 1, 2) @ j_pose, f_count)
        g_p = _sum_by(obs_slot, np.einsum("oki,ok->oi", wj_pose, reproj[moving]), f_count)
        w = np.swapaxes(wj_pose, 1, 2) @ j_pt[moving]  # (M, 6, 3)
        return u, v, w, g_p, g_x

    def step(u, v, w, g_p, g_x, damping):
        """The damped Gauss–Newton step (Marquardt's diagonal scaling): pose twists (F, 6), point moves (N, 3)."""
        v_d = v + (damping * np.einsum("nii->ni", v) + 1e-12)[..., None] * np.eye(3)
        v_inv = np.linalg.inv(v_d)
        y = w @ v_inv[obs_i[moving]]  # (M, 6, 3): W V⁻¹ per observation
        u_d = u + (damping * np.einsum("fii->fi", u) + 1e-12)[..., None] * np.eye(6)
        if dense:  # dense 6F × 3N layouts of W and W V⁻¹: S is one matrix product
            w_mat, y_mat = np.zeros((2, f_count, 6, n_count, 3))
            w_mat[obs_slot, :, obs_i[moving], :] = w
            y_mat[obs_slot, :, obs_i[moving], :] = y
            w_mat, y_mat = w_mat.reshape(6 * f_count, 3 * n_count), y_mat.reshape(6 * f_count, 3 * n_count)
            reduced = -(y_mat @ w_mat.T)
            frames = np.arange(f_count)
            reduced.reshape(f_count, 6, f_count, 6)[frames, :, frames, :] += u_d
            d_p = np.linalg.solve(reduced, -g_p.ravel() + y_mat @ g_x.ravel())
            back = d_p @ w_mat
        else:  # two frames couple only through points seen in both: S is banded, as wide as the tracks are long
            w_mat = sparse.bsr_matrix((w[by_frame], block_columns, block_rows), shape=(6 * f_count, 3 * n_count))
            y_blocks = y[by_frame]
            y_mat = sparse.bsr_matrix((y_blocks, block_columns, block_rows), shape=(6 * f_count, 3 * n_count))
            w_t, rhs = w_mat.T, -g_p.ravel() + y_mat @ g_x.ravel()
            if solve_dense:  # one dense copy of S, solved in place
                reduced = np.zeros((f_count, 6, f_count, 6))
                slab = max(1, _SLAB_BYTES // (36 * 8 * f_count))
                for a in range(0, f_count, slab):  # block rows a..b-1 of Y Wᵀ, each summed as in the whole product
                    b = min(a + slab, f_count)
                    lo, hi = block_rows[a], block_rows[b]
                    y_rows = sparse.bsr_matrix((y_blocks[lo:hi], block_columns[lo:hi], block_rows[a:b + 1] - lo),
                                               shape=(6 * (b - a), 3 * n_count))
                    part = y_rows @ w_t
                    block_row = np.repeat(np.arange(a, b), np.diff(part.indptr))
                    reduced[block_row, :, part.indices, :] = part.data  # toarray() would go through COO
                np.negative(reduced, out=reduced)
                frames = np.arange(f_count)
                reduced[frames, :, frames, :] += u_d
                # Its transpose is Fortran-ordered, which LAPACK factors in place (``transposed`` solves with S
                # itself); a C-ordered matrix is copied first, 288 MB at 1000 frames.
                reduced = reduced.reshape(6 * f_count, 6 * f_count).T
                d_p = linalg.solve(reduced, rhs, transposed=True, overwrite_a=True, check_finite=False)
            else:
                frames = np.arange(f_count + 1)
                u_mat = sparse.bsr_matrix((u_d, frames[:-1], frames), shape=(6 * f_count, 6 * f_count))
                reduced = u_mat - y_mat @ w_t
                d_p = spsolve(reduced.tocsc(), rhs, permc_spec="MMD_AT_PLUS_A")
            back = w_t @ d_p
        d_x = (v_inv @ (-g_x - back.reshape(n_count, 3))[..., None])[..., 0]
        return d_p.reshape(f_count, 6), d_x

    # One BLAS thread: a threaded matrix product or solve splits its sums differently with the thread count,
    # and a result that changes in its last bits can change a chaotic clip's poses by degrees.
    with threadpool_limits(limits=1, user_api="blas"):
        rot, trans, pts = poses[:, :3, :3].copy(), poses[:, :3, 3].copy(), start.copy()
        rx, cam, reproj, prior, current = evaluate(rot, trans, pts)
        evaluations, damping = 1, 1e-3
        while evaluations < max_evaluations and f_count and np.isfinite(current):
            system = normal_equations(rot, rx, cam, reproj, prior)
            while evaluations < max_evaluations:
                d_p, d_x = step(*system, damping)
                new_rot, new_trans = rot.copy(), trans.copy()
                new_rot[free] = axis_angle_to_matrix(d_p[:, :3]) @ rot[free]
                new_trans[free] += d_p[:, 3:]
                new_pts = pts + d_x
                trial = evaluate(new_rot, new_trans, new_pts)
                evaluations += 1
                if trial[-1] < current:
                    break
                damping *= 10.0
            else:
                break
            gain = current - trial[-1]
            rot, trans, pts = new_rot, new_trans, new_pts
            rx, cam, reproj, prior, current = trial
            damping = max(damping * 0.3, 1e-9)
            if gain < ftol * current:
                break
    return make_transform(rot, trans), pts
