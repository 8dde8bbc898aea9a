"""Normal equations of a part's bundle adjustment (:mod:`.parts`), as compiled loops.

A part's motion is fitted by Levenberg–Marquardt on T poses and N points
observed in normalised image coordinates (``x = π(R_t X_n + T_t)``, ``π`` the
perspective division with depths floored at 1e-2). Each residual depends on
one pose and one point, so the Gauss–Newton matrix is made of blocks: ``U_t``
(6 × 6) per pose, ``V_n`` (3 × 3) per point and ``W_tn = J_tᵀ P_tn`` (6 × 3)
per observation. The points are eliminated (Schur complement), which leaves
the reduced camera system ``S = U - Σ_n W_n V_n⁻¹ W_nᵀ`` (6T × 6T). Also here,
the two smaller fits around it: one frame's pose from known points
(:func:`refine_pose`, the frame-by-frame start) and each track's point from
known poses (:func:`triangulate_points`, which scores a motion on tracks).

Written as loops over the observations, these take a few stacked 2 × 6 and
2 × 3 products per observation instead of numpy's many small batched matrix
products (3-4 times the time on the part fits' sizes), and their rounding does
not depend on the BLAS kernel of the machine.
"""

from __future__ import annotations

import numba
import numpy as np

from .spd6 import cholesky6, cholesky6_solve

__all__ = ["normal_blocks", "reduced_system", "point_steps", "reprojection_cost", "refine_pose", "triangulate_points"]

_MIN_DEPTH = 1e-2


@numba.njit(cache=True)
def _moved(rot, trans, point, cam):
    """``cam`` = rot (3, 3) @ point (3,) + trans (3,), written out (no BLAS call for a 3-vector)."""
    for i in range(3):
        cam[i] = rot[i, 0] * point[0] + rot[i, 1] * point[1] + rot[i, 2] * point[2] + trans[i]


@numba.njit(cache=True)
def _observation(rot, trans, point, obs, cam, jc, jp):
    """Residual (2,) of one observation, and its pose (2, 6) and point (2, 3) Jacobians into ``jc``, ``jp``."""
    _moved(rot, trans, point, cam)
    z = max(cam[2], _MIN_DEPTH)
    x, y = cam[0] / z, cam[1] / z
    a, b, c = 1.0 / z, -x / z, -y / z  # the projection's Jacobian is [[a, 0, b], [0, a, c]]
    # Left perturbation of the pose: rotation (ω × cam), then translation.
    jc[0, 0], jc[0, 1], jc[0, 2] = b * cam[1], a * cam[2] - b * cam[0], -a * cam[1]
    jc[1, 0], jc[1, 1], jc[1, 2] = c * cam[1] - a * cam[2], -c * cam[0], a * cam[0]
    jc[0, 3], jc[0, 4], jc[0, 5] = a, 0.0, b
    jc[1, 3], jc[1, 4], jc[1, 5] = 0.0, a, c
    for k in range(3):
        jp[0, k] = a * rot[0, k] + b * rot[2, k]
        jp[1, k] = a * rot[1, k] + c * rot[2, k]
    return obs[0] - x, obs[1] - y


@numba.njit(cache=True)
def normal_blocks(rot, trans, points, prior, obs, vis, prior_weight):
    """Gauss–Newton blocks and gradients of ``Σ |obs - π(R X + T)|² + prior_weight Σ |X - prior|²``.

    rot (T, 3, 3), trans (T, 3); points, prior (N, 3); obs (T, N, 2); vis (T, N) bool.
    Returns u (T, 6, 6), v (N, 3, 3), w (T, N, 6, 3) (zero where not visible),
    g_cam (T, 6) and g_pt (N, 3): minus half the gradient, so that a Gauss–Newton
    step solves ``[[U, W], [Wᵀ, V]] d = g``.
    """
    num_frames, n = vis.shape
    u = np.zeros((num_frames, 6, 6))
    v = np.zeros((n, 3, 3))
    w = np.zeros((num_frames, n, 6, 3))
    g_cam = np.zeros((num_frames, 6))
    g_pt = np.zeros((n, 3))
    cam, jc, jp = np.empty(3), np.empty((2, 6)), np.empty((2, 3))
    for m in range(n):
        for i in range(3):
            v[m, i, i] = prior_weight
            g_pt[m, i] = prior_weight * (prior[m, i] - points[m, i])
    for t in range(num_frames):
        for m in range(n):
            if not vis[t, m]:
                continue
            r0, r1 = _observation(rot[t], trans[t], points[m], obs[t, m], cam, jc, jp)
            for i in range(6):
                g_cam[t, i] += jc[0, i] * r0 + jc[1, i] * r1
                for j in range(6):
                    u[t, i, j] += jc[0, i] * jc[0, j] + jc[1, i] * jc[1, j]
                for j in range(3):
                    w[t, m, i, j] = jc[0, i] * jp[0, j] + jc[1, i] * jp[1, j]
            for i in range(3):
                g_pt[m, i] += jp[0, i] * r0 + jp[1, i] * r1
                for j in range(3):
                    v[m, i, j] += jp[0, i] * jp[0, j] + jp[1, i] * jp[1, j]
    return u, v, w, g_cam, g_pt


@numba.njit(cache=True)
def _inverse3(m, out):
    """``out`` = inverse of the 3 × 3 matrix ``m``, by its adjugate."""
    for i in range(3):
        for j in range(3):
            r1, r2, c1, c2 = (j + 1) % 3, (j + 2) % 3, (i + 1) % 3, (i + 2) % 3
            out[i, j] = m[r1, c1] * m[r2, c2] - m[r1, c2] * m[r2, c1]
    det = m[0, 0] * out[0, 0] + m[0, 1] * out[1, 0] + m[0, 2] * out[2, 0]
    for i in range(3):
        for j in range(3):
            out[i, j] /= det


@numba.njit(cache=True)
def reduced_system(u, v, w, vis, g_cam, g_pt, damping):
    """The reduced camera system of a damped step: ``S d_cam = rhs``.

    Blocks from :func:`normal_blocks`; each diagonal block ``B`` is damped as
    ``B + damping (diag(B) + 1e-12)`` (Marquardt). Returns S (6T, 6T), rhs (6T,)
    and the damped points' inverses vinv (N, 3, 3), for :func:`point_steps`.
    """
    num_frames, n = vis.shape
    s = np.zeros((6 * num_frames, 6 * num_frames))
    rhs = g_cam.copy().reshape(6 * num_frames)
    vinv = np.empty((n, 3, 3))
    damped = np.empty((3, 3))
    y = np.empty((num_frames, 6, 3))  # W_tn V_n⁻¹ of the frames that see point n
    seen = np.empty(num_frames, np.int64)
    for m in range(n):
        for i in range(3):
            for j in range(3):
                damped[i, j] = v[m, i, j]
            damped[i, i] += damping * v[m, i, i]
        _inverse3(damped, vinv[m])
        count = 0
        for t in range(num_frames):
            if vis[t, m]:
                seen[count] = t
                count += 1
        for a in range(count):
            t = seen[a]
            for i in range(6):
                for j in range(3):
                    y[a, i, j] = w[t, m, i, 0] * vinv[m, 0, j] + w[t, m, i, 1] * vinv[m, 1, j] \
                        + w[t, m, i, 2] * vinv[m, 2, j]
                rhs[6 * t + i] -= y[a, i, 0] * g_pt[m, 0] + y[a, i, 1] * g_pt[m, 1] + y[a, i, 2] * g_pt[m, 2]
        for a in range(count):
            ta = seen[a]
            for b in range(a, count):
                tb = seen[b]
                for i in range(6):  # the upper blocks only (ta <= tb); the lower ones are mirrored below
                    for j in range(6):
                        s[6 * ta + i, 6 * tb + j] -= y[a, i, 0] * w[tb, m, j, 0] + y[a, i, 1] * w[tb, m, j, 1] \
                            + y[a, i, 2] * w[tb, m, j, 2]
    for ta in range(num_frames):
        for tb in range(ta + 1, num_frames):
            for i in range(6):
                for j in range(6):
                    s[6 * tb + j, 6 * ta + i] = s[6 * ta + i, 6 * tb + j]
    for t in range(num_frames):
        for i in range(6):
            for j in range(6):
                s[6 * t + i, 6 * t + j] += u[t, i, j]
            s[6 * t + i, 6 * t + i] += damping * (u[t, i, i] + 1e-12)
    return s, rhs, vinv


@numba.njit(cache=True)
def point_steps(vinv, w, vis, g_pt, d_cam):
    """Back-substitution: each point's step ``V_n⁻¹ (g_n - Σ_t W_tnᵀ d_t)`` (N, 3), given d_cam (T, 6)."""
    num_frames, n = vis.shape
    out = np.empty((n, 3))
    rest = np.empty(3)
    for m in range(n):
        for j in range(3):
            rest[j] = g_pt[m, j]
        for t in range(num_frames):
            if vis[t, m]:
                for j in range(3):
                    for i in range(6):
                        rest[j] -= w[t, m, i, j] * d_cam[t, i]
        for i in range(3):
            out[m, i] = vinv[m, i, 0] * rest[0] + vinv[m, i, 1] * rest[1] + vinv[m, i, 2] * rest[2]
    return out


@numba.njit(cache=True)
def reprojection_cost(rot, trans, points, prior, obs, vis, prior_weight):
    """``Σ_visible |obs - π(R_t X_n + T_t)|² + prior_weight Σ_n |X_n - prior_n|²``
    (arguments as :func:`normal_blocks`)."""
    num_frames, n = vis.shape
    total = 0.0
    cam = np.empty(3)
    for t in range(num_frames):
        for m in range(n):
            if not vis[t, m]:
                continue
            _moved(rot[t], trans[t], points[m], cam)
            z = max(cam[2], _MIN_DEPTH)
            total += (obs[t, m, 0] - cam[0] / z) ** 2 + (obs[t, m, 1] - cam[1] / z) ** 2
    for m in range(n):
        for i in range(3):
            total += prior_weight * (points[m, i] - prior[m, i]) ** 2
    return total


@numba.njit(cache=True)
def _rodrigues(v, out):
    """``out`` (3, 3) = the rotation of axis-angle vector ``v`` (3,) (series below 1e-8 rad)."""
    theta = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if theta < 1e-8:
        a, b = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    else:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / (theta * theta)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    for i in range(3):
        for j in range(3):
            kk = k[i, 0] * k[0, j] + k[i, 1] * k[1, j] + k[i, 2] * k[2, j]
            out[i, j] = (1.0 if i == j else 0.0) + a * k[i, j] + b * kk


@numba.njit(cache=True)
def refine_pose(rot, trans, points, obs, iterations):
    """Gauss–Newton on one frame's pose (rot (3, 3), trans (3,), updated in place) from the points
    (N, 3) observed at ``obs`` (N, 2, normalised); a ridge of 1e-6 of the trace keeps the step defined."""
    cam, jc, jp = np.empty(3), np.empty((2, 6)), np.empty((2, 3))
    hess, grad, turn = np.empty((6, 6)), np.empty(6), np.empty((3, 3))
    for _ in range(iterations):
        hess[:] = 0.0
        grad[:] = 0.0
        for m in range(len(points)):
            r0, r1 = _observation(rot, trans, points[m], obs[m], cam, jc, jp)
            for i in range(6):
                grad[i] += jc[0, i] * r0 + jc[1, i] * r1
                for j in range(6):
                    hess[i, j] += jc[0, i] * jc[0, j] + jc[1, i] * jc[1, j]
        ridge = 1e-6 * (hess[0, 0] + hess[1, 1] + hess[2, 2] + hess[3, 3] + hess[4, 4] + hess[5, 5]) + 1e-12
        for i in range(6):
            hess[i, i] += ridge
        step = cholesky6_solve(cholesky6(hess), grad)
        _rodrigues(step[:3], turn)
        _turn_pose(turn, step[3:], rot, trans)


@numba.njit(cache=True)
def _turn_pose(turn, shift, rot, trans):
    """Left update of a pose in place: ``rot ← turn rot``, ``trans ← turn trans + shift`` (products written out)."""
    old_rot, old_trans = rot.copy(), trans.copy()
    for i in range(3):
        for j in range(3):
            rot[i, j] = turn[i, 0] * old_rot[0, j] + turn[i, 1] * old_rot[1, j] + turn[i, 2] * old_rot[2, j]
        trans[i] = turn[i, 0] * old_trans[0] + turn[i, 1] * old_trans[1] + turn[i, 2] * old_trans[2] + shift[i]


@numba.njit(cache=True)
def triangulate_points(rot, trans, prior, obs, vis, prior_weight, iterations):
    """Each track's 3D point under fixed poses, and its squared reprojection errors.

    rot (T, 3, 3), trans (T, 3); prior (M, 3) starting points, held by
    ``prior_weight |X - prior|²``; obs (T, M, 2) normalised; vis (T, M) bool, the
    observations that count. ``iterations`` Gauss–Newton steps per track.
    Returns points (M, 3) and errors (T, M) (0 where not counted).
    """
    num_frames, n = vis.shape
    points = prior.copy()
    err = np.zeros((num_frames, n))
    cam, jc, jp = np.empty(3), np.empty((2, 6)), np.empty((2, 3))
    hess, inv, rhs = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    for m in range(n):
        for _ in range(iterations):
            for i in range(3):
                for j in range(3):
                    hess[i, j] = prior_weight if i == j else 0.0
                rhs[i] = prior_weight * (prior[m, i] - points[m, i])
            for t in range(num_frames):
                if not vis[t, m]:
                    continue
                r0, r1 = _observation(rot[t], trans[t], points[m], obs[t, m], cam, jc, jp)
                for i in range(3):
                    rhs[i] += jp[0, i] * r0 + jp[1, i] * r1
                    for j in range(3):
                        hess[i, j] += jp[0, i] * jp[0, j] + jp[1, i] * jp[1, j]
            _inverse3(hess, inv)
            for i in range(3):
                points[m, i] += inv[i, 0] * rhs[0] + inv[i, 1] * rhs[1] + inv[i, 2] * rhs[2]
        for t in range(num_frames):
            if vis[t, m]:
                _moved(rot[t], trans[t], points[m], cam)
                z = max(cam[2], _MIN_DEPTH)
                err[t, m] = (obs[t, m, 0] - cam[0] / z) ** 2 + (obs[t, m, 1] - cam[1] / z) ** 2
    return points, err
