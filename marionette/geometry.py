"""Rigid-motion helpers on NumPy arrays.

Conventions, stated once: column vectors (``y = R @ x + t``), rotations are
(3, 3) matrices in SO(3), quaternions are stored ``w, x, y, z`` with ``w >= 0``
after conversion from a matrix, axis-angle vectors are ``angle * unit_axis``,
and rigid transforms are (4, 4) homogeneous matrices. Every function accepts
leading batch dimensions ``...``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "quaternion_multiply",
    "skew",
    "rodrigues_terms",
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "so3_left_jacobian",
    "rotation_angle_deg",
    "make_transform",
    "invert_transform",
    "transform_points",
    "umeyama",
    "rotation_between_directions",
    "se3_interpolate",
]


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``w, x, y, z`` (..., 4) → rotation matrices (..., 3, 3).

    The input is normalised first, so any non-zero quaternion is accepted.
    """
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products ``a ⊗ b`` of quaternions ``w, x, y, z`` (..., 4), broadcast.

    For unit quaternions, ``a ⊗ b`` is the rotation ``R(a) R(b)``.
    """
    a, b = np.asarray(a), np.asarray(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def matrix_to_quaternion(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) → unit quaternions ``w, x, y, z`` (..., 4), ``w >= 0``.

    Uses the largest of the four candidate denominators (Shepperd's method), so
    rotations by π are handled without loss of precision.
    """
    m = np.asarray(m, dtype=np.float64)
    batch = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    # Candidate 4*q_i^2 for i = w, x, y, z.
    diag = np.stack(
        [1 + tr, 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2],
         1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2], 1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2]],
        axis=1,
    )
    best = np.argmax(diag, axis=1)
    q = np.empty((m.shape[0], 4))
    r = np.arange(m.shape[0])
    s = 2.0 * np.sqrt(np.maximum(diag[r, best], 1e-300))
    # Off-diagonal sums and differences give the other three components.
    d21, d02, d10 = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    s10, s02, s21 = m[:, 1, 0] + m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 2, 1] + m[:, 1, 2]
    cand = [
        np.stack([s / 4, d21 / s, d02 / s, d10 / s], axis=1),
        np.stack([d21 / s, s / 4, s10 / s, s02 / s], axis=1),
        np.stack([d02 / s, s10 / s, s / 4, s21 / s], axis=1),
        np.stack([d10 / s, s02 / s, s21 / s, s / 4], axis=1),
    ]
    for i in range(4):
        q[best == i] = cand[i][best == i]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(batch + (4,))


def skew(v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) → cross-product matrices (..., 3, 3): ``skew(a) @ b == a × b``."""
    k = np.zeros(np.shape(v)[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return k - np.swapaxes(k, -1, -2)


def rodrigues_terms(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The terms of Rodrigues' formula ``R = I + a K + b K²`` for axis-angle vectors v (..., 3): the angles
    θ (..., 1, 1), the cross-product matrices K (..., 3, 3), and a = sin θ / θ, b = (1 - cos θ) / θ² (..., 1, 1)
    (their series near 0)."""
    v = np.asarray(v, dtype=np.float64)
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return theta, skew(v), a, b


def axis_angle_to_matrix(v: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3) → rotation matrices (..., 3, 3) (Rodrigues)."""
    _, k, a, b = rodrigues_terms(v)
    return np.eye(3) + a * k + b * (k @ k)


def so3_left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobians (..., 3, 3) of the rotation exponential at rotation vectors w (..., 3).

    exp(w + δ) ≈ exp(J δ) exp(w).
    """
    w = np.asarray(w, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    small = theta < 1e-6
    theta = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(theta)) / theta**2)
    b = np.where(small, 1 / 6, (theta - np.sin(theta)) / theta**3)
    k = skew(w)
    # (b k) k, not b (k k): the bundle adjustment's poses, and with them the hinge's part count, follow its last bits.
    return np.eye(3) + a * k + b * k @ k


def matrix_to_axis_angle(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) → axis-angle vectors (..., 3), angle in [0, π]."""
    q = matrix_to_quaternion(m)
    xyz = q[..., 1:]
    s = np.linalg.norm(xyz, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < 1e-12
    return np.where(small, 2.0 * xyz, xyz / np.where(small, 1.0, s) * angle)


def rotation_angle_deg(m: np.ndarray) -> np.ndarray:
    """Rotation angle in degrees of rotation matrices (..., 3, 3) → (...)."""
    m = np.asarray(m, dtype=np.float64)
    c = (np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0
    s = np.linalg.norm(matrix_to_axis_angle(m), axis=-1)
    # arccos loses precision near 0; use the axis-angle norm there.
    return np.degrees(np.where(c > 0.99, s, np.arccos(np.clip(c, -1.0, 1.0))))


def make_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Rotation (..., 3, 3) and translation (..., 3) → transform (..., 4, 4)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    translation = np.asarray(translation, dtype=np.float64)
    batch = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros(batch + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def invert_transform(m: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4), using ``R^T`` rather than a general inverse."""
    m = np.asarray(m, dtype=np.float64)
    rt = np.swapaxes(m[..., :3, :3], -1, -2)
    return make_transform(rt, -(rt @ m[..., :3, 3:])[..., 0])


def transform_points(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a transform (4, 4) to points (N, 3) → (N, 3)."""
    m = np.asarray(m, dtype=np.float64)
    return points @ m[:3, :3].T + m[:3, 3]


def umeyama(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None,
            with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity (or rigid) transform mapping ``src`` onto ``dst``.

    Umeyama (1991), as used by Motion Marionette Eq. 3-4: the cross-covariance
    ``H = Σ w (src - src̄)(dst - dst̄)^T``, ``H = U Σ V^T``,
    ``R = V diag(1, 1, det(V U^T)) U^T``, ``δ = dst̄ - s R src̄``.

    Parameters
    ----------
    src, dst : ndarray, shape (N, 3)
        Corresponding points, N >= 3 and not all collinear for a unique answer.
    weights : ndarray, shape (N,), optional
        Non-negative weights; uniform by default.
    with_scale : bool
        Also estimate an isotropic scale ``s`` (1.0 otherwise).

    Returns
    -------
    R : (3, 3), t : (3,), s : float, with ``dst ≈ s R src + t``.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama: src and dst must both be (N, 3), got {src.shape} and {dst.shape}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    h = (xs * w[:, None]).T @ xd
    u, sig, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    corr = np.array([1.0, 1.0, d])
    r = vt.T @ np.diag(corr) @ u.T
    s = 1.0
    if with_scale:
        var = float(w @ (xs**2).sum(axis=1))
        s = float((sig * corr).sum() / var) if var > 0 else 1.0
    return r, mu_d - s * r @ mu_s, s


def rotation_between_directions(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) minimising ``Σ |dst - R src|²`` over direction pairs (..., N, 3) (Kabsch, no centring:
    the directions are seen from one centre)."""
    u, _, vt = np.linalg.svd(np.swapaxes(src, -1, -2) @ dst)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    vt[..., 2, :] *= d[..., None]  # keep det(R) = +1
    return np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)


def se3_interpolate(a: np.ndarray, b: np.ndarray, alpha: float | np.ndarray) -> np.ndarray:
    """Interpolate rigid transforms (4, 4): rotation by slerp, translation linearly.

    ``alpha = 0`` gives ``a``, ``alpha = 1`` gives ``b``; ``alpha`` may be an array
    (...,), giving (..., 4, 4).
    """
    alpha = np.asarray(alpha, dtype=np.float64)
    rel = a[:3, :3].T @ b[:3, :3]
    aa = matrix_to_axis_angle(rel)
    rot = a[:3, :3] @ axis_angle_to_matrix(alpha[..., None] * aa)
    trans = (1 - alpha)[..., None] * a[:3, 3] + alpha[..., None] * b[:3, 3]
    return make_transform(rot, trans)
