"""Automatic foreground masks for a source video given without masks (Motion Marionette stage 2).

The moving object is found from two cues, each weak on its own:

- **saliency**: U²-Netp (:mod:`marionette.segment`) on key frames, every
  ``key_every``-th frame, at its native 320 x 320 input. Sharp boundaries,
  but it also picks salient things that do not move (a parked car, a person
  holding the object) and misses nothing-special-looking objects;
- **motion**: dense optical flow between neighbouring frames (DIS, Kroeger
  et al., ECCV 2016, ``cv2.DISOpticalFlow``); per frame pair the dominant
  background motion is a homography fitted by RANSAC to the flow on a grid
  away from salient things (exact for a static or rotating camera and a
  distant or planar background), and a pixel is *moving* where its flow
  departs from it by more than a threshold (:func:`_moving`). Blurry at
  boundaries, blind to the object while it pauses, and a translating camera
  makes things in front of the background "move" by parallax (a person
  standing in front of stairs). An epipolar model would explain parallax
  but is degenerate for a static camera, where it can explain a translating
  object as well; it is not used.

Saliency maps are carried from the key frames to every frame along the
flow (from the previous and the next key frame, blended by distance), the
moving masks are gathered over a few neighbouring frames along the flow,
and per frame the two are combined by :func:`_combine`:

"Moving" here means within ``reach`` of a moving pixel (flow blurs
boundaries and misses textureless rims):

1. a salient component that is mostly moving (``>= whole_fraction`` of its
   pixels) is the object: kept whole, with saliency's boundary, except for
   parts farther than ``_WHOLE_REACH`` reaches from any motion (salient
   clutter touching the object);
2. of a salient component that moves only in part (a person carrying a
   swinging bag), only the part that is both salient and moving is kept;
3. salient components that do not move are dropped;
4. if nothing salient moves in a frame, the moving region alone is the
   object (an object saliency misses). A frame where neither cue finds
   anything takes the masks of the nearest frames that have one, carried
   along the flow. If nothing moves in the whole video, saliency alone is
   used: a static scene is not an error here (the motion fit then finds no
   motion); only a video where neither cue finds anything raises InputError.

Then the main connected components are kept and small holes filled, and
the paper's sliding-window union makes a frame's mask the union of its
neighbours' masks (within ``union_radius`` frames), each carried into the
frame along the flow so that a moving object's mask does not smear along its
path: trajectories near the boundary survive a frame where the mask misses
a sliver. GrabCut refinement of the boundary is optional (slow).

Flow and motion are computed at a reduced working size (long side
``work_side``); masks are upsampled to the frames' size at the end.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..io.video import PackedMasks, VideoFrames, check_frames
from ..segment import SalientModel, refine_with_grabcut
from ..segment._grabcut import keep_main_object
from ..segment._u2net import model_in_use

__all__ = ["ForegroundOptions", "auto_masks"]

#: Grid step (working pixels) of the flow samples the background homography is fitted to.
_GRID_STEP = 8
#: RANSAC inlier threshold (working pixels) of the background homography.
_RANSAC_PX = 1.0
#: Fewest background grid samples to fit the background homography to (else all samples are used).
_MIN_SAMPLES = 50
#: A salient component kept whole is cut beyond this many ``reach`` of a moving pixel.
_WHOLE_REACH = 3
#: Bytes of optical flow kept per direction; longer videos recompute flows
#: that fell out of the cache (each stage visits them in order).
_FLOW_CACHE_BYTES = 2**27


@dataclass(frozen=True)
class ForegroundOptions:
    """Settings of :func:`auto_masks`.

    Attributes
    ----------
    work_side : int
        Long side (pixels) at which flow and motion are computed.
    motion_floor : float
        Residual motion (working pixels per frame) below which nothing counts
        as moving: flow noise and the parallax of a hand-held camera.
    motion_relative : float
        A pixel moves when its residual also reaches this fraction of the
        frame's strongest residual (99th percentile), so that a person
        swaying a little behind a swinging bag stays "static".
    motion_window : int
        Moving masks are gathered over this many frames on either side (along
        the flow), so an object that pauses for a moment stays found.
    reach : float
        Salient pixels count as moving within this fraction of the working
        long side from a moving pixel (flow blurs boundaries and misses
        textureless rims).
    whole_fraction : float
        A salient component with at least this fraction of moving pixels is
        kept whole (within ``_WHOLE_REACH`` reaches of motion); below, only
        its moving part (rules 1 and 2 in the module doc).
    union_radius : int
        Sliding-window union over this many frames on either side; 0 turns it off.
    grabcut : bool
        Snap each frame's boundary to colour edges with GrabCut, at the
        working size, before the union (about 30 ms per frame). Off by
        default: on the DAVIS car clips it lowers the IoU by 0.01-0.02.
    """

    work_side: int = 480
    motion_floor: float = 0.7
    motion_relative: float = 0.3
    motion_window: int = 2
    reach: float = 0.02
    whole_fraction: float = 0.5
    union_radius: int = 1
    grabcut: bool = False

    def __post_init__(self) -> None:
        for name, low in (("work_side", 32), ("motion_window", 0), ("union_radius", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < low:
                raise InputError(f"foreground: {name} must be an integer >= {low}, got {value!r}")
        for name in ("motion_floor", "motion_relative", "reach", "whole_fraction"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0 < value):
                raise InputError(f"foreground: {name} must be a positive number, got {value!r}")
        if self.whole_fraction > 1:
            raise InputError(f"foreground: whole_fraction must lie in (0, 1], got {self.whole_fraction}")


class _Flows:
    """Dense optical flow between neighbouring frames, computed on demand: ``flows[t]`` (h, w, 2) float32.

    Forward flows go from frame t to t+1 in frame t's grid, backward ones from
    t+1 to t in frame t+1's grid. The ``keep`` most recently used are cached.
    """

    def __init__(self, grey: np.ndarray, *, forward: bool, keep: int) -> None:
        self._grey, self._forward, self._keep = grey, forward, keep  # grey: (T, h, w) uint8
        self._dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def __len__(self) -> int:
        return len(self._grey) - 1

    def __getitem__(self, t: int) -> np.ndarray:
        if t in self._cache:
            self._cache.move_to_end(t)
            return self._cache[t]
        a, b = (t, t + 1) if self._forward else (t + 1, t)
        flow = self._cache[t] = self._dis.calc(self._grey[a], self._grey[b], None)
        if len(self._cache) > self._keep:
            self._cache.popitem(last=False)
        return flow


@functools.lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> np.ndarray:
    """(h, w, 2) float32 pixel positions (u, v), read-only (cached: every warp needs it)."""
    grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), axis=-1)
    grid.flags.writeable = False
    return grid


def _warp(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Pull ``image`` (h, w[, C]) float32 into the grid of ``flow`` (h, w, 2): out(x) = image(x + flow(x)).

    With ``flow`` from frame a to frame b, ``image`` lives in frame b and the
    result in frame a. Outside the image the result is 0.
    """
    h, w = flow.shape[:2]
    grid = _pixel_grid(h, w)
    return cv2.remap(image, grid + flow, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _background_residual(flow: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(h, w) length of each pixel's flow (h, w, 2) minus the dominant background homography's.

    The homography is fitted by RANSAC to flow samples on a grid over the
    ``background`` (h, w) bool pixels, or over all pixels if those are too
    few; when the fit fails the median flow stands in for it.
    """
    h, w = flow.shape[:2]
    ys, xs = np.mgrid[_GRID_STEP // 2:h:_GRID_STEP, _GRID_STEP // 2:w:_GRID_STEP]
    if background[ys, xs].sum() >= _MIN_SAMPLES:
        ys, xs = ys[background[ys, xs]], xs[background[ys, xs]]
    p0 = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float32)
    p1 = p0 + flow[ys.ravel(), xs.ravel()]
    hom, _ = cv2.findHomography(p0, p1, cv2.RANSAC, _RANSAC_PX)
    if hom is None:
        return np.linalg.norm(flow - np.median(p1 - p0, axis=0), axis=2)
    grid = _pixel_grid(h, w)
    diff = grid + flow - cv2.perspectiveTransform(grid.reshape(-1, 1, 2), hom).reshape(h, w, 2)
    return cv2.magnitude(diff[..., 0], diff[..., 1])


def _moving(residual: np.ndarray, options: ForegroundOptions) -> np.ndarray:
    """(h, w) bool moving pixels of a residual map, specks removed.

    Occlusion edges give a large residual in one flow direction only, so the
    caller passes the smaller of the forward and backward residuals.
    """
    threshold = max(options.motion_floor, options.motion_relative * float(np.percentile(residual, 99)))
    moving = (residual >= threshold).astype(np.uint8)
    return cv2.morphologyEx(moving, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)


def _carry(maps, fwd, bwd, radius: int, out: np.ndarray | PackedMasks | None = None) -> np.ndarray | PackedMasks:
    """(T, h, w) bool: where the union (max) of each frame's map and its neighbours' exceeds 0.5.

    The neighbours are those within ``radius`` frames, carried along the flow.
    maps : (T, h, w) float or bool (an array or PackedMasks); fwd, bwd :
    sequences of T-1 flows (h, w, 2) t → t+1 and t+1 → t (arrays or
    :class:`_Flows`); out : (T, h, w) bool to write into (default: a new
    array). Frame by frame, so only a few maps and flows are in use at once.
    """
    T = len(maps)
    out = np.empty((T,) + maps[0].shape, bool) if out is None else out
    for t in range(T):
        union = maps[t].astype(np.float32)
        for j in range(1, radius + 1):
            if t + j < T:  # frame t + j's map, carried back step by step
                carried = maps[t + j].astype(np.float32)
                for s in range(t + j - 1, t - 1, -1):
                    carried = _warp(carried, fwd[s])
                union = np.maximum(union, carried)
            if t - j >= 0:
                carried = maps[t - j].astype(np.float32)
                for s in range(t - j, t):
                    carried = _warp(carried, bwd[s])
                union = np.maximum(union, carried)
        out[t] = union > 0.5
    return out


def _propagated(keys: dict[int, np.ndarray], fwd, bwd) -> Iterator[np.ndarray]:
    """Maps (h, w) bool of frames 0 … T-1 in order, from key-frame maps ``{t: (h, w) float32}`` along the flow.

    Each frame between two key frames blends the previous key's map carried
    forward and the next key's carried backward, weighted by closeness;
    frames before the first or after the last key take that key's map. A
    pixel is True where the blend reaches 0.5. fwd, bwd as in :func:`_carry`.
    """
    T = len(fwd) + 1

    def carried(start: int, stop: int) -> Iterator[np.ndarray]:
        """The map of key ``start`` carried to each frame from ``start`` to ``stop`` (inclusive)."""
        current, step = keys[start], 1 if stop >= start else -1
        yield current
        for t in range(start, stop, step):
            current = _warp(current, bwd[t] if step > 0 else fwd[t - 1])
            yield current

    order = sorted(keys)
    yield from (m >= 0.5 for m in list(carried(order[0], 0))[::-1])
    for a, b in zip(order[:-1], order[1:]):
        weight = np.linspace(0.0, 1.0, b - a + 1, dtype=np.float32)
        backward = list(carried(b, a))[::-1]
        for i, forward in enumerate(carried(a, b)):
            if i:  # frame a was given by the previous interval
                yield (1 - weight[i]) * forward + weight[i] * backward[i] >= 0.5
    yield from (m >= 0.5 for m in list(carried(order[-1], T - 1))[1:])


def _propagate(keys: dict[int, np.ndarray], fwd, bwd) -> np.ndarray:
    """(T, h, w) bool: :func:`_propagated` as one array."""
    return np.stack(list(_propagated(keys, fwd, bwd)))


def _combine(salient: np.ndarray, moving: np.ndarray, reach: int, whole_fraction: float) -> np.ndarray:
    """(h, w) bool object mask from a salient and a moving mask, by the rules of the module doc.

    Salient pixels count as moving within ``reach`` pixels of a moving one
    (flow blurs boundaries and misses textureless rims); a salient component
    kept whole is still cut ``_WHOLE_REACH`` times further out, so that
    salient clutter touching the object does not join it.
    """
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1,) * 2)
    near = cv2.dilate(moving.astype(np.uint8), disc)
    n, labels = cv2.connectedComponents(salient.astype(np.uint8), connectivity=8)
    size = np.bincount(labels.ravel(), minlength=n)
    whole = np.bincount(labels.ravel(), weights=near.ravel(), minlength=n) >= whole_fraction * size
    whole[0] = False
    wide = cv2.dilate(near, disc, iterations=_WHOLE_REACH - 1).astype(bool)
    mask = (whole[labels] & wide) | (salient & near.astype(bool))
    return mask if mask.any() else moving


def _snap_to_edges(image: np.ndarray, mask: np.ndarray, reach: int) -> np.ndarray:
    """GrabCut refinement of ``mask`` (h, w) bool on ``image`` (h, w, 3): the boundary may move about ``reach`` pixels.

    The mask blurred by ``reach / 2`` is GrabCut's soft prior (sure inside and
    outside, uncertain in the band between); the mask is kept when GrabCut fails.
    """
    if not mask.any():
        return mask
    prior = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), max(reach / 2, 0.5))
    try:
        return refine_with_grabcut(image, prior)
    except InputError:
        return mask


def _clean(mask: np.ndarray) -> np.ndarray:
    """Main connected components with small holes filled; empty stays empty."""
    return keep_main_object(mask) if mask.any() else mask


def auto_masks(frames: np.ndarray | VideoFrames, *, key_every: int = 8, options: ForegroundOptions | None = None,
               model: SalientModel | None = None, packed: bool = False,
               progress: Callable[[int, int], None] | None = None) -> np.ndarray | PackedMasks:
    """Foreground masks of the moving object in a video, from saliency and motion.

    The frames are read once, in order (twice with GrabCut); what is kept of
    the whole video is at the working size (a greyscale image and packed
    masks per frame), and flows are recomputed when they fall out of a
    bounded cache.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W, 3), uint8, or VideoFrames
        RGB video frames, T >= 2.
    key_every : int
        The salient-object model runs on every ``key_every``-th frame and the last one.
    options : ForegroundOptions, optional
        Motion thresholds, windows and clean-up; defaults documented there.
    model : SalientModel, optional
        The salient-object network; by default the packaged U²-Netp, whose
        session is released once the key frames are done.
    packed : bool
        Return :class:`~marionette.io.video.PackedMasks` (an eighth of the memory).
    progress : callable(done, total), optional
        Called as frames, flows and masks are done.

    Returns
    -------
    ndarray, shape (T, H, W), bool, or PackedMasks
        Object mask per frame.

    Raises
    ------
    InputError
        On malformed frames or options, or when no frame shows a salient or
        moving object.
    """
    check_frames(frames, min_frames=2, min_side=16)
    if isinstance(key_every, bool) or int(key_every) != key_every or key_every < 1:
        raise InputError(f"foreground: key_every must be an integer >= 1, got {key_every!r}")
    options = options or ForegroundOptions()
    T, H, W = frames.shape[:3]
    scale = min(1.0, options.work_side / max(H, W))
    w, h = max(16, round(W * scale)), max(16, round(H * scale))
    keys = set(range(0, T, key_every)) | {T - 1}
    total, done = T + 2 * (T - 1) + T, 0

    def advance() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    grey = np.empty((T, h, w), np.uint8)
    salient_keys = {}
    with model_in_use(model) as salient:  # nothing after needs its session's memory arena (0.5 GB)
        for t in range(T):
            frame = frames[t]
            grey[t] = cv2.resize(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY), (w, h), interpolation=cv2.INTER_AREA)
            if t in keys:
                prob = salient.predict(frame, normalize=False)
                salient_keys[t] = cv2.resize(prob, (w, h), interpolation=cv2.INTER_AREA)
            advance()
    keep = max(_FLOW_CACHE_BYTES // (8 * h * w), key_every + 2 * max(options.motion_window, options.union_radius) + 2)
    fwd = _Flows(grey, forward=True, keep=keep)  # flow t → t+1, in frame t's grid
    bwd = _Flows(grey, forward=False, keep=keep)  # flow t+1 → t, in frame t+1's grid

    # The background motion is fitted away from salient things (and their flow-blurred rims).
    reach = max(1, round(options.reach * max(w, h)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1,) * 2)
    salient, moving = PackedMasks(T, h, w), PackedMasks(T, h, w)
    previous = res_bwd = None  # frame t-1's background, and its backward residual
    for t, mask in enumerate(_propagated(salient_keys, fwd, bwd)):
        salient[t] = mask
        background = ~cv2.dilate(mask.astype(np.uint8), disc).astype(bool)
        if t:  # the pair t-1 → t, with both frames' saliency known
            res_fwd = _background_residual(fwd[t - 1], previous)
            # Residual of frame t-1: the smaller of its forward and backward ones (see _moving).
            moving[t - 1] = _moving(res_fwd if res_bwd is None else np.minimum(res_fwd, res_bwd), options)
            res_bwd = _background_residual(bwd[t - 1], background)
            advance()
            advance()
        previous = background
    moving[T - 1] = _moving(res_bwd, options)
    moving = _carry(moving, fwd, bwd, options.motion_window, out=PackedMasks(T, h, w))

    masks = PackedMasks(T, h, w)
    anything_moves = moving.any()
    for t in range(T):  # without motion anywhere (a static scene), saliency alone
        masks[t] = _clean(_combine(salient[t], moving[t], reach, options.whole_fraction) if anything_moves
                          else salient[t])
    found = np.array([m.any() for m in masks])
    if not found.any():
        raise InputError("could not find a moving object; pass --masks DIR")
    if not found.all():  # frames where neither cue found the object take their neighbours' masks
        edges = found & ~(np.r_[found[1:], True] & np.r_[True, found[:-1]])  # found next to not found
        filled = _propagate({t: masks[t].astype(np.float32) for t in np.nonzero(edges)[0]}, fwd, bwd)
        for t in np.nonzero(~found)[0]:
            masks[t] = filled[t]
    if options.grabcut:
        for t in range(T):
            masks[t] = _snap_to_edges(cv2.resize(frames[t], (w, h), interpolation=cv2.INTER_AREA), masks[t], reach)
    if options.union_radius:
        masks = _carry(masks, fwd, bwd, options.union_radius, out=PackedMasks(T, h, w))

    out = PackedMasks(T, H, W) if packed else np.empty((T, H, W), bool)
    for t in range(T):
        out[t] = cv2.resize(masks[t].astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR) >= 0.5
        advance()
    return out
