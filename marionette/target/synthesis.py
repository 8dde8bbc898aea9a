"""Texture for surface no view shows, quilted from patches of surface the photo does show.

A lifted surface sampled on a grid holds a colour per sample. Where neither
the photo nor a symmetry gives one, a colour copied from the nearest known
sample draws streaks; instead square patches of known colours, at the same
sample spacing (so at the texture's own scale), are laid over the grid with
overlaps blended by a tent window (a simple image quilting).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["quilt", "fill_unseen"]

# Patch side over the source's shorter side, and the share of a patch its neighbours overlap.
_PATCH_SHARE = 0.5
_PATCH_OVERLAP = 0.25
# Known colours blend into synthesised ones over this share of a patch side.
_SEAM = 0.25


def _tent(side: int) -> np.ndarray:
    ramp = np.minimum(np.arange(side) + 1.0, side - np.arange(side)) / (0.5 * side + 0.5)
    return np.outer(ramp, ramp)[..., None]


def quilt(source: np.ndarray, shape: tuple[int, int], rng: np.random.Generator, side: int | None = None,
          corners: np.ndarray | None = None, row_window: int | None = None) -> np.ndarray:
    """(n_a, n_b, 3) texture of ``shape`` laid from square patches of ``source`` (m_a, m_b, 3), feathered.

    ``side``: the patches' side (default half the source's shorter side); ``corners`` (K, 2): the patches'
    allowed top-left cells in ``source`` (default every one); ``row_window``: a patch laid at row ``r`` is
    taken from rows ``r ± row_window`` where it can be (the nearest allowed rows else), so colours that
    change along the rows (a pot's bands, a label) stay at their rows.
    """
    side = max(1, side or int(_PATCH_SHARE * min(source.shape[:2])))
    if corners is None:
        a, b = np.mgrid[0:source.shape[0] - side + 1, 0:source.shape[1] - side + 1]
        corners = np.stack([a.ravel(), b.ravel()], axis=1)
    step = max(1, int(round(side * (1.0 - _PATCH_OVERLAP))))
    window = _tent(side)
    total = np.zeros((shape[0] + side, shape[1] + side, source.shape[2]))
    weight = np.zeros((shape[0] + side, shape[1] + side, 1))
    for r in range(0, shape[0], step):
        allowed = corners
        if row_window is not None:
            gap = np.abs(corners[:, 0] - r)
            allowed = corners[gap <= max(row_window, gap.min())]
        for c in range(0, shape[1], step):
            a, b = allowed[rng.integers(len(allowed))]
            total[r:r + side, c:c + side] += window * source[a:a + side, b:b + side]
            weight[r:r + side, c:c + side] += window
    return (total / np.maximum(weight, 1e-12))[: shape[0], : shape[1]]


def fill_unseen(colours: np.ndarray, known: np.ndarray, rng: np.random.Generator,
                keep_rows: bool = False) -> np.ndarray:
    """(n_a, n_b, 3) colours with the cells not ``known`` (n_a, n_b) bool quilted from known ones.

    Patches are the largest squares (at most half the known region's extent) lying wholly on known cells;
    the quilt meets the known colours through a seam a quarter of a patch wide. ``keep_rows``: patches come
    from about the rows they are laid at (:func:`quilt`'s ``row_window``, a quarter of a patch).
    """
    if known.all() or not known.any():
        return colours if known.all() else np.broadcast_to(colours.reshape(-1, 3).mean(axis=0), colours.shape)
    rows, cols = np.nonzero(known.any(axis=1))[0], np.nonzero(known.any(axis=0))[0]
    side = max(1, int(_PATCH_SHARE * min(np.ptp(rows) + 1, np.ptp(cols) + 1)))
    table = np.pad(np.cumsum(np.cumsum(known, axis=0), axis=1), ((1, 0), (1, 0)))  # known cells per square
    while True:
        count = table[side:, side:] - table[:-side, side:] - table[side:, :-side] + table[:-side, :-side]
        corners = np.argwhere(count == side * side)
        if len(corners) or side == 1:
            break
        side = max(1, side // 2)
    filled = quilt(colours, colours.shape[:2], rng, side, corners, max(1, side // 4) if keep_rows else None)
    distance, (ia, ib) = ndimage.distance_transform_edt(~known, return_indices=True)  # 0 on known cells
    blend = np.clip(distance / max(_SEAM * side, 1.0), 0.0, 1.0)[..., None]
    return np.where(known[..., None], colours, blend * filled + (1 - blend) * colours[ia, ib])
