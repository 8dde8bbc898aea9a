"""Which target Gaussian follows which source part.

Parts are grown from seeds by a geodesic flood fill: each Gaussian takes the
part of the seed nearest to it along a k-nearest-neighbour graph of the
rest positions (distances summed along graph edges, so a part does not leak
across a gap into another limb the way straight-line distance would). Seeds
are given in target pixels, or matched from the source's part layout: each
source part's centroid, normalised to the object's bounding box, placed at
the same relative position in the target.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..errors import InputError
from .metrics import knn_edges

__all__ = ["seeds_from_layout", "labels_from_seeds", "boundary_band"]


def _bbox(mask: np.ndarray) -> tuple[float, float, float, float]:
    v, u = np.nonzero(mask)
    return float(u.min()), float(v.min()), float(u.max() - u.min() + 1), float(v.max() - v.min() + 1)


def seeds_from_layout(source_labels: np.ndarray, target_mask: np.ndarray) -> dict[int, tuple[float, float]]:
    """One target pixel (x, y) per source part: its centroid at the same place relative to the object's box.

    source_labels : (Hs, Ws) int, part per source frame-0 pixel, negative off the object.
    target_mask : (H, W) bool.
    """
    src_obj = source_labels >= 0
    su, sv, sw, sh = _bbox(src_obj)
    tu, tv, tw, th = _bbox(target_mask)
    seeds = {}
    for k in np.unique(source_labels[src_obj]):
        v, u = np.nonzero(source_labels == k)
        seeds[int(k)] = (tu + (u.mean() - su + 0.5) / sw * tw - 0.5, tv + (v.mean() - sv + 0.5) / sh * th - 0.5)
    return seeds


def labels_from_seeds(means: np.ndarray, pixel_of: np.ndarray, seeds: dict[int, tuple[float, float]],
                      k: int = 8) -> np.ndarray:
    """(N,) int32 part of each Gaussian by geodesic flood fill from seed pixels.

    means : (N, 3) rest positions; pixel_of : (N, 2) the target pixel each came from;
    seeds : part → (x, y) target pixel. A seed starts at the Gaussian made from
    the nearest pixel (the front-most of those). Gaussians the graph does not
    reach take the part of the nearest Gaussian that it does.
    """
    if not seeds:
        raise InputError("no part seeds given")
    means = np.asarray(means, dtype=np.float64)
    parts = sorted(seeds)
    by_pixel = cKDTree(np.asarray(pixel_of, dtype=np.float64))
    starts = []
    for part in parts:
        _, idx = by_pixel.query(np.asarray(seeds[part], dtype=np.float64), k=min(8, len(means)))
        idx = np.atleast_1d(idx)
        starts.append(int(idx[np.argmin(means[idx, 2])]))
    # Directed k-nearest-neighbour edges; dijkstra(directed=False) walks them both ways.
    n, k = len(means), max(min(k, len(means) - 1), 1)
    gap, near = cKDTree(means).query(means, k=k + 1, workers=-1)
    gap, near = np.atleast_2d(gap)[:, 1:], np.atleast_2d(near)[:, 1:]
    ok = near < n  # fewer points than k + 1: missing neighbours come back as index n
    graph = csr_matrix((gap[ok] + 1e-12, (np.nonzero(ok)[0], near[ok])), shape=(n, n))
    # With min_only, the third output is the start each node is nearest to (-9999 when unreached).
    dist, _, source = dijkstra(graph, directed=False, indices=starts, min_only=True, return_predecessors=True)
    part_of_start = {s: p for s, p in zip(starts, parts)}
    labels = np.array([part_of_start.get(s, -1) for s in source], np.int32)
    lost = ~np.isfinite(dist)
    if lost.any():
        _, near = cKDTree(means[~lost]).query(means[lost])
        labels[lost] = labels[~lost][near]
    return labels


def boundary_band(means: np.ndarray, labels: np.ndarray, k: int = 8) -> np.ndarray:
    """(N,) bool: Gaussians with a k-nearest neighbour in another part."""
    edges = knn_edges(np.asarray(means, dtype=np.float64), k)
    across = labels[edges[:, 0]] != labels[edges[:, 1]]
    band = np.zeros(len(means), bool)
    band[edges[across].ravel()] = True
    return band
