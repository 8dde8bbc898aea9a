"""Quality of a transferred trajectory: local rigidity, separation at part boundaries, jerk.

All of them compare a trajectory of Gaussian means (T, N, 3) with its own
frame 0 on a k-nearest-neighbour graph of the frame-0 means, so they need no
ground truth:

- rigidity error: mean over frames and within-part edges of
  ``| |x_i(t) - x_j(t)| / |x_i(0) - x_j(0)| - 1 |`` (0 for a rigid motion);
- boundary separation: share of edges across a part
  boundary stretched by more than ``stretch`` (50 %) at some frame. It
  counts a seam that gapes: an honest hinge opening scores high on it, since
  every seam edge off the hinge line stretches as the lid turns away;
- detached seam (ours): share of edges across a part boundary that tear
  while their two parts have lost contact: stretched by more than
  ``stretch`` at a frame where fewer than ``contact`` (0.5 %, and at least
  one) of the pair's across edges stay within ``stretch``. It tells a lid
  that opens about its hinge line (attached: 0) from one that flies off (all
  its stretched edges count, so near 1);
- jerk: RMS third time difference of the means, in object radii per frame³.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..trajectory import Trajectory

__all__ = ["TrajectoryQuality", "knn_edges", "trajectory_quality"]


@dataclass(frozen=True)
class TrajectoryQuality:
    """Figures of :func:`trajectory_quality`."""

    rigidity_error: float
    boundary_separation: float
    detached_seam: float
    jerk: float
    edges_within: int
    edges_across: int

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def knn_edges(points: np.ndarray, k: int = 8) -> np.ndarray:
    """Undirected edges (E, 2) int, i < j, between each of points (N, 3) and its ``k`` nearest neighbours."""
    k = min(k, len(points) - 1)
    if k < 1:
        return np.zeros((0, 2), np.int64)
    _, idx = cKDTree(points).query(points, k=k + 1, workers=-1)
    i = np.repeat(np.arange(len(points), dtype=np.int64), k)
    j = idx[:, 1:].ravel().astype(np.int64)
    # Unique pairs through one int64 key per pair (i < j): a 1-D unique, far faster than a row-wise one.
    key = np.sort(np.minimum(i, j) * len(points) + np.maximum(i, j))
    key = key[np.concatenate([[True], key[1:] != key[:-1]])]
    return np.column_stack([key // len(points), key % len(points)])


def _detached(change: np.ndarray, pairs: np.ndarray, stretch: float, contact: float) -> float:
    """Share of across edges (change (T, E), part pairs (E, 2)) stretched while their pair has lost contact."""
    if not change.size:
        return 0.0
    _, pair = np.unique(np.sort(pairs, axis=1), axis=0, return_inverse=True)
    pair = pair.ravel()
    stretched = change > stretch  # (T, E)
    # (T, pairs)
    kept = np.stack([np.bincount(pair, (~row).astype(float), minlength=pair.max() + 1) for row in stretched])
    size = np.bincount(pair)
    lost = kept < np.maximum(contact * size, 1)
    return float((stretched & lost[:, pair]).any(axis=0).mean())


def trajectory_quality(trajectory: Trajectory, *, k: int = 8, stretch: float = 0.5, contact: float = 0.005,
                       max_points: int = 20000, seed: int = 0) -> TrajectoryQuality:
    """Rigidity error, boundary separation, detached seam and jerk of a trajectory (see the module notes).

    Up to ``max_points`` Gaussians (a random subset) enter the graph.
    """
    means = np.asarray(trajectory.means, dtype=np.float64)  # (T, N, 3)
    labels = np.asarray(trajectory.labels)
    if means.shape[1] > max_points:
        keep = np.sort(np.random.default_rng(seed).choice(means.shape[1], max_points, replace=False))
        means, labels = means[:, keep], labels[keep]
    edges = knn_edges(means[0], k)
    rest = np.linalg.norm(means[0, edges[:, 0]] - means[0, edges[:, 1]], axis=1)
    ok = rest > 1e-9
    edges, rest = edges[ok], rest[ok]
    length = np.linalg.norm(means[:, edges[:, 0]] - means[:, edges[:, 1]], axis=2)  # (T, E)
    change = length / rest - 1.0
    within = labels[edges[:, 0]] == labels[edges[:, 1]]
    rigidity = float(np.abs(change[:, within]).mean()) if within.any() else 0.0
    separation = float((change[:, ~within].max(axis=0) > stretch).mean()) if (~within).any() else 0.0
    detached = _detached(change[:, ~within], labels[edges[~within]], stretch, contact)
    radius = float(np.sqrt(((means[0] - means[0].mean(axis=0)) ** 2).sum(axis=1).mean())) or 1.0
    third = np.diff(means, n=3, axis=0)
    jerk = float(np.sqrt((third ** 2).sum(axis=2).mean()) / radius) if len(third) else 0.0
    return TrajectoryQuality(rigidity, separation, detached, jerk, int(within.sum()), int((~within).sum()))
