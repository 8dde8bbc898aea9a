"""Playback controls on a prior: speed and length (Motion Marionette Sec. 4.3).

Speed resamples each part's cumulative pose at fractional source times with
SE(3) interpolation (slerp on rotation, linear on translation), so a slower
video gets genuinely in-between poses rather than repeated frames.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..geometry import se3_interpolate
from ..prior import SpatPrior

__all__ = ["retime"]


def retime(prior: SpatPrior, *, speed: float = 1.0, frames: int | None = None) -> SpatPrior:
    """A prior played at ``speed`` for ``frames`` output frames.

    Output frame i shows source time ``i * speed`` (in source frames). The
    default length covers the source once; beyond the source's end the last
    pose is held.
    """
    if not (np.isfinite(speed) and speed > 0):
        raise InputError(f"speed must be a positive number, got {speed}")
    last = prior.num_frames - 1
    if frames is None:
        frames = int(np.floor(last / speed)) + 1
    if frames < 2:
        raise InputError(f"frames must be at least 2, got {frames}")
    if speed == 1.0 and frames == prior.num_frames:
        return prior
    times = np.minimum(np.arange(frames) * speed, last)
    lo = np.minimum(np.floor(times).astype(int), last - 1)
    frac = times - lo
    poses = np.empty((prior.num_parts, frames, 4, 4))
    cents = np.empty((prior.num_parts, frames, 3))
    for k in range(prior.num_parts):
        for i, (a, w) in enumerate(zip(lo, frac)):
            poses[k, i] = se3_interpolate(prior.poses[k, a], prior.poses[k, a + 1], w)
        cents[k] = (1 - frac)[:, None] * prior.centroids[k, lo] + frac[:, None] * prior.centroids[k, lo + 1]
    return SpatPrior.from_poses(poses, cents, prior.radii, fps=prior.fps, image_size=tuple(prior.image_size),
                                intrinsics=prior.intrinsics, extras=prior.extras, metadata=prior.metadata)
