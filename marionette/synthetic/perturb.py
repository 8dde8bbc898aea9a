"""Known pose errors put into a prior: what a pose refinement must take back out."""

from __future__ import annotations

import numpy as np

from ..geometry import axis_angle_to_matrix
from ..prior import SpatPrior

__all__ = ["perturbed_prior"]

#: The axis of the perturbation's turn: mostly about the camera's vertical, a little about the other two.
AXIS = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])


def perturbed_prior(prior: SpatPrior, angle_deg: float, shift: float, every: int = 3) -> tuple[SpatPrior, list[int]]:
    """The prior with part 0's pose in frames 1, 1 + every, … turned by ``angle_deg`` about :data:`AXIS` through
    its centre and moved sideways by ``shift`` radii; and those frames (a third of them at ``every=3``)."""
    poses = prior.poses.copy()
    turn = axis_angle_to_matrix(np.radians(angle_deg) * AXIS)
    frames = list(range(1, prior.num_frames, every))
    for t in frames:
        centre = prior.centroids[0, t]
        poses[0, t, :3, :3] = turn @ poses[0, t, :3, :3]
        poses[0, t, :3, 3] = turn @ (poses[0, t, :3, 3] - centre) + centre + [shift * prior.radii[0], 0.0, 0.0]
    return SpatPrior.from_poses(poses, prior.centroids, prior.radii, fps=prior.fps,
                                image_size=tuple(prior.image_size), intrinsics=prior.intrinsics), frames
