"""Playback controls on a prior: speed, length, looping, reversal, motion magnitude (Motion Marionette Sec. 4.3).

Speed resamples each part's cumulative pose at fractional source times with
SE(3) interpolation (slerp on rotation, linear on translation), so a slower
video gets genuinely in-between poses rather than repeated frames. Output
frame ``i`` shows source time ``τ_i``; the target starts at rest, so the
poses are taken relative to the first one shown: ``P'_i = P(τ_i) P(τ_0)⁻¹``.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..geometry import axis_angle_to_matrix, invert_transform, matrix_to_axis_angle, se3_interpolate
from ..prior import SpatPrior

__all__ = ["output_length", "retime", "scale_motion", "source_times", "LOOPS"]

#: What happens when the output is longer than the source: hold the last pose,
#: start again from the first, or play back and forth.
LOOPS = ("hold", "repeat", "pingpong")


def source_times(frames: int, last: int, *, speed: float = 1.0, loop: str = "hold",
                 reverse: bool = False) -> np.ndarray:
    """Source time (in source frames, within ``[0, last]``) of each of ``frames`` output frames, (frames,)."""
    if not (np.isfinite(speed) and speed > 0):
        raise InputError(f"speed must be a positive number, got {speed}")
    if loop not in LOOPS:
        raise InputError(f"loop must be one of {', '.join(LOOPS)}, got {loop!r}")
    if frames < 2:
        raise InputError(f"frames must be at least 2, got {frames}")
    times = np.arange(frames) * float(speed)
    if loop == "hold":
        times = np.minimum(times, last)
    elif loop == "repeat":
        times = np.minimum(np.mod(times, last + speed), last)  # after the last pose, a cut to the first
    else:
        phase = np.mod(times, 2 * last)
        times = np.where(phase <= last, phase, 2 * last - phase)
    return last - times if reverse else times


def output_length(source_frames: int, speed: float, frames: int | None = None) -> int:
    """Number of output frames: ``frames`` if given, else enough to play the source once at ``speed``."""
    if frames is not None:
        return frames
    return int(np.floor((source_frames - 1) / speed)) + 1 if np.isfinite(speed) and speed > 0 else 0


def retime(prior: SpatPrior, *, speed: float = 1.0, frames: int | None = None, loop: str = "hold",
           reverse: bool = False) -> SpatPrior:
    """A prior played at ``speed`` for ``frames`` output frames.

    The default length covers the source once. Beyond the source's end the
    ``loop`` mode applies (see :data:`LOOPS`); ``reverse`` plays the source
    backwards (from its last pose, taken as the rest pose).
    """
    last = prior.num_frames - 1
    frames = output_length(prior.num_frames, speed, frames)
    times = source_times(frames, last, speed=speed, loop=loop, reverse=reverse)
    if np.array_equal(times, np.arange(prior.num_frames)):
        return prior
    lo = np.minimum(np.floor(times).astype(int), last - 1)
    frac = times - lo
    poses = np.empty((prior.num_parts, frames, 4, 4))
    cents = np.empty((prior.num_parts, frames, 3))
    for k in range(prior.num_parts):
        for i, (a, w) in enumerate(zip(lo, frac)):
            poses[k, i] = se3_interpolate(prior.poses[k, a], prior.poses[k, a + 1], w)
        cents[k] = (1 - frac)[:, None] * prior.centroids[k, lo] + frac[:, None] * prior.centroids[k, lo + 1]
    poses = poses @ invert_transform(poses[:, :1])  # the first frame shown is the rest pose
    return SpatPrior.from_poses(poses, cents, prior.radii, fps=prior.fps, image_size=tuple(prior.image_size),
                                intrinsics=prior.intrinsics, extras=prior.extras, metadata=prior.metadata)


def scale_motion(prior: SpatPrior, *, rotation: float = 1.0, translation: float = 1.0) -> SpatPrior:
    """The prior with each part's rotation angle and centre displacement multiplied.

    Part k's pose at frame t turns by ``rotation`` times its angle about the
    same axis (the rotation vector scaled), and its centre moves by
    ``translation`` times its displacement from frame 0; the pose keeps the
    scaled centre on the scaled path: ``t' = c'_t − R'_t c_0``.
    """
    for name, value in (("rotation", rotation), ("translation", translation)):
        if not np.isfinite(value):
            raise InputError(f"{name} scale must be a finite number, got {value}")
    if rotation == 1.0 and translation == 1.0:
        return prior
    rot = axis_angle_to_matrix(rotation * matrix_to_axis_angle(prior.poses[..., :3, :3]))  # (K, T, 3, 3)
    c0 = prior.centroids[:, :1]  # (K, 1, 3)
    cents = c0 + translation * (prior.centroids - c0)
    poses = np.tile(np.eye(4), prior.poses.shape[:2] + (1, 1))
    poses[..., :3, :3] = rot
    poses[..., :3, 3] = cents - np.einsum("ktij,kj->kti", rot, c0[:, 0])
    return SpatPrior.from_poses(poses, cents, prior.radii, fps=prior.fps, image_size=tuple(prior.image_size),
                                intrinsics=prior.intrinsics, extras=prior.extras, metadata=prior.metadata)
