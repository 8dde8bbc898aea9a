"""Temporal smoothing of rigid poses on SE(3), and a jitter measure.

Each part's poses are smoothed as a trajectory on SO(3) × R³: the rotation
``R_t`` and the position ``c_t = R_t c + t_t`` of a chosen centre ``c``
(the part's centroid at frame 0, so that a rotation about the part's own
centre does not show up as translation). The smoothed trajectory minimises a
Whittaker (Hodrick-Prescott) objective on the manifold,

    Σ_t ρ(|log(R̂_tᵀ R_t)|) + ρ(|c_t - ĉ_t|) + λ Σ_t (|ω_t - ω_{t-1}|² + |v_t - v_{t-1}|²),

with body velocities ``ω_t = log(R_tᵀ R_{t+1})`` and ``v_t = c_{t+1} - c_t``,
so motion at constant (angular) velocity costs nothing, whatever its size.
``ρ`` is a Huber loss on the per-frame residual (``r²`` up to a threshold
``c``, ``2 c r - c²`` beyond; one threshold for rotations, one for positions,
set from the median residual of the plain least-squares fit), so an outlier
frame is pulled towards its neighbours instead of dragging them. The problem
is solved by Gauss-Newton on the manifold (``R_t ← R_t exp(δ_t)``, exact
SO(3) Jacobians, the Huber loss's exact Hessian) with a backtracking line
search; each step is a sparse banded linear solve. Frame 0 is held fixed.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from ..errors import InputError
from ..geometry import axis_angle_to_matrix, matrix_to_axis_angle

__all__ = ["smooth_poses", "jitter", "CUTOFF_FRAMES"]

#: Period, in frames, whose amplitude the smoother halves at ``strength = 1``: motion
#: that repeats over more frames than this is kept, faster wiggles removed.
CUTOFF_FRAMES = 5.0
#: The Whittaker smoother's gain at frequency f (cycles per frame) is
#: 1 / (1 + 16 λ sin⁴(π f)); this λ halves the amplitude at a period of CUTOFF_FRAMES.
_LAMBDA_1 = 1.0 / (16.0 * np.sin(np.pi / CUTOFF_FRAMES) ** 4)
#: Huber threshold as a multiple of the median residual norm (about 3 σ per
#: axis for Gaussian noise, whose 3-D norm has median ≈ 1.54 σ).
_HUBER_MEDIANS = 2.0
#: Rotation residuals below this (degrees) are never treated as outliers, so
#: clean data with a sudden start keeps its corner.
_MIN_THRESHOLD_DEG = 2.0
_MAX_ITERATIONS = 50
_TOLERANCE = 1e-10


def smooth_poses(poses: np.ndarray, strength: float = 1.0, *, centers: np.ndarray | None = None,
                 robust: bool = True) -> np.ndarray:
    """Remove frame-to-frame jitter from per-part rigid poses, keeping real motion.

    Parameters
    ----------
    poses : ndarray, shape (K, T, 4, 4)
        Part k's frame-0 points → frame t (the SpaT prior convention).
    strength : float
        Size of the smoothing window: motion repeating over fewer than about
        ``CUTOFF_FRAMES * strength`` frames (5 at the default 1.0) is
        attenuated, slower motion kept (the period P whose amplitude is halved solves
        ``sin(π / P) = sin(π / 5) / strength``; λ grows as ``strength⁴``).
        At 1.0, a ±25° oscillation with a 12-frame period keeps about 96 % of
        its amplitude while white rotation noise loses about 80 % of its
        second-difference jitter and 40 % of its error. 0 returns the input.
    centers : ndarray, shape (K, 3), optional
        Point of each part, at frame 0, whose trajectory is smoothed (its
        centroid); the world origin by default. Rotation jitter about a
        centre far from it would otherwise be seen as translation jitter.
    robust : bool
        Huber-weight the data term so that outlier frames are pulled in.

    Returns
    -------
    ndarray, shape (K, T, 4, 4)
        Smoothed poses; frame 0 is the input's frame 0 exactly.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 4 or poses.shape[2:] != (4, 4) or 0 in poses.shape[:2]:
        raise InputError(f"poses must have shape (K, T, 4, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError("poses contain NaN or infinite values")
    if isinstance(strength, bool) or not np.isscalar(strength) or not (np.isfinite(strength) and strength >= 0):
        raise InputError(f"smoothing strength must be a non-negative number, got {strength!r}")
    k_count, t_count = poses.shape[:2]
    centers = np.zeros((k_count, 3)) if centers is None else np.asarray(centers, dtype=np.float64)
    if centers.shape != (k_count, 3) or not np.all(np.isfinite(centers)):
        raise InputError(f"centers must be finite with shape ({k_count}, 3), got {centers.shape}")
    out = poses.copy()
    if strength == 0 or t_count < 3:
        return out
    lam = _LAMBDA_1 * float(strength) ** 4
    for k in range(k_count):
        rot = poses[k, :, :3, :3]
        pos = rot @ centers[k] + poses[k, :, :3, 3]  # (T, 3) the centre's trajectory
        threshold = None
        if robust:
            # Positions get the same floor, as the arc a rotation by it sweeps at the part's distance.
            reach = max(np.linalg.norm(pos, axis=1).max(), 1e-9)
            floor = np.radians(_MIN_THRESHOLD_DEG) * np.array([1.0, reach])

            def threshold(norms: np.ndarray, floor: np.ndarray = floor) -> np.ndarray:
                return np.maximum(_HUBER_MEDIANS * np.median(norms, axis=0), floor)
        rot_s, pos_s = _smooth_trajectory(rot, pos, lam, threshold)
        out[k, 1:, :3, :3] = rot_s[1:]
        out[k, 1:, :3, 3] = pos_s[1:] - rot_s[1:] @ centers[k]
    return out


def jitter(poses: np.ndarray) -> np.ndarray:
    """RMS rotation jitter of each part, in degrees per frame².

    The norm of the second difference of the rotation, ``|ω_t - ω_{t-1}|``
    with ``ω_t = log(R_tᵀ R_{t+1})``, averaged (RMS) over frames: zero for
    rotation at constant angular velocity, about √6 times the per-frame noise
    for white rotation noise.

    Parameters
    ----------
    poses : ndarray, shape (K, T, 4, 4)

    Returns
    -------
    ndarray, shape (K,)
        Zeros when T < 3.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 4 or poses.shape[2:] != (4, 4):
        raise InputError(f"poses must have shape (K, T, 4, 4), got {poses.shape}")
    rot = poses[..., :3, :3]
    omega = matrix_to_axis_angle(np.swapaxes(rot[:, :-1], -1, -2) @ rot[:, 1:])  # (K, T-1, 3)
    second = np.linalg.norm(np.diff(omega, axis=1), axis=-1)  # (K, T-2)
    if second.shape[1] == 0:
        return np.zeros(poses.shape[0])
    return np.degrees(np.sqrt((second**2).mean(axis=1)))


def _hat(v: np.ndarray) -> np.ndarray:
    """Skew matrices (..., 3, 3) of vectors (..., 3): ``hat(a) @ b = a × b``."""
    z = np.zeros(v.shape[:-1])
    return np.stack([z, -v[..., 2], v[..., 1], v[..., 2], z, -v[..., 0], -v[..., 1], v[..., 0], z],
                    axis=-1).reshape(v.shape[:-1] + (3, 3))


def _right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian of SO(3) at axis-angle ``phi`` (..., 3) → (..., 3, 3).

    ``log(exp(φ) exp(δ)) ≈ φ + J_r⁻¹(φ) δ`` for small δ.
    """
    # Clamped below π, where J_r⁻¹ is singular (only far outliers get there).
    theta = np.minimum(np.linalg.norm(phi, axis=-1), 3.0)[..., None, None]
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    coef = np.where(small, 1.0 / 12.0 + theta**2 / 720.0,
                    1.0 / safe**2 - (1.0 + np.cos(safe)) / (2.0 * safe * np.sin(safe)))
    w = _hat(phi)
    return np.eye(3) + 0.5 * w + coef * (w @ w)


def _block_matrix(rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray, shape: tuple[int, int]) -> sp.csr_array:
    """Sparse matrix of 6x6 ``blocks`` (N, 6, 6) at block positions ``rows``, ``cols`` (N,)."""
    i = 6 * rows[:, None, None] + np.arange(6)[None, :, None]
    j = 6 * cols[:, None, None] + np.arange(6)[None, None, :]
    i, j = np.broadcast_arrays(i, j)
    return sp.csr_array((blocks.ravel(), (i.ravel(), j.ravel())), shape=(6 * shape[0], 6 * shape[1]))


def _blockdiag(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per-frame 6x6 blocks diag(a, b) from (N, 3, 3) rotation and position blocks."""
    out = np.zeros(a.shape[:-2] + (6, 6))
    out[..., :3, :3], out[..., 3:, 3:] = a, b
    return out


def _residuals(rot: np.ndarray, pos: np.ndarray, rot_s: np.ndarray, pos_s: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Data residuals (T-1, 6) of frames 1.., velocities ω̄ (T-1, 3) and second differences (T-2, 6)."""
    e = np.concatenate([matrix_to_axis_angle(np.swapaxes(rot[1:], -1, -2) @ rot_s[1:]), pos_s[1:] - pos[1:]], axis=1)
    omega = matrix_to_axis_angle(np.swapaxes(rot_s[:-1], -1, -2) @ rot_s[1:])
    vel = np.concatenate([omega, np.diff(pos_s, axis=0)], axis=1)
    return e, omega, np.diff(vel, axis=0)


def _objective(e: np.ndarray, second: np.ndarray, lam: float, limit: np.ndarray) -> float:
    """Σ ρ(|e|) + λ Σ |second|², with the Huber loss ρ at thresholds ``limit`` (2,) (rotation, position)."""
    r = np.linalg.norm(e.reshape(-1, 2, 3), axis=-1)
    with np.errstate(invalid="ignore"):  # 2 c r - c² is inf - inf for an infinite threshold, and unused
        rho = np.where(r <= limit, r**2, 2 * limit * r - limit**2)
    return float(rho.sum() + lam * (second**2).sum())


def _huber_newton(e: np.ndarray, limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half the gradient (T-1, 6) and Hessian (T-1, 6, 6) of the Huber data term in the residuals ``e``.

    Below the threshold c, ``e`` and I; beyond it, ``c ê`` and ``(c / r)(I - ê êᵀ)``: the exact
    Hessian, so that iterations converge like Newton's rather than like IRLS with its majorising
    ``(c / r) I``.
    """
    parts = e.reshape(-1, 2, 3)
    r = np.maximum(np.linalg.norm(parts, axis=-1), 1e-300)[..., None]
    unit = parts / r
    far = r > limit[:, None]
    c = np.where(far, limit[:, None], 0.0)  # finite even where the threshold is infinite
    grad = np.where(far, c * unit, parts)
    scale = np.where(far, c / r, 1.0)[..., None]
    radial = np.where(far, 1.0, 0.0)[..., None] * unit[..., :, None] * unit[..., None, :]
    hess_blocks = scale * (np.eye(3) - radial)  # (T-1, 2, 3, 3)
    return grad.reshape(-1, 6), _blockdiag(hess_blocks[:, 0], hess_blocks[:, 1])


def _smooth_trajectory(rot: np.ndarray, pos: np.ndarray, lam: float,
                       threshold: Callable[[np.ndarray], np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton solver of the module's objective for one part, with a backtracking line search.

    Parameters
    ----------
    rot : (T, 3, 3) measured rotations; pos : (T, 3) measured centre positions.
    lam : float
        Weight λ of the second-difference term.
    threshold : callable or None
        Residual norms (T-1, 2) of frames 1.. (rotation in radians, position)
        → Huber thresholds (2,), evaluated once on the least-squares
        solution's residuals; None for plain least squares.

    Returns
    -------
    (T, 3, 3) rotations and (T, 3) positions; frame 0 unchanged.
    """
    t_count = len(rot)
    steps = np.arange(t_count - 1)
    eye = np.broadcast_to(np.eye(3), (t_count - 1, 3, 3))
    # Second differences of the T-1 per-step velocities.
    first_diff = sp.kron(sp.diags_array([-np.ones(t_count - 2), np.ones(t_count - 2)], offsets=[0, 1],
                                        shape=(t_count - 2, t_count - 1)), sp.eye_array(6)).tocsr()
    rot_s, pos_s = rot.copy(), pos.copy()
    limit = np.full(2, np.inf)
    for iteration in range(_MAX_ITERATIONS):
        e, omega, second = _residuals(rot, pos, rot_s, pos_s)
        if threshold is not None and iteration == 1:  # the first step solved plain least squares
            limit = np.asarray(threshold(np.linalg.norm(e.reshape(-1, 2, 3), axis=-1)), dtype=np.float64)
        grad, hess = _huber_newton(e, limit)
        # Linearised in δ (R̄ ← R̄ exp(δ)): e_t ≈ ē_t + J_r⁻¹(ē_t) δ_t, and the velocities
        # ω_t ≈ ω̄_t + B_t (δ_{t+1} - A_tᵀ δ_t), with A_t = R̄_tᵀ R̄_{t+1}, B_t = J_r⁻¹(ω̄_t).
        jd = _block_matrix(steps, steps, _blockdiag(_right_jacobian_inv(e[:, :3]), eye), (t_count - 1,) * 2)
        a = np.swapaxes(rot_s[:-1], -1, -2) @ rot_s[1:]
        b = _right_jacobian_inv(omega)
        jv = (_block_matrix(steps, steps + 1, _blockdiag(b, eye), (t_count - 1, t_count))
              + _block_matrix(steps, steps, _blockdiag(-b @ np.swapaxes(a, -1, -2), -eye), (t_count - 1, t_count)))
        js = (first_diff @ jv)[:, 6:]  # frame 0 is fixed: drop its columns
        lhs = jd.T @ _block_matrix(steps, steps, hess, (t_count - 1,) * 2) @ jd + lam * (js.T @ js)
        rhs = -(jd.T @ grad.ravel() + lam * (js.T @ second.ravel()))
        delta = spsolve(sp.csc_array(lhs), rhs).reshape(t_count - 1, 6)
        current = _objective(e, second, lam, limit)
        for _ in range(30):  # halve the step until the objective does not increase
            rot_new = np.concatenate([rot_s[:1], rot_s[1:] @ axis_angle_to_matrix(delta[:, :3])])
            pos_new = np.concatenate([pos_s[:1], pos_s[1:] + delta[:, 3:]])
            e_new, _, second_new = _residuals(rot, pos, rot_new, pos_new)
            if _objective(e_new, second_new, lam, limit) <= current:
                break
            delta = delta / 2
        else:
            break
        rot_s, pos_s = rot_new, pos_new
        if np.abs(delta).max() < _TOLERANCE and iteration > 0:
            break
    return rot_s, pos_s
