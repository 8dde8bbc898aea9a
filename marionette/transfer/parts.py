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
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..errors import InputError
from ..geometry import invert_transform, rotation_angle_deg
from ..prior import SpatPrior
from .metrics import knn_edges

__all__ = ["seeds_from_layout", "labels_from_seeds", "boundary_band", "joint_offsets"]


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
    edges = knn_edges(means, k)
    length = np.linalg.norm(means[edges[:, 0]] - means[edges[:, 1]], axis=1) + 1e-12
    graph = coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(len(means),) * 2).tocsr()
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


def joint_offsets(prior: SpatPrior, *, min_degrees: float = 5.0) -> tuple[int, dict[int, np.ndarray]]:
    """The root part (the one that turns least) and, per part hinged on it, its joint relative to the part.

    A joint point ``x`` moves alike with both parts: ``Q_t x = x`` for the
    relative motion ``Q_t = (P^r_t)⁻¹ P^k_t``. Stacking ``(R^Q_t − I) x =
    −t^Q_t`` over frames gives a least-squares problem whose solutions, for a
    hinge, form its axis; a weak pull towards the part's centre picks the
    axis point nearest it. The joint is returned as an offset from the
    part's frame-0 centre in units of its radius, to be placed on the target
    part the same way. Parts that turn less than ``min_degrees`` relative to
    the root get none.
    """
    turn = rotation_angle_deg(prior.poses[..., :3, :3]).max(axis=1)  # (K,)
    root = int(np.argmin(turn))
    offsets = {}
    for k in range(prior.num_parts):
        rel = invert_transform(prior.poses[root]) @ prior.poses[k]
        if k == root or rotation_angle_deg(rel[:, :3, :3]).max() < min_degrees:
            continue
        a = (rel[:, :3, :3] - np.eye(3)).reshape(-1, 3)
        b = -rel[:, :3, 3].reshape(-1)
        centre = prior.centroids[k, 0]
        pull = 1e-2 * np.linalg.norm(a, axis=1).max()
        x = np.linalg.lstsq(np.vstack([a, pull * np.eye(3)]), np.concatenate([b, pull * centre]), rcond=None)[0]
        offsets[k] = (x - centre) / prior.radii[k]
    return root, offsets
