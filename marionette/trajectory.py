"""Gaussian centres over time, the output of a transfer."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .gaussians import Gaussians
from .geometry import matrix_to_quaternion

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """Where each target Gaussian is at each output frame.

    Attributes
    ----------
    means : (T, N, 3) float32
        Gaussian centres per frame; ``means[0]`` is the rest position.
    part_rotations : (T, P, 3, 3) float32
        Accumulated rotation of each part since frame 0, used to turn the
        Gaussians' own orientations (the paper moves centres only, which leaves
        elongated splats pointing the wrong way after a large turn).
    labels : (N,) int32
        Part index of each Gaussian.
    """

    means: np.ndarray
    part_rotations: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        means = np.asarray(self.means, dtype=np.float32)
        rots = np.asarray(self.part_rotations, dtype=np.float32)
        labels = np.asarray(self.labels, dtype=np.int32)
        if means.ndim != 3 or means.shape[2] != 3:
            raise ValueError(f"Trajectory.means must be (T, N, 3), got {means.shape}")
        t, n = means.shape[:2]
        if rots.ndim != 4 or rots.shape[0] != t or rots.shape[2:] != (3, 3):
            raise ValueError(f"Trajectory.part_rotations must be ({t}, P, 3, 3), got {rots.shape}")
        if labels.shape != (n,) or (n and (labels.min() < 0 or labels.max() >= rots.shape[1])):
            raise ValueError(f"Trajectory.labels must be ({n},) part indices below {rots.shape[1]}")
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "part_rotations", rots)
        object.__setattr__(self, "labels", labels)

    @property
    def num_frames(self) -> int:
        return self.means.shape[0]

    def frame(self, gaussians: Gaussians, t: int) -> Gaussians:
        """The Gaussians as they are at frame ``t``: moved and turned."""
        turn = matrix_to_quaternion(self.part_rotations[t].astype(np.float64))  # (P, 4): one per part
        return gaussians.with_means(self.means[t]).turned(turn, self.labels)
