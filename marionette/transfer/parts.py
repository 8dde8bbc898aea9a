"""Which target Gaussian follows which source part."""

from __future__ import annotations

import numpy as np

__all__ = ["labels_from_layout"]


def _bbox(mask: np.ndarray) -> tuple[float, float, float, float]:
    v, u = np.nonzero(mask)
    return float(u.min()), float(v.min()), float(u.max() - u.min() + 1), float(v.max() - v.min() + 1)


def labels_from_layout(pixel_of: np.ndarray, target_mask: np.ndarray, source_labels: np.ndarray) -> np.ndarray:
    """Part label per target Gaussian by matching the objects' normalised layouts.

    Each Gaussian's source pixel is mapped into the source object's bounding
    box at the same relative position, and takes the label of the nearest
    labelled source pixel there.

    Parameters
    ----------
    pixel_of : (N, 2) int, (u, v) target pixel each Gaussian came from.
    target_mask : (H, W) bool, target object mask.
    source_labels : (Hs, Ws) int, part per source frame-0 pixel, -1 background.

    Returns
    -------
    (N,) int32 labels.
    """
    from scipy.ndimage import distance_transform_edt

    src_obj = source_labels >= 0
    if not src_obj.any():
        return np.zeros(len(pixel_of), np.int32)
    tu, tv, tw, th = _bbox(target_mask)
    su, sv, sw, sh = _bbox(src_obj)
    u = su + (pixel_of[:, 0] - tu + 0.5) / tw * sw - 0.5
    v = sv + (pixel_of[:, 1] - tv + 0.5) / th * sh - 0.5
    u = np.clip(np.rint(u), 0, source_labels.shape[1] - 1).astype(int)
    v = np.clip(np.rint(v), 0, source_labels.shape[0] - 1).astype(int)
    # Nearest labelled source pixel for every source pixel (background included).
    _, (iv, iu) = distance_transform_edt(~src_obj, return_indices=True)
    return source_labels[iv[v, u], iu[v, u]].astype(np.int32)
