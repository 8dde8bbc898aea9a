"""Source masks from a prompt on the first frame: the clicked object followed through the video.

The prompt (points, a box, excluded points; :class:`~marionette.segment.prompt.Prompt`)
gives frame 0's mask (:func:`~marionette.segment.prompt.prompted_regions`). Each
next frame starts from the previous mask carried along the dense optical
flow (DIS, as :mod:`.foreground` computes it). Carried masks drift (an
object that turns or comes closer outgrows them), so each frame is
re-anchored on the automatic masks (:func:`~.foreground.auto_masks`:
saliency and motion, sharp boundaries), restricted to the prompted object:
their components that lie mostly inside the carried mask (``_INSIDE``) are
the object when they agree with it (IoU ``_AGREE``). Where they do not (the
automatic choice took something else, or nothing), the carried mask's
boundary is snapped to the frame's colour edges by GrabCut (the carried
mask, blurred, is its soft prior: it may move the boundary a few pixels,
not jump to another object), and kept as carried if GrabCut strays too;
an automatic mask that holds the carried one with more (the arm holding a
bag) still bounds the snapped mask, so it does not spread frame by frame
over a background of the object's colours. What excluded points put out of
frame 0 (:func:`~marionette.segment.prompt.prompted_regions`) is carried
along the flow as well and kept out of every frame.
Work is at the working size of
:class:`~marionette.source.foreground.ForegroundOptions`.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from ..errors import InputError
from ..io.video import PackedMasks, VideoFrames, check_frames
from ..segment import SalientModel
from ..segment._grabcut import keep_main_object
from ..segment.prompt import Prompt, prompted_regions
from .foreground import ForegroundOptions, _Flows, _pixel_grid, _snap_to_edges, _warp, auto_masks

__all__ = ["prompted_masks"]

#: An automatic or GrabCut-snapped mask replaces the carried one when their IoU reaches this.
_AGREE = 0.6
#: An automatic mask's component belongs to the prompted object when this share of it lies in the carried mask.
_INSIDE = 0.5
#: Frame 0's mask is cut to what moves with the clicks between frame 0 and this frame (see _moving_with) ...
_LOOKAHEAD = 4
#: ... when the mask's median flow reaches this (working pixels), a pixel agreeing within this share of it
#: (or 1 px), and the part kept is between these shares of the mask.
_MIN_FLOW = 1.5
_AGREE_FLOW = 0.25
_MIN_SHARE, _MAX_SHARE = 0.05, 0.9
#: ... and the rest is another object when its motion parts from the points' by this many times the agreement
#: all along the seam (10th percentile). Measured on frame 0: the faces of single synthetic boxes part by 0.45-4.2
#: times, the car of davis_car-shadow by 4.3, two synthetic boxes that touch by 11-14.
_SEPARATE = 6.0
#: A frame's mask reaches at most this many ``reach`` beyond the previous one carried into it.
_GROWTH = 3
#: An automatic mask that covers this share of the carried one holds the object (with more, or it would agree):
#: the snapped mask stays within a ``reach`` of it, not spilling onto a background of the object's colours.
_COVERED = 0.9


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def _restricted(automatic: np.ndarray, carried: np.ndarray) -> np.ndarray:
    """(h, w) bool: the components of ``automatic`` that lie mostly (``_INSIDE``) in ``carried``."""
    n, labels = cv2.connectedComponents(automatic.astype(np.uint8), connectivity=8)
    size = np.bincount(labels.ravel(), minlength=n)
    inside = np.bincount(labels.ravel(), weights=carried.ravel(), minlength=n)
    keep = inside >= _INSIDE * np.maximum(size, 1)
    keep[0] = False
    return keep[labels]


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

    scaled = prompt.scaled(w / W)
    # a bad prompt fails before the long work
    first, away = prompted_regions(small(0), scaled, model=model)
    away = away if away.any() else None  # what the excluded points put out stays out, carried along the flow
    total = 5 * T - 2  # auto_masks reports 4 T - 2 steps, then one per frame here

    def report(done: int, _: int) -> None:
        if progress is not None:
            progress(done, total)

    try:
        automatic = auto_masks(frames, options=options, model=model, packed=True, progress=report)
    except InputError:  # nothing salient or moving anywhere: the carried masks alone
        automatic = None
    # The frames are read again in each pass rather than kept (in colour at the working size they would hold
    # 0.4 GB for 1000 frames); only their grey images are, for the flow.
    grey = np.empty((T, h, w), np.uint8)
    for t in range(T):
        grey[t] = cv2.cvtColor(small(t), cv2.COLOR_RGB2GRAY)
    first = _moving_with(first, scaled.points, grey)
    bwd = _Flows(grey, forward=False, keep=2)  # flow t+1 → t, in frame t+1's grid
    reach = max(1, round(options.reach * max(w, h)))
    masks = PackedMasks(T, h, w)
    masks[0] = first if automatic is None else _follow(first, None, automatic[0], (w, h), reach, away, snap=False)
    out = PackedMasks(T, H, W) if packed else np.empty((T, H, W), bool)
    for t in range(T):
        if t:
            carried = _warp(masks[t - 1].astype(np.float32), bwd[t - 1]) >= 0.5
            if not carried.any():
                raise InputError(f"the prompted object is lost at frame {t} (it left the picture?); "
                                 "pass --masks DIR")
            if away is not None:
                away = _warp(away.astype(np.float32), bwd[t - 1]) >= 0.5
            masks[t] = _follow(carried, small(t), None if automatic is None else automatic[t], (w, h), reach, away)
        out[t] = cv2.resize(masks[t].astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR) >= 0.5
        report(4 * T - 2 + t + 1, total)
    return out


def _moving_with(mask: np.ndarray, points, grey: np.ndarray) -> np.ndarray:
    """Frame 0's mask (h, w) bool cut down to what moves with the clicked points over the next frames.

    Two objects that touch make one salient region, and a click keeps all of it; but they move
    differently. The flow from frame 0 to frame ``_LOOKAHEAD`` (fewer in a short clip) is fitted, around
    each point (its inscribed disc in the mask), by a homography (RANSAC), and the region about the point
    whose flow that homography explains is the point's object, if the rest moves otherwise: the rest's own
    homography must part from the point's all along the seam between them, by ``_SEPARATE`` times what
    counts as agreeing. (A homography is one plane's motion: another face of the same rigid object is
    not explained by it either, but the two faces' homographies agree where the faces meet.) When
    everything moves alike (one object, or nothing moves) the mask stays whole.
    """
    if not points or len(grey) < 2:
        return mask
    later = min(len(grey) - 1, _LOOKAHEAD)
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(grey[0], grey[later], None)
    moved = np.linalg.norm(flow[mask], axis=1)
    if not len(moved) or np.median(moved) < _MIN_FLOW:
        return mask
    tolerance = max(1.0, _AGREE_FLOW * float(np.median(moved)))
    depth = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    grid = _pixel_grid(*mask.shape)  # (h, w, 2) pixel positions (u, v)
    xs, ys = grid[..., 0], grid[..., 1]
    regions = []  # per point: its homography and the region it explains
    for x, y in points:
        u, v = int(round(min(max(x, 0), mask.shape[1] - 1))), int(round(min(max(y, 0), mask.shape[0] - 1)))
        radius = max(3.0, 0.8 * float(depth[v, u]))
        near = mask & ((xs - u) ** 2 + (ys - v) ** 2 <= radius**2)
        if near.sum() < 8:
            return mask
        homography = _homography(grid[near], flow[near])
        if homography is None:
            return mask
        error = np.linalg.norm(grid + flow - _moved(grid, homography), axis=2)
        agrees = mask & (error < tolerance)
        agrees = cv2.morphologyEx(agrees.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)
        _, labels = cv2.connectedComponents(agrees.astype(np.uint8), connectivity=8)
        if labels[v, u]:
            regions.append((homography, labels == labels[v, u]))
    keep = np.zeros_like(mask)
    for _, region in regions:
        keep |= region
    share = keep.sum() / mask.sum()
    if not _MIN_SHARE <= share <= _MAX_SHARE:  # nothing clear, or everything moves alike: the mask as it was
        return mask
    rest = mask & ~cv2.dilate(keep.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    other = _homography(grid[rest], flow[rest]) if rest.sum() >= 16 else None
    if other is None:
        return mask
    for homography, region in regions:  # a seam where the two motions meet is a crease of one object
        seam = grid[cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & mask & ~keep]
        if not len(seam):
            return mask
        parting = np.linalg.norm(_moved(seam, homography) - _moved(seam, other), axis=-1)
        if np.percentile(parting, 10) < _SEPARATE * tolerance:
            return mask
    filled = keep_main_object(keep, keep_fraction=0.0)
    return filled & mask


def _homography(source: np.ndarray, flow: np.ndarray) -> np.ndarray | None:
    """(3, 3) homography (RANSAC, 1 px) taking pixels ``source`` (N, 2) to ``source + flow``, or None."""
    homography, _ = cv2.findHomography(source, source + flow, cv2.RANSAC, 1.0)
    return homography


def _moved(points: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """Pixels ``points`` (..., 2) float32 moved by ``homography`` (3, 3)."""
    return cv2.perspectiveTransform(points.reshape(-1, 1, 2), homography).reshape(points.shape)


def _follow(carried: np.ndarray, image: np.ndarray | None, automatic: np.ndarray | None, size: tuple[int, int],
            reach: int, away: np.ndarray | None = None, snap: bool = True) -> np.ndarray:
    """A frame's mask from the previous one carried into it (h, w) bool, the frame (h, w, 3) at working size
    and its automatic mask (full size, or None), never on ``away`` (h, w) bool (what excluded points put out);
    without ``snap``, no GrabCut and no frame needed (frame 0's mask is GrabCut's)."""
    if away is not None:
        carried = carried & ~away
    if automatic is not None:
        automatic = cv2.resize(automatic.astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5
        if away is not None:
            automatic &= ~away
        found = _restricted(automatic, carried)
        # Not past a few reaches from the carried mask: an object touching it is not let in.
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * _GROWTH * reach + 1,) * 2)
        found &= cv2.dilate(carried.astype(np.uint8), disc).astype(bool)
        if _iou(found, carried) >= _AGREE:
            return found
    if not snap:
        return carried
    snapped = _snap_to_edges(image, carried, reach)
    if automatic is not None:  # it holds the object with more (the person holding it): the object stays within it
        ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1,) * 2)
        near = cv2.dilate(automatic.astype(np.uint8), ring).astype(bool)
        if (carried & near).sum() >= _COVERED * carried.sum():
            snapped &= near
    if away is not None:
        snapped &= ~away
    return snapped if _iou(snapped, carried) >= _AGREE else carried
