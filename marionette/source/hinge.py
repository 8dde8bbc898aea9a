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
for every candidate motion. Tracks that do not follow the fitted hinge (a
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
#: Weight of the depth gauge: 1 % off the free fit's mean depth costs what a 0.01 px residual does (it only
#: has to hold the scale where the images leave it free).
_GAUGE_WEIGHT = 1.0
#: A track whose median residual under the first fit exceeds this (pixels) is dropped before the second.
_DROP_PX = 1.0


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
        A point of the axis (the one closest to the origin).
    angles : (T,) float64
        Turn about the axis, radians; 0 at frame 0.
    residual_px : float
        Median reprojection error of the part's tracks under the hinge model (all tracks).
    free_residual_px : float
        The same under the free poses it started from, measured alike.
    dropped : int
        Tracks left out of the final fit as not following the hinge.
    """

    poses: np.ndarray
    axis: np.ndarray
    point: np.ndarray
    angles: np.ndarray
    residual_px: float
    free_residual_px: float
    dropped: int


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

    def points(self, poses: np.ndarray, k: np.ndarray, steps: int = 3) -> np.ndarray:
        """(M, 3) frame-0 points that best explain the tracks under ``poses`` (T, 4, 4).

        Linear triangulation, then ``steps`` Gauss-Newton steps on the reprojection error.
        """
        return _solve_points(self.t, self.uv, self._starts, np.ascontiguousarray(poses[:, :3]), k, steps)

    def residuals_of(self, cam: np.ndarray, k: np.ndarray) -> np.ndarray:
        """(N, 2) projections of camera-frame points ``cam`` (N, 3) minus the observations."""
        return np.column_stack([k[0, 0] * cam[:, 0] / cam[:, 2] + k[0, 2],
                                k[1, 1] * cam[:, 1] / cam[:, 2] + k[1, 2]]) - self.uv

    def residuals(self, poses: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) reprojection errors under ``poses`` (T, 4, 4), each track's point re-solved, and those
        points (M, 3)."""
        points = self.points(poses, k)
        cam = np.einsum("nij,nj->ni", poses[self.t, :3, :3], points[self.m]) + poses[self.t, :3, 3]
        return self.residuals_of(cam, k), points

    def per_track_median(self, residuals: np.ndarray) -> np.ndarray:
        """(M,) median error (pixels) of each track, from ``residuals`` (N, 2)."""
        err = np.split(np.linalg.norm(residuals, axis=1), self._starts[1:])
        return np.array([np.median(e) for e in err])


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


@njit(cache=True)
def _solve_points(t: np.ndarray, uv: np.ndarray, starts: np.ndarray, poses: np.ndarray, k: np.ndarray,
                  steps: int) -> np.ndarray:
    """(M, 3) points from observations grouped by track (track m: ``starts[m]`` up to the next start) of frames
    ``t`` (N,) at pixels ``uv`` (N, 2) under ``poses`` (T, 3, 4): linear triangulation, then Gauss-Newton."""
    num_points, n = len(starts), len(t)
    points = np.zeros((num_points, 3))
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
        points[m] = x
    return points


def _initial_hinge(relative: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis direction (3,), axis point (3,) and angles (T,) closest to relative poses (T, 4, 4)."""
    rotvecs = Rotation.from_matrix(relative[:, :3, :3]).as_rotvec()  # (T, 3)
    axis = rotvecs[np.argmax(np.linalg.norm(rotvecs, axis=1))]
    axis /= np.linalg.norm(axis)
    # Points of the axis stay put: (I - R_t) p = t_t for every frame, in the least-squares sense.
    lhs = np.concatenate(np.eye(3) - relative[1:, :3, :3])
    point = np.linalg.lstsq(lhs, np.concatenate(relative[1:, :3, 3]), rcond=None)[0]
    return axis, point - axis * (point @ axis), rotvecs @ axis


def fit_hinge(uv: np.ndarray, visible: np.ndarray, body_poses: np.ndarray, free_poses: np.ndarray,
              k: np.ndarray, *, min_track_frames: int = 3, max_evaluations: int = 100) -> HingeFit | None:
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
        Cap on the least-squares evaluations per fit.

    Returns
    -------
    HingeFit, or None when the part barely turns relative to the body (under 5°: no axis to find) or has
    fewer than 6 usable tracks.
    """
    relative = invert_transform(body_poses) @ free_poses
    keep = visible.sum(axis=0) >= min_track_frames
    if rotation_angle_deg(relative[:, :3, :3]).max() < 5.0 or keep.sum() < 6:
        return None
    obs = _Observations(uv, visible, keep)
    axis0, point0, angles0 = _initial_hinge(relative)
    e1 = np.cross(axis0, np.eye(3)[np.argmin(np.abs(axis0))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis0, e1)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        axis = axis0 + p[0] * e1 + p[1] * e2
        return axis / np.linalg.norm(axis), point0 + p[2] * e1 + p[3] * e2, np.r_[0.0, p[4:]]

    # When the body does not move, scaling the part's points and axis about the camera changes no image:
    # the part keeps the mean depth its free fit gave it.
    depth = float(np.mean(obs.residuals(free_poses, k)[1][:, 2]))

    def residuals(p: np.ndarray, data: _Observations) -> np.ndarray:
        errors, points = data.residuals(hinge_poses(body_poses, *unpack(p)), k)
        return np.r_[errors.ravel(), _GAUGE_WEIGHT * (np.mean(points[:, 2]) / depth - 1.0)]

    def robust_fit(start: np.ndarray, data: _Observations) -> np.ndarray:
        with threadpool_limits(limits=1, user_api="blas"):  # the same bits whatever the BLAS thread count
            return least_squares(residuals, start, args=(data,), loss="cauchy", f_scale=_LOSS_SCALE,
                                 max_nfev=max_evaluations).x

    first = robust_fit(np.r_[0.0, 0.0, 0.0, 0.0, angles0[1:]], obs)
    follows = obs.per_track_median(residuals(first, obs)[:-1].reshape(-1, 2)) < _DROP_PX
    if follows.sum() < 6:
        return None
    following = keep.copy()
    following[np.flatnonzero(keep)[~follows]] = False
    axis, point, angles = unpack(robust_fit(first, _Observations(uv, visible, following)))
    poses = hinge_poses(body_poses, axis, point, angles)
    hinged, free = (float(np.median(np.linalg.norm(obs.residuals(p, k)[0], axis=1))) for p in (poses, free_poses))
    return HingeFit(poses, axis, point, angles, hinged, free, int((~follows).sum()))
