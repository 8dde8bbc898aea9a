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

:func:`fit_hinge` starts from the free fit's poses (its angles, and half of
them) and, when the best of those leaves many tracks out, from the hinge
fitted on the first half of the key frames carried on at its last rate (a
thin part the free fit loses once it turns edge-on); it returns the hinge
that explains the tracks best, with how well; the extraction keeps it when
it explains them about as well as the free poses do (the simpler model).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import invert_transform, rotation_angle_deg
from .joint_tracks import Observations, fit_frame_parameter, fit_joint_tracks, key_frames

__all__ = ["HingeFit", "fit_hinge", "hinge_poses", "scaled_hinge"]

#: The key frames' fit starts from the free fit's angles times each of these, and the hinge that explains the
#: tracks best is kept. Its cost has several minima where the turn trades against the part's relief, and free
#: angles that differ by a RANSAC inlier can start it in a wrong one; from half the angles, it reaches the true
#: one (docs/benchmarks/suite.md).
_START_SCALES = (1.0, 0.5)
#: When the best of those leaves out more than this share of the tracks as not following it, the fit starts once
#: more from the first half of the key frames carried on (:func:`_continued`).
_CARRY_ON_DROPPED = 0.1


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
    followers : (M,) bool
        Which of the tracks given are the final fit's.
    """

    poses: np.ndarray
    axis: np.ndarray
    point: np.ndarray
    angles: np.ndarray
    residual_px: float
    free_residual_px: float
    dropped: int
    seen: np.ndarray
    followers: np.ndarray


def hinge_poses(body_poses: np.ndarray, axis: np.ndarray, point: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(T, 4, 4) poses of a part turning by ``angles`` (T,) about the line ``point + s * axis`` of its body."""
    rot = Rotation.from_rotvec(angles[:, None] * axis).as_matrix()
    turn = np.tile(np.eye(4), (len(angles), 1, 1))
    turn[:, :3, :3] = rot
    turn[:, :3, 3] = point - rot @ point
    return body_poses @ turn


def scaled_hinge(fit: HingeFit, body_poses: np.ndarray, factor: float) -> HingeFit:
    """``fit`` with its axis ``factor`` times as far from the camera (its poses on ``body_poses`` (T, 4, 4)): on a
    still body the part and its axis scaled together about the camera change no image
    (:func:`.joint_tracks.surface_scale` finds the factor)."""
    point = fit.point * factor
    return dataclasses.replace(fit, point=point, poses=hinge_poses(body_poses, fit.axis, point, fit.angles))


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
              k: np.ndarray, *, min_track_frames: int = 3, max_evaluations: int = 50,
              start_scales: tuple[float, ...] = _START_SCALES) -> HingeFit | None:
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
    start_scales : the free poses' angles times each of these start a fit (a hinge refitted from one already
        found: ``(1.0,)``).

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
    key = key_frames(len(body_poses))
    every = Observations(uv, visible, keep)
    free = float(np.median(np.linalg.norm(every.residuals(free_poses, k)[0], axis=1)))

    def completed(start: tuple) -> tuple[HingeFit, float] | None:
        """The hinge fitted from ``start`` (axis, point, key frames' angles) over every frame, and the share of
        the tracks it left out; None if too few follow it."""
        fitted = _fit_key_frames(uv[key], visible[key], body_poses[key], free_poses[key], k, *start,
                                 min_track_frames, max_evaluations)
        if fitted is None:
            return None
        axis, point, key_angles, points, tracks, dropped = fitted
        angles = np.interp(np.arange(len(body_poses)), key, _wrapped(key_angles))
        for t in np.setdiff1d(np.arange(len(body_poses)), key):
            angles[t] = _frame_angle(uv[t, tracks], visible[t, tracks], points, body_poses[t], axis, point,
                                     angles[t], k)
        angles = _wrapped(angles)
        poses = hinge_poses(body_poses, axis, point, angles)
        hinged = float(np.median(np.linalg.norm(every.residuals(poses, k)[0], axis=1)))
        return (HingeFit(poses, axis, point, angles, hinged, free, dropped, visible[:, tracks].sum(axis=1),
                         tracks),
                dropped / (tracks.sum() + dropped))

    fits = [fit for fit in (completed((axis0, point0, scale * angles0[key])) for scale in start_scales) if fit]
    if not fits or min(fits, key=lambda fit: fit[0].residual_px)[1] > _CARRY_ON_DROPPED:  # many tracks left out
        continued = _continued(uv, visible, body_poses, free_poses, k, key, axis0, point0, angles0,
                               min_track_frames, max_evaluations)
        carried = None if continued is None else completed(continued)
        if carried is not None:
            fits.append(carried)
    return min(fits, key=lambda fit: fit[0].residual_px)[0] if fits else None


def _continued(uv, visible, body_poses, free_poses, k, key, axis0, point0, angles0, min_track_frames,
               max_evaluations):
    """One more start of the key frames' fit: the hinge fitted on the first half of them, its angles carried on
    over the rest at their last rate; None if the first half fits none. A thin part the free fit loses once it
    turns edge-on (its later tracks explained by depths and a wrong turn) starts every other fit in a basin its
    later tracks cannot pull it out of (they are too far off, down-weighted by the robust loss)."""
    half = len(key) // 2
    if half < 3:
        return None
    first = key[:half]
    fitted = _fit_key_frames(uv[first], visible[first], body_poses[first], free_poses[first], k, axis0, point0,
                             angles0[first], min_track_frames, max_evaluations)
    if fitted is None:
        return None
    axis, point, angles = fitted[:3]
    rate = (angles[-1] - angles[-2]) / (first[-1] - first[-2])
    return axis, point, np.r_[angles, angles[-1] + rate * (key[half:] - first[-1])]


def _wrapped(angles: np.ndarray) -> np.ndarray:
    """``angles`` (radians) in [-π, π): the same turns (a fit can land a whole number of turns away)."""
    return (np.asarray(angles) + np.pi) % (2 * np.pi) - np.pi


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


def _frame_angle(uv: np.ndarray, visible: np.ndarray, points: np.ndarray, body_pose: np.ndarray, axis: np.ndarray,
                 point: np.ndarray, start: float, k: np.ndarray) -> float:
    """The angle about the axis that best places ``points`` (M, 3) on one frame's tracks (see
    :func:`fit_frame_parameter`)."""
    return fit_frame_parameter(uv, visible, points, lambda angle: hinge_poses(body_pose[None], axis, point, angle)[0],
                               start, k)
