"""Frames where something in front covers the object, told from the masks alone.

A mask holds only what shows: behind a trunk a ball's mask is two slivers. Fitted
to them as if they were the whole object, a frame's pose is pulled off the trunk
and the model is carved there. A rigid object's mask changes size smoothly as it
turns or nears the camera; one that shrinks by a quarter and grows back within a
few frames (a dip below its size on both sides) is covered there. A mask that
touches the frame's border is not counted: an object leaving the frame shrinks
the same way.
"""

from __future__ import annotations

import numpy as np

__all__ = ["covered_frames", "COVERED_SHARE", "COVER_WINDOW"]

#: A frame is covered when its mask's area is this share or more below the largest within COVER_WINDOW frames on
#: each side of it.
COVERED_SHARE = 0.25
COVER_WINDOW = 8


def covered_frames(masks) -> dict[int, float]:
    """Frame -> the share of the object covered, for the frames where something in front covers it.

    ``masks`` (T, H, W) bool, any per-frame indexable. The share is ``1 - area / the smaller of the largest
    areas within COVER_WINDOW frames before and after`` (an estimate: the object's own change of size over the
    window counts too); the first and last frames are never counted (one side only).
    """
    areas, border = np.zeros(len(masks)), np.zeros(len(masks), bool)
    for t in range(len(masks)):
        mask = np.asarray(masks[t], bool)
        areas[t] = np.count_nonzero(mask)
        border[t] = mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any()
    shares = {}
    for t in range(1, len(areas) - 1):
        around = min(areas[max(0, t - COVER_WINDOW):t].max(), areas[t + 1:t + COVER_WINDOW + 1].max())
        share = 1 - areas[t] / around if around else 0.0
        if share >= COVERED_SHARE and not border[t]:
            shares[t] = round(float(share), 2)
    return shares
