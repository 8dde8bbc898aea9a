"""A part hinged on another: its motion as a turn about one fixed axis of the body.

A thin part turning away from the camera (a lid, a door) is where a free
6-DoF pose fit fails: its rotation trades against the depth relief of its
points (the bas-relief ambiguity), and sub-pixel track drift decides the
trade. A hinge leaves the part one degree of freedom per frame, the angle
about an axis fixed in the body, and the shortening of the part's extent
across the axis then pins the angle. The model is fitted by variable
projection: the axis (direction and position, 4 parameters) and the angles
are the unknowns of a robust least-squares problem whose residuals are the
reprojection errors of the part's tracks, each track's 3D point re-solved
for every candidate motion, on evenly spaced key frames; each other frame's
angle is then fitted alone. Tracks that do not follow the fitted hinge (a
few of another part's tracks carry its label near the seam) are dropped and
the fit repeated.

:func:`fit_hinge` starts from the free fit's poses and returns the hinge
model with how well it explains the tracks; the extraction keeps it when it
explains them about as well as the free poses do (the simpler model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from ..geometry import invert_transform, rotation_angle_deg

__all__ = ["HingeFit", "fit_hinge", "hinge_poses"]

#: Cauchy loss scale of the reprojection residuals, pixels.
_LOSS_SCALE = 0.5
#: Weight of the scale gauge: the axis 1 % nearer or farther than the free fit put it costs what a 0.01 px
#: residual does (it only has to hold the scale where the images leave it free).
_GAUGE_WEIGHT = 1.0
#: The fit uses at most this many tracks (the longest), plus the longest few seen in each frame.
_MAX_TRACKS = 400
_TRACKS_PER_FRAME = 16
#: At most this many evenly spaced frames in the joint fit of the axis and the angles.
_KEY_FRAMES = 24
#: A point nearer than this (in the poses' units) to the camera plane counts as behind it, and its observations
#: as this many pixels off.
_MIN_DEPTH = 1e-6
_BEHIND_PX = 1e3
#: A track whose median residual under the first fit exceeds this (pixels) is dropped before the second.
_DROP_PX = 1.0
#: The key frames' fit starts from the free fit's angles times each of these, and the hinge that explains the
#: tracks best is kept. Its cost has several minima where the turn trades against the part's relief, and free
#: angles that differ by a RANSAC inlier can start it in a wrong one; from half the angles, it reaches the true
#: one (docs/benchmarks/suite.md).
_START_SCALES = (1.0, 0.5)


@dataclass(frozen=True)
class HingeFit:
    """A part's motion as a turn about an axis fixed in its body.

    Attributes
    ----------
    poses : (T, 4, 4) float64
        The part's poses, ``body_poses[t] @ turn(axis, angles[t])``.
    axis : (3,) float64
        Unit direction of the hinge axis, in the body's frame-0 coordinates.
    point : (3,) float64
        A point of the axis.
    angles : (T,) float64
        Turn about the axis, radians; 0 at frame 0.
    residual_px : float
        Median reprojection error of the part's tracks under the hinge model (all tracks).
    free_residual_px : float
        The same under the free poses it started from, measured alike.
    dropped : int
        Tracks left out of the final fit as not following the hinge.
    seen : (T,) int
        Tracks of the final fit seen in each frame: what placed its angle (none: it kept its start).
    """

    poses: np.ndarray
    axis: np.ndarray
    point: np.ndarray
    angles: np.ndarray
    residual_px: float
    free_residual_px: float
    dropped: int
    seen: np.ndarray


def hinge_poses(body_poses: np.ndarray, axis: np.ndarray, point: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(T, 4, 4) poses of a part turning by ``angles`` (T,) about the line ``point + s * axis`` of its body."""
    rot = Rotation.from_rotvec(angles[:, None] * axis).as_matrix()
    turn = np.tile(np.eye(4), (len(angles), 1, 1))
    turn[:, :3, :3] = rot
    turn[:, :3, 3] = point - rot @ point
    return body_poses @ turn


class _Observations:
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


def _initial_hinge(relative: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis direction (3,), axis point (3,) and angles (T,) closest to relative poses (T, 4, 4)."""
    rotvecs = Rotation.from_matrix(relative[:, :3, :3]).as_rotvec()  # (T, 3)
    widest = rotvecs[np.argmax(np.linalg.norm(rotvecs, axis=1))]
    axis = widest / np.linalg.norm(widest)  # a new array: the angles below need that frame's rotation vector
    # Points of the axis stay put: (I - R_t) p = t_t for every frame, in the least-squares sense.
    lhs = np.concatenate(np.eye(3) - relative[1:, :3, :3])
    point = np.linalg.lstsq(lhs, np.concatenate(relative[1:, :3, 3]), rcond=None)[0]
    return axis, point - axis * (point @ axis), rotvecs @ axis


def fit_hinge(uv: np.ndarray, visible: np.ndarray, body_poses: np.ndarray, free_poses: np.ndarray,
              k: np.ndarray, *, min_track_frames: int = 3, max_evaluations: int = 50) -> HingeFit | None:
    """Fit a part's motion as a hinge on its body, starting from its free poses.

    Parameters
    ----------
    uv : (T, M, 2) float
        The part's tracks; ``visible`` (T, M) bool says where they are seen.
    body_poses, free_poses : (T, 4, 4) float64
        Camera-frame poses of the body and of the part (free 6-DoF fit), identity at frame 0.
    k : (3, 3) intrinsics.
    min_track_frames : int
        Tracks seen in fewer frames say nothing of the motion and are left out.
    max_evaluations : int
        Cap on the least-squares evaluations per fit of the axis.

    Returns
    -------
    HingeFit, or None when the part barely turns relative to the body (under 5°: no axis to find) or has
    fewer than 6 usable tracks.
    """
    relative = invert_transform(body_poses) @ free_poses
    keep = visible.sum(axis=0) >= min_track_frames
    if rotation_angle_deg(relative[:, :3, :3]).max() < 5.0 or keep.sum() < 6:
        return None
    axis0, point0, angles0 = _initial_hinge(relative)
    # The axis and the angles of evenly spaced key frames first (the cost grows with the frames squared),
    # then each other frame's angle alone, about that axis.
    key = np.unique(np.linspace(0, len(body_poses) - 1, min(len(body_poses), _KEY_FRAMES)).round().astype(int))
    every = _Observations(uv, visible, keep)
    free = float(np.median(np.linalg.norm(every.residuals(free_poses, k)[0], axis=1)))
    best = None
    for scale in _START_SCALES:
        fitted = _fit_key_frames(uv[key], visible[key], body_poses[key], free_poses[key], k, axis0, point0,
                                 scale * angles0[key], min_track_frames, max_evaluations)
        if fitted is None:
            continue
        axis, point, key_angles, points, tracks, dropped = fitted
        angles = np.interp(np.arange(len(body_poses)), key, key_angles)
        for t in np.setdiff1d(np.arange(len(body_poses)), key):
            angles[t] = _frame_angle(uv[t, tracks], visible[t, tracks], points, body_poses[t], axis, point,
                                     angles[t], k)
        poses = hinge_poses(body_poses, axis, point, angles)
        hinged = float(np.median(np.linalg.norm(every.residuals(poses, k)[0], axis=1)))
        if best is None or hinged < best.residual_px:
            best = HingeFit(poses, axis, point, angles, hinged, free, dropped, visible[:, tracks].sum(axis=1))
    return best


def _fit_key_frames(uv, visible, body_poses, free_poses, k, axis0, point0, angles0, min_track_frames,
                    max_evaluations):
    """Axis, point, angles (T',), the tracks' points (M', 3) and which tracks they are ((M,) bool), and how many
    tracks were dropped, from the key frames' tracks ``uv`` (T', M, 2); None if too few tracks follow a hinge."""
    e1 = np.cross(axis0, np.eye(3)[np.argmin(np.abs(axis0))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis0, e1)
    # When the body does not move, scaling the part and its axis about the camera changes no image: the
    # axis keeps its free fit's distance from the camera.
    distance = max(float(np.linalg.norm(point0)), 1e-9)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        axis = axis0 + p[0] * e1 + p[1] * e2
        return axis / np.linalg.norm(axis), point0 + p[2] * e1 + p[3] * e2, np.r_[0.0, p[4:]]

    def poses(p: np.ndarray) -> np.ndarray:
        return hinge_poses(body_poses, *unpack(p))

    def gauge(p: np.ndarray) -> float:
        return np.linalg.norm(unpack(p)[1]) / distance - 1.0

    fitted = fit_joint_tracks(uv, visible, free_poses, k, poses, gauge, np.r_[0.0, 0.0, 0.0, 0.0, angles0[1:]],
                              min_track_frames, max_evaluations)
    if fitted is None:
        return None
    p, points, tracks, dropped = fitted
    return (*unpack(p), points, tracks, dropped)


def fit_joint_tracks(uv: np.ndarray, visible: np.ndarray, free_poses: np.ndarray, k: np.ndarray, poses,
                     gauge, start: np.ndarray, min_track_frames: int, max_evaluations: int):
    """The parameters of a one-degree-of-freedom joint fitted to tracks ``uv`` (T, M, 2) seen where ``visible``
    (T, M), by robust least squares of their reprojection errors (each track's point re-solved), then again
    without the tracks that do not follow it. ``poses(p)``: (T, 4, 4) poses of the parameters ``p`` (from
    ``start``); ``gauge(p)``: a residual holding the scale the images leave free.

    Returns (p, the tracks' points (M', 3), which tracks ((M,) bool), how many were dropped), or None when
    fewer than 6 tracks follow the joint.
    """
    def residuals(p: np.ndarray, data: _Observations) -> np.ndarray:
        return np.r_[data.residuals(poses(p), k)[0].ravel(), _GAUGE_WEIGHT * gauge(p)]

    def robust_fit(start: np.ndarray, data: _Observations) -> np.ndarray:
        with threadpool_limits(limits=1, user_api="blas"):  # the same bits whatever the BLAS thread count
            return least_squares(residuals, start, args=(data,), loss="cauchy", f_scale=_LOSS_SCALE,
                                 max_nfev=max_evaluations).x

    sample = _sample_tracks(visible, visible.sum(axis=0) >= min_track_frames)
    if sample.sum() < 6:
        return None
    obs = _Observations(uv, visible, sample)
    fit = robust_fit(start, obs)
    errors = np.linalg.norm(residuals(fit, obs)[:-1].reshape(-1, 2), axis=1)
    free_errors = np.linalg.norm(obs.residuals(free_poses, k)[0], axis=1)
    follows = obs.per_track_median(errors) < _DROP_PX
    if follows.sum() < 6:
        return None
    tracks = sample.copy()
    if np.median(errors) <= 2 * np.median(free_errors) + _DROP_PX:  # else plainly no joint: not worth refining
        tracks[np.flatnonzero(sample)[~follows]] = False
        obs = _Observations(uv, visible, tracks)
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


def _frame_angle(uv: np.ndarray, visible: np.ndarray, points: np.ndarray, body_pose: np.ndarray, axis: np.ndarray,
                 point: np.ndarray, start: float, k: np.ndarray) -> float:
    """The angle about the axis that best places ``points`` (M, 3) on one frame's tracks (see
    :func:`fit_frame_parameter`)."""
    return fit_frame_parameter(uv, visible, points, lambda angle: hinge_poses(body_pose[None], axis, point, angle)[0],
                               start, k)


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
