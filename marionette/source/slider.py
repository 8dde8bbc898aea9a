"""A part sliding on another: its motion as a travel along one direction fixed in its body (a drawer, a
telescoping handle).

The counterpart of :mod:`.hinge` for prismatic joints. A free 6-DoF fit of a
part that only slides lets small turns trade against its depth; a slider
leaves it one degree of freedom per frame, the distance along a direction
fixed in the body. The direction (2 parameters) and the distances of evenly
spaced key frames are fitted together by robust least squares on the
reprojection errors of the part's tracks, each track's 3D point re-solved for
every candidate motion (variable projection, as for the hinge); each other
frame's distance is then fitted alone, and tracks that do not follow the
slider are dropped before a second fit.

:func:`fit_slider` starts from the free fit's poses; the extraction keeps the
slider when it explains the tracks about as well as the free poses do.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..geometry import invert_transform
from .joint_tracks import Observations, fit_frame_parameter, fit_joint_tracks, key_frames

__all__ = ["SliderFit", "fit_slider", "scaled_slider", "slider_poses"]

#: A part whose travel stays under this share of its distance from the camera has no direction to find.
_MIN_TRAVEL = 0.01


@dataclass(frozen=True)
class SliderFit:
    """A part's motion as a travel along a direction fixed in its body.

    Attributes
    ----------
    poses : (T, 4, 4) float64
        The part's poses, ``body_poses[t]`` then a shift by ``distances[t] * axis``.
    axis : (3,) float64
        Unit direction of travel, in the body's frame-0 coordinates.
    distances : (T,) float64
        Travel along the axis, in the poses' units; 0 at frame 0.
    residual_px, free_residual_px : float
        Median reprojection error of the part's tracks under the slider, and under the free poses.
    dropped : int
        Tracks left out of the final fit as not following the slider.
    seen : (T,) int
        Tracks of the final fit seen in each frame.
    """

    poses: np.ndarray
    axis: np.ndarray
    distances: np.ndarray
    residual_px: float
    free_residual_px: float
    dropped: int
    seen: np.ndarray


def slider_poses(body_poses: np.ndarray, axis: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """(T, 4, 4) poses of a part shifted by ``distances`` (T,) along ``axis`` (3,) of its body."""
    shift = np.tile(np.eye(4), (len(distances), 1, 1))
    shift[:, :3, 3] = distances[:, None] * axis
    return body_poses @ shift


def scaled_slider(fit: SliderFit, body_poses: np.ndarray, factor: float) -> SliderFit:
    """``fit`` with its travel ``factor`` times as long (its poses on ``body_poses`` (T, 4, 4)): on a still body
    the part and its travel scaled together about the camera change no image (:func:`.joint_tracks.surface_scale`
    finds the factor)."""
    distances = fit.distances * factor
    return dataclasses.replace(fit, distances=distances, poses=slider_poses(body_poses, fit.axis, distances))


def _initial_slider(relative: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Direction (3,) and distances (T,) closest to relative poses (T, 4, 4): the principal direction of the
    travel of the part's ``centre`` (3,) (not of the poses' translations, which a turn about the camera
    swings), pointing the way the part goes furthest."""
    travel = relative[:, :3, :3] @ centre + relative[:, :3, 3] - centre
    axis = np.linalg.svd(travel, full_matrices=False)[2][0]
    distances = travel @ axis
    if distances[np.argmax(np.abs(distances))] < 0:
        axis, distances = -axis, -distances
    return axis, distances


def fit_slider(uv: np.ndarray, visible: np.ndarray, body_poses: np.ndarray, free_poses: np.ndarray,
               k: np.ndarray, *, min_track_frames: int = 3, max_evaluations: int = 50) -> SliderFit | None:
    """Fit a part's motion as a slider on its body, starting from its free poses.

    Arguments as :func:`~marionette.source.hinge.fit_hinge`. The free poses may turn the part (a free fit of a
    thin drawer often does, by 10-20°): whether it slides is for the residuals to say. Returns None when the
    part barely travels or has fewer than 6 usable tracks.
    """
    relative = invert_transform(body_poses) @ free_poses
    keep = visible.sum(axis=0) >= min_track_frames
    if keep.sum() < 6:
        return None
    every = Observations(uv, visible, keep)
    free_errors, points = every.residuals(free_poses, k)
    distance = float(np.median(np.linalg.norm(points, axis=1)))
    axis0, distances0 = _initial_slider(relative, np.median(points, axis=0))
    if np.abs(distances0).max() < _MIN_TRAVEL * distance:
        return None
    key = key_frames(len(body_poses))
    fitted = _fit_key_frames(uv[key], visible[key], body_poses[key], free_poses[key], k, axis0, distances0[key],
                             min_track_frames, max_evaluations)
    if fitted is None:
        return None
    axis, key_distances, points, tracks, dropped = fitted
    distances = np.interp(np.arange(len(body_poses)), key, key_distances)
    for t in np.setdiff1d(np.arange(len(body_poses)), key):
        distances[t] = fit_frame_parameter(uv[t, tracks], visible[t, tracks], points,
                                           lambda d, t=t: slider_poses(body_poses[t][None], axis, d)[0],
                                           distances[t], k)
    poses = slider_poses(body_poses, axis, distances)
    slid = float(np.median(np.linalg.norm(every.residuals(poses, k)[0], axis=1)))
    free = float(np.median(np.linalg.norm(free_errors, axis=1)))
    return SliderFit(poses, axis, distances, slid, free, dropped, visible[:, tracks].sum(axis=1))


def _fit_key_frames(uv, visible, body_poses, free_poses, k, axis0, distances0, min_track_frames, max_evaluations):
    """Axis, distances (T',), the tracks' points (M', 3), which tracks they are ((M,) bool) and how many were
    dropped, from the key frames' tracks ``uv`` (T', M, 2); None if too few tracks follow a slider."""
    e1 = np.cross(axis0, np.eye(3)[np.argmin(np.abs(axis0))])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis0, e1)
    # With the body still, the part and its travel scaled about the camera change no image: the widest travel
    # keeps about its free fit's length.
    widest = int(np.argmax(np.abs(distances0)))
    if distances0[widest] == 0:
        return None

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        axis = axis0 + p[0] * e1 + p[1] * e2
        return axis / np.linalg.norm(axis), np.r_[0.0, p[2:]]

    fitted = fit_joint_tracks(uv, visible, free_poses, k, lambda p: slider_poses(body_poses, *unpack(p)),
                              lambda p: unpack(p)[1][widest] / distances0[widest] - 1.0,
                              np.r_[0.0, 0.0, distances0[1:]], min_track_frames, max_evaluations)
    if fitted is None:
        return None
    p, points, tracks, dropped = fitted
    return (*unpack(p), points, tracks, dropped)
