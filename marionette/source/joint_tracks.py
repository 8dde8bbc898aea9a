"""What the joint models of a part (:mod:`.hinge`, :mod:`.slider`) share: a one-degree-of-freedom joint fitted to
the part's tracks by variable projection.

Each candidate motion's reprojection errors are taken with every track's 3D
point re-solved for it (linear triangulation and Gauss-Newton steps, compiled,
with no LAPACK call so the bits do not follow the BLAS kernel); the joint's
parameters (its axis or direction and one value per key frame) are fitted by
robust least squares on them, tracks that do not follow the joint dropped and
the fit repeated (:func:`fit_joint_tracks`); each other frame's value is then
fitted alone (:func:`fit_frame_parameter`).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy.optimize import least_squares
from threadpoolctl import threadpool_limits

__all__ = ["Observations", "fit_joint_tracks", "fit_frame_parameter", "key_frames", "surface_scale"]

#: Cauchy loss scale of the reprojection residuals, pixels.
_LOSS_SCALE = 0.5
#: Weight of the scale gauge: a joint 1 % larger or smaller than the free fit put it (a hinge's axis 1 % nearer
#: or farther, a slider's travel 1 % longer or shorter) costs what a 0.01 px residual does (it only has to hold
#: the scale where the images leave it free).
_GAUGE_WEIGHT = 1.0
#: The fit uses at most this many tracks (the longest), plus the longest few seen in each frame.
_MAX_TRACKS = 400
_TRACKS_PER_FRAME = 16
#: At most this many evenly spaced frames in the joint fit of the axis and the per-frame values.
_KEY_FRAMES = 24
#: A point nearer than this (in the poses' units) to the camera plane counts as behind it, and its observations
#: as this many pixels off.
_MIN_DEPTH = 1e-6
_BEHIND_PX = 1e3
#: A track whose median residual under the first fit exceeds this (pixels) is dropped before the second.
_DROP_PX = 1.0
#: A track that never moves further than this (pixels) from where frame 0 sees it tells nothing of a joint's scale.
_STILL_PX = 1.5
#: ... nor one lost before the joint reaches this share of its range.
_FAR_SHARE = 0.25


class Observations:
    """The visible positions of the tracks ``keep`` (M,) bool, flattened track by track: frame ``t`` (N,),
    track ``m`` (N,) (0..M'-1 among those kept), pixel ``uv`` (N, 2)."""

    def __init__(self, uv: np.ndarray, visible: np.ndarray, keep: np.ndarray) -> None:
        m, t = np.nonzero(visible[:, keep].T)  # grouped by track, so that per-track sums are segment sums
        self.t, self.m, self.num_points = t, m, int(keep.sum())
        self.uv = uv[:, keep][t, m].astype(np.float64)
        self._starts = np.searchsorted(m, np.arange(self.num_points))

    def residuals(self, poses: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) reprojection errors under ``poses`` (T, 4, 4), each track's frame-0 point re-solved (linear
        triangulation, then three Gauss-Newton steps on the reprojection error), and those points (M, 3)."""
        return _solve_points(self.t, self.uv, self._starts, np.ascontiguousarray(poses[:, :3]), k, 3)

    def per_track_median(self, errors: np.ndarray) -> np.ndarray:
        """(M,) median of each track's per-observation ``errors`` (N,)."""
        return np.array([np.median(e) for e in np.split(errors, self._starts[1:])])


@njit(cache=True)
def _solve3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for a symmetric positive (semi-)definite 3x3 ``a``, by the adjugate (no LAPACK: the same
    bits on every BLAS kernel); a singular ``a`` gives zeros."""
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    out = np.zeros(3)
    if abs(det) < 1e-300:
        return out
    inv = np.empty((3, 3))
    inv[0, 0], inv[1, 0], inv[2, 0] = c00, c01, c02
    inv[0, 1] = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    inv[1, 1] = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    inv[2, 1] = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    inv[0, 2] = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    inv[1, 2] = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    inv[2, 2] = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    for i in range(3):
        out[i] = (inv[i, 0] * b[0] + inv[i, 1] * b[1] + inv[i, 2] * b[2]) / det
    return out


@njit(cache=True, error_model="numpy")
def _solve_points(t: np.ndarray, uv: np.ndarray, starts: np.ndarray, poses: np.ndarray, k: np.ndarray,
                  steps: int) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) points from observations grouped by track (track m: ``starts[m]`` up to the next start) of frames
    ``t`` (N,) at pixels ``uv`` (N, 2) under ``poses`` (T, 3, 4): linear triangulation, then ``steps``
    Gauss-Newton steps; and the (N, 2) reprojection errors they leave."""
    num_points, n = len(starts), len(t)
    points, errors = np.zeros((num_points, 3)), np.zeros((n, 2))
    proj, du, dv = np.empty(4), np.empty(3), np.empty(3)
    for m in range(num_points):
        stop = starts[m + 1] if m + 1 < num_points else n
        normal, rhs = np.zeros((3, 3)), np.zeros(3)
        for i in range(starts[m], stop):
            r = poses[t[i]]
            for row in range(2):  # with p = K [R | t]: u (p2 . X) - p0 . X = 0, v (p2 . X) - p1 . X = 0
                for j in range(4):
                    proj[j] = uv[i, row] * r[2, j] - (k[row, 0] * r[0, j] + k[row, 1] * r[1, j] + k[row, 2] * r[2, j])
                for a in range(3):
                    rhs[a] -= proj[a] * proj[3]
                    for b in range(3):
                        normal[a, b] += proj[a] * proj[b]
        x = _solve3(normal, rhs)
        for _ in range(steps):
            normal, grad = np.zeros((3, 3)), np.zeros(3)
            for i in range(starts[m], stop):
                r = poses[t[i]]
                cx = r[0, 0] * x[0] + r[0, 1] * x[1] + r[0, 2] * x[2] + r[0, 3]
                cy = r[1, 0] * x[0] + r[1, 1] * x[1] + r[1, 2] * x[2] + r[1, 3]
                cz = r[2, 0] * x[0] + r[2, 1] * x[1] + r[2, 2] * x[2] + r[2, 3]
                if cz < _MIN_DEPTH:  # behind the camera: no say in the step
                    continue
                res_u = k[0, 0] * cx / cz + k[0, 2] - uv[i, 0]
                res_v = k[1, 1] * cy / cz + k[1, 2] - uv[i, 1]
                for a in range(3):  # d pixel / d point = d pixel / d camera point @ rotation
                    du[a] = k[0, 0] * (r[0, a] - cx / cz * r[2, a]) / cz
                    dv[a] = k[1, 1] * (r[1, a] - cy / cz * r[2, a]) / cz
                for a in range(3):
                    grad[a] += du[a] * res_u + dv[a] * res_v
                    for b in range(3):
                        normal[a, b] += du[a] * du[b] + dv[a] * dv[b]
            step = _solve3(normal, grad)
            for a in range(3):
                x[a] -= step[a]
        # Element by element: an array store compiles numba's shape-error formatting (2.6 s of 5.9 s).
        points[m, 0], points[m, 1], points[m, 2] = x[0], x[1], x[2]
        for i in range(starts[m], stop):
            r = poses[t[i]]
            cx = r[0, 0] * x[0] + r[0, 1] * x[1] + r[0, 2] * x[2] + r[0, 3]
            cy = r[1, 0] * x[0] + r[1, 1] * x[1] + r[1, 2] * x[2] + r[1, 3]
            cz = r[2, 0] * x[0] + r[2, 1] * x[1] + r[2, 2] * x[2] + r[2, 3]
            if cz < _MIN_DEPTH:
                errors[i, 0] = errors[i, 1] = _BEHIND_PX
            else:
                errors[i, 0] = k[0, 0] * cx / cz + k[0, 2] - uv[i, 0]
                errors[i, 1] = k[1, 1] * cy / cz + k[1, 2] - uv[i, 1]
    return errors, points


def fit_joint_tracks(uv: np.ndarray, visible: np.ndarray, free_poses: np.ndarray, k: np.ndarray, poses,
                     gauge, start: np.ndarray, min_track_frames: int, max_evaluations: int):
    """The parameters of a one-degree-of-freedom joint fitted to tracks ``uv`` (T, M, 2) seen where ``visible``
    (T, M), by robust least squares of their reprojection errors (each track's point re-solved), then again
    without the tracks that do not follow it. ``poses(p)``: (T, 4, 4) poses of the parameters ``p`` (from
    ``start``); ``gauge(p)``: a residual holding the scale the images leave free.

    Returns (p, the tracks' points (M', 3), which tracks ((M,) bool), how many were dropped), or None when
    fewer than 6 tracks follow the joint.
    """
    def residuals(p: np.ndarray, data: Observations) -> np.ndarray:
        return np.r_[data.residuals(poses(p), k)[0].ravel(), _GAUGE_WEIGHT * gauge(p)]

    def robust_fit(start: np.ndarray, data: Observations) -> np.ndarray:
        with threadpool_limits(limits=1, user_api="blas"):  # the same bits whatever the BLAS thread count
            return least_squares(residuals, start, args=(data,), loss="cauchy", f_scale=_LOSS_SCALE,
                                 max_nfev=max_evaluations).x

    sample = _sample_tracks(visible, visible.sum(axis=0) >= min_track_frames)
    if sample.sum() < 6:
        return None
    obs = Observations(uv, visible, sample)
    fit = robust_fit(start, obs)
    errors = np.linalg.norm(residuals(fit, obs)[:-1].reshape(-1, 2), axis=1)
    free_errors = np.linalg.norm(obs.residuals(free_poses, k)[0], axis=1)
    follows = obs.per_track_median(errors) < _DROP_PX
    if follows.sum() < 6:
        return None
    tracks = sample.copy()
    if np.median(errors) <= 2 * np.median(free_errors) + _DROP_PX:  # else plainly no joint: not worth refining
        tracks[np.flatnonzero(sample)[~follows]] = False
        obs = Observations(uv, visible, tracks)
        fit = robust_fit(fit, obs)
    return fit, obs.residuals(poses(fit), k)[1], tracks, int((sample & ~tracks).sum())


def fit_frame_parameter(uv: np.ndarray, visible: np.ndarray, points: np.ndarray, pose, start: float,
                        k: np.ndarray) -> float:
    """The one parameter (an angle, a distance) whose ``pose(value)`` (4, 4) best places ``points`` (M, 3) on one
    frame's tracks ``uv`` (M, 2) where ``visible`` (M,); ``start`` when fewer than 3 are seen."""
    if visible.sum() < 3:
        return start
    seen, observed = points[visible], uv[visible].astype(np.float64)

    def residuals(value: np.ndarray) -> np.ndarray:
        moved = pose(value)
        cam = seen @ moved[:3, :3].T + moved[:3, 3]
        return (cam[:, :2] / cam[:, 2:] * np.diag(k)[:2] + k[:2, 2] - observed).ravel()

    return float(least_squares(residuals, [start], loss="cauchy", f_scale=_LOSS_SCALE).x[0])


def surface_scale(poses, values: np.ndarray, uv: np.ndarray, visible: np.ndarray, k: np.ndarray,
                  surface: np.ndarray) -> float | None:
    """The factor ``f`` whose ``poses(f)`` (T, 4, 4) best move the points that ``surface`` (H, W) (frame-0 depth,
    NaN off the object) puts under a part's tracks ``uv`` (T, M, 2) onto them where ``visible`` (T, M) (robust
    least squares), from the tracks that move and are seen at frame 0 and at a frame where the joint's
    ``values`` (T,) (angles, distances) reach a quarter of their range; None under 6 such tracks.

    On a still body a part and its joint scaled together about the camera (a slider's travel, a hinge's axis)
    change no image, and each track's own depth trades against the scale, so the tracks alone do not tell it;
    the body's surface, which the part is part of at frame 0, does. A track that barely moves (the body's, taken
    for the part's, or one lost early) would pull towards no motion."""
    h, w = surface.shape
    pixel = np.round(np.nan_to_num(uv[0])).astype(int)
    moved = np.where(visible[..., None], np.abs(np.nan_to_num(uv - uv[0])), 0.0).max(axis=(0, 2))
    far = np.abs(values) >= _FAR_SHARE * np.abs(values).max()
    across = visible[0] & visible[far].any(axis=0) & (moved > _STILL_PX)
    inside = across & (pixel[:, 0] >= 0) & (pixel[:, 0] < w) & (pixel[:, 1] >= 0) & (pixel[:, 1] < h)
    depth = np.full(len(inside), np.nan)
    depth[inside] = surface[pixel[inside, 1], pixel[inside, 0]]
    seen = np.isfinite(depth) & (depth > 0)
    if seen.sum() < 6:
        return None
    rays = np.c_[uv[0, seen], np.ones(seen.sum())] @ np.linalg.inv(k).T
    points, observed, where = rays * depth[seen, None], uv[:, seen], visible[:, seen]

    def residuals(factor: np.ndarray) -> np.ndarray:
        scaled = poses(factor[0])
        cam = np.einsum("tij,mj->tmi", scaled[:, :3, :3], points) + scaled[:, None, :3, 3]
        return (cam[..., :2] / cam[..., 2:] * np.diag(k)[:2] + k[:2, 2] - observed)[where].ravel()

    with threadpool_limits(limits=1, user_api="blas"):
        return float(least_squares(residuals, [1.0], loss="cauchy", f_scale=_LOSS_SCALE, bounds=(0.2, 5.0)).x[0])


def key_frames(count: int) -> np.ndarray:
    """Indices of at most ``_KEY_FRAMES`` evenly spaced frames of ``count``, the first and last among them (the
    joint's fit grows with the frames squared)."""
    return np.unique(np.linspace(0, count - 1, min(count, _KEY_FRAMES)).round().astype(int))


def _sample_tracks(visible: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(M,) bool: the longest of the tracks ``keep``, at most :data:`_MAX_TRACKS`, and the
    :data:`_TRACKS_PER_FRAME` longest seen in each frame (so no frame is left without)."""
    lengths = np.where(keep, visible.sum(axis=0), 0)
    order = np.lexsort((np.arange(len(lengths)), -lengths))  # longest first, ties by index
    chosen = np.zeros(len(lengths), bool)
    chosen[order[:_MAX_TRACKS]] = True
    for seen in visible[:, order]:
        chosen[order[seen][:_TRACKS_PER_FRAME]] = True
    return chosen & keep
