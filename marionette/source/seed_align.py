"""Tracks re-aligned to the windows they were seeded on.

The tracker carries a point from frame to frame (re-anchored now and then), and each step's small error stays
with it: on a face that turns away from the camera its windows shorten across the axis and the tracks lag
the motion by a few per cent (docs/benchmarks/lid_information.md: 0.3-0.4 px on a lid, against 0.1 px
re-aligned). Here each observation is aligned again to the track's seed window under an affine warp with a gain
and a bias, started from the last re-aligned position moved by the tracker's step, so no error is carried
over. Where the seed window no longer matches (a face seen edge-on, a window now on another surface) the
observation is dropped, or keeps the tracker's position when asked: the tracks across an edge-on turn are
what tell a turn past it from one back (the two mirror each other in a part's relief).
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from .tracks import _ALIGN_BLUR, Tracks, _align_affine, _aligned_noise

__all__ = ["realign_to_seeds"]

#: The window's side (the tracker's), and the residual (a share of the window's contrast) above which an
#: observation no longer matches its seed window.
WINDOW, MATCH_LIMIT = 21, 0.6
#: A re-aligned position farther than this (pixels) from the tracker's is taken for a wrong match.
_MAX_SHIFT_PX = 3.0


def realign_to_seeds(tracks: Tracks, frames, masks, *, subset: np.ndarray | None = None,
                     keep_unmatched: bool = False) -> Tracks:
    """``tracks`` with each observation re-aligned to its track's seed window.

    Parameters
    ----------
    tracks : the tracker's (chained) tracks, T frames, M tracks.
    frames, masks : (T, H, W, 3) uint8 and (T, H, W) bool, or anything indexed by frame; a seed window's pixels
        off its frame's mask are left out.
    subset : (M,) bool, the tracks to re-align (all by default); the others are returned as they are.
    keep_unmatched : an observation whose seed window no longer matches keeps the tracker's position instead of
        being dropped.

    Returns
    -------
    Tracks with the same ``start``; ``visible`` False where an observation was dropped.
    """
    chosen = np.flatnonzero(np.ones(tracks.num_tracks, bool) if subset is None else subset)
    uv = tracks.uv.astype(np.float64)
    out = uv.copy()
    images: dict[int, np.ndarray] = {}

    def image(t: int) -> np.ndarray:
        if t not in images:
            grey = cv2.cvtColor(np.asarray(frames[t]), cv2.COLOR_RGB2GRAY)
            images[t] = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), _ALIGN_BLUR)
        return images[t]

    noise = _aligned_noise(cv2.cvtColor(np.asarray(frames[0]), cv2.COLOR_RGB2GRAY))
    starts = tracks.start[chosen]
    seed_frames = set(np.unique(starts).tolist())
    seeds = uv[starts, chosen]  # (N, 2)
    position, warp = seeds.copy(), np.tile(np.eye(2), (len(chosen), 1, 1))
    matched = np.zeros(tracks.visible.shape, bool)
    matched[starts, chosen] = True
    for t in range(1, tracks.num_frames):
        alive = np.flatnonzero(tracks.visible[t, chosen] & (starts < t))
        for s in np.unique(starts[alive]):
            at = alive[starts[alive] == s]
            ids = chosen[at]
            before = np.where(np.isfinite(uv[t - 1, ids]), uv[t - 1, ids], uv[t, ids])
            p, a, residual, _ = _align_affine(image(s), np.asarray(masks[s], np.float32), image(t), seeds[at],
                                              position[at] + uv[t, ids] - before, warp[at], WINDOW,
                                              photometric=True, noise=noise)
            good = (np.isfinite(residual) & (residual < MATCH_LIMIT)
                    & (np.linalg.norm(p - uv[t, ids], axis=1) < _MAX_SHIFT_PX))
            out[t, ids[good]] = p[good]
            matched[t, ids[good]] = True
            position[at[good]], warp[at[good]] = p[good], a[good]
            position[at[~good]] = uv[t, ids[~good]]
        if t - 1 not in seed_frames:  # no window is seeded there: not needed again
            images.pop(t - 1, None)
    visible = tracks.visible.copy()
    if not keep_unmatched:
        visible[:, chosen] &= matched[:, chosen]
        out[~visible] = np.nan
    return dataclasses.replace(tracks, uv=out.astype(np.float32), visible=visible)
