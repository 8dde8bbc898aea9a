"""Source masks from a prompt on the first frame: the clicked object followed through the video.

The prompt (points, a box, excluded points; :class:`~marionette.segment.prompt.Prompt`)
gives frame 0's mask (:func:`~marionette.segment.prompt.prompted_mask`). Each
next frame takes the previous mask carried along the dense optical flow
(DIS, as :mod:`.foreground` computes it), its boundary snapped to the
frame's colour edges by GrabCut (the carried mask, blurred, is GrabCut's
soft prior: it may move the boundary a few pixels, not jump to another
object); when GrabCut strays from the carried mask (IoU below
``_AGREE``) the carried mask is kept. Work is at the working size of
:class:`~marionette.source.foreground.ForegroundOptions`.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from ..errors import InputError
from ..io.video import PackedMasks, VideoFrames, check_frames
from ..segment import SalientModel
from ..segment.prompt import Prompt, prompted_mask
from .foreground import ForegroundOptions, _Flows, _snap_to_edges, _warp

__all__ = ["prompted_masks"]

#: A frame's GrabCut-snapped mask is kept when its IoU with the carried mask reaches this.
_AGREE = 0.7


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def prompted_masks(frames: np.ndarray | VideoFrames, prompt: Prompt, *, options: ForegroundOptions | None = None,
                   model: SalientModel | None = None, packed: bool = False,
                   progress: Callable[[int, int], None] | None = None) -> np.ndarray | PackedMasks:
    """(T, H, W) bool masks of the object ``prompt`` picks on frame 0 (pixels of the frames given).

    Raises :class:`InputError` on a prompt outside the frame or one that selects nothing.
    """
    check_frames(frames, min_frames=2, min_side=16)
    options = options or ForegroundOptions()
    T, H, W = frames.shape[:3]
    prompt.check(W, H, "first frame")
    scale = min(1.0, options.work_side / max(H, W))
    w, h = max(16, round(W * scale)), max(16, round(H * scale))

    def small(t: int) -> np.ndarray:
        return cv2.resize(frames[t], (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (W, H) else frames[t]

    colour = [small(t) for t in range(T)]
    grey = np.stack([cv2.cvtColor(c, cv2.COLOR_RGB2GRAY) for c in colour])
    bwd = _Flows(grey, forward=False, keep=2)  # flow t+1 → t, in frame t+1's grid
    reach = max(1, round(options.reach * max(w, h)))
    masks = PackedMasks(T, h, w)
    masks[0] = prompted_mask(colour[0], prompt.scaled(w / W), model=model)
    out = PackedMasks(T, H, W) if packed else np.empty((T, H, W), bool)
    for t in range(T):
        if t:
            carried = _warp(masks[t - 1].astype(np.float32), bwd[t - 1]) >= 0.5
            if not carried.any():
                raise InputError(f"the prompted object is lost at frame {t} (it left the picture?); "
                                 "pass --masks DIR")
            snapped = _snap_to_edges(colour[t], carried, reach)
            masks[t] = snapped if _iou(snapped, carried) >= _AGREE else carried
        out[t] = cv2.resize(masks[t].astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR) >= 0.5
        if progress is not None:
            progress(t + 1, T)
    return out
