"""The object chosen by a click: masks from point and box prompts.

A prompt is what a user gives on an image: points on the object, points
that are not on it, and a box around it, in the image's pixels. The mask
follows from it in three steps:

1. **Where to look.** The box (when given) bounds the object; the salient-
   object model runs on the box's neighbourhood, at its native resolution, so
   a small object is seen as well as a large one. Without a box, the model runs
   on the whole image and only its salient components under (or next to) a
   point are kept: a click picks one of several salient things.
2. **GrabCut**, seeded by the prompt: a disc around each point is sure
   object, a disc around each excluded point sure background, everything
   outside the box sure background; the saliency kept marks the probable
   object, the rest of the box the probable background. A click on
   something the model does not find salient still grows into that thing
   (a disc of probable object around the point starts it).
3. **Clean-up.** The components holding a point (or, with a box alone, the
   largest ones) with small holes filled; excluded points stay out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np
from skimage.segmentation import random_walker

from ..errors import InputError
from ._grabcut import check_image, grabcut_labels, keep_main_object
from ._u2net import SalientModel, predict_raw

__all__ = ["Prompt", "prompted_mask", "prompted_regions"]

#: Radius of a point's sure disc, as a share of the image's diagonal.
_POINT_RADIUS = 0.01
#: Radius of the probable-object disc that starts an object the model missed, as a share of the diagonal.
_SEED_RADIUS = 0.04
#: The box's neighbourhood the salient model sees, as a share of the box's size on each side.
_BOX_MARGIN = 0.15
#: A salient component counts as clicked within this share of the diagonal from a point.
_TOUCH = 0.02
#: A salient region shared by points and excluded points is split at most this long side (pixels); and how
#: strongly colour edges stop the random walk (scikit-image's default).
_SPLIT_SIDE = 512
_SPLIT_BETA = 130.0


@dataclass(frozen=True)
class Prompt:
    """Points on the object, points off it, and a box around it, in pixels of one image.

    points, exclude : tuples of (x, y); box : (x0, y0, x1, y1) or None.
    """

    points: tuple[tuple[float, float], ...] = ()
    box: tuple[float, float, float, float] | None = None
    exclude: tuple[tuple[float, float], ...] = field(default=())

    def __bool__(self) -> bool:
        """True when it says where the object is (a point or a box; excluded points alone do not)."""
        return bool(self.points) or self.box is not None

    def check(self, width: int, height: int, what: str = "image") -> None:
        """Raise :class:`InputError` unless every point lies in a ``width`` x ``height`` image and the box has area."""
        for name, points in (("point", self.points), ("excluded point", self.exclude)):
            for x, y in points:
                if not (np.isfinite(x) and np.isfinite(y) and 0 <= x <= width - 1 and 0 <= y <= height - 1):
                    raise InputError(f"{name} {_xy(x, y)} lies outside the {width}x{height} {what}")
        if self.box is not None:
            x0, y0, x1, y1 = self.box
            if not all(np.isfinite(v) for v in self.box):
                raise InputError(f"box {self.box} is not four finite numbers")
            if x1 <= x0 or y1 <= y0:
                raise InputError(f"box {_xy(x0, y0)}-{_xy(x1, y1)} has no area (need X0 < X1 and Y0 < Y1)")
            if x1 < 0 or y1 < 0 or x0 > width - 1 or y0 > height - 1:
                raise InputError(f"box {_xy(x0, y0)}-{_xy(x1, y1)} lies outside the {width}x{height} {what}")
        if not self and self.exclude:
            raise InputError("excluded points need a point or a box on the object too")

    def scaled(self, fx: float, fy: float | None = None) -> "Prompt":
        """The prompt on the image scaled by ``fx`` across and ``fy`` (default ``fx``) down, pixel centres kept
        (``(x + 0.5) f - 0.5``)."""
        fy = fx if fy is None else fy

        def move(x: float, y: float) -> tuple[float, float]:
            return (x + 0.5) * fx - 0.5, (y + 0.5) * fy - 0.5

        box = None if self.box is None else (*move(*self.box[:2]), *move(*self.box[2:]))
        return Prompt(tuple(move(x, y) for x, y in self.points), box, tuple(move(x, y) for x, y in self.exclude))


def _xy(x: float, y: float) -> str:
    return f"{x:g},{y:g}"


def _discs(shape: tuple[int, int], points, radius: int) -> np.ndarray:
    """(H, W) bool: discs of ``radius`` pixels about (x, y) ``points``."""
    out = np.zeros(shape, np.uint8)
    for x, y in points:
        cv2.circle(out, (int(round(x)), int(round(y))), radius, 1, -1)
    return out.astype(bool)


def _components_touching(mask: np.ndarray, near: np.ndarray, unless: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: the 8-connected components of ``mask`` that overlap ``near``, except those overlapping
    ``unless``."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[labels[near]] = True
    if unless is not None:
        keep[labels[unless]] = False
    keep[0] = False
    return keep[labels]


def _box_pixels(box, width: int, height: int, margin: float = 0.0) -> tuple[int, int, int, int]:
    """Integer (x0, y0, x1, y1) (exclusive ends) of ``box`` grown by ``margin`` of its size, clipped."""
    x0, y0, x1, y1 = box
    mx, my = margin * (x1 - x0), margin * (y1 - y0)
    return (max(0, int(np.floor(x0 - mx))), max(0, int(np.floor(y0 - my))),
            min(width, int(np.ceil(x1 + mx)) + 1), min(height, int(np.ceil(y1 + my)) + 1))


def _saliency(image: np.ndarray, prompt: Prompt, model: SalientModel | None) -> np.ndarray:
    """(H, W) float32 object probability: the model (by default the packaged one) on the box's neighbourhood
    (zero elsewhere), or on the image."""
    h, w = image.shape[:2]
    if prompt.box is None:
        return predict_raw(image, model)
    x0, y0, x1, y1 = _box_pixels(prompt.box, w, h, _BOX_MARGIN)
    prob = np.zeros((h, w), np.float32)
    if x1 - x0 >= 8 and y1 - y0 >= 8:
        prob[y0:y1, x0:x1] = predict_raw(np.ascontiguousarray(image[y0:y1, x0:x1]), model)
    return prob


def _split_at_exclusions(image: np.ndarray, salient: np.ndarray, points, exclude, radius: int) -> np.ndarray:
    """(H, W) bool: the share of ``salient`` (H, W) bool that belongs with the ``points`` rather than with the
    ``exclude`` points lying on it (all of it when none does), split by a random walk over the image (H, W, 3)."""
    h, w = salient.shape
    scale = min(1.0, _SPLIT_SIDE / max(h, w))
    size = (max(8, round(w * scale)), max(8, round(h * scale)))

    def small(array: np.ndarray, interpolation: int) -> np.ndarray:
        return cv2.resize(array, size, interpolation=interpolation) if size != (w, h) else array

    region = small(salient.astype(np.uint8), cv2.INTER_NEAREST).astype(bool)
    seed_radius = max(1, round(radius * scale))
    fx, fy = size[0] / w, size[1] / h
    ours = _discs(region.shape, [((x + 0.5) * fx - 0.5, (y + 0.5) * fy - 0.5) for x, y in points], seed_radius)
    theirs = _discs(region.shape, [((x + 0.5) * fx - 0.5, (y + 0.5) * fy - 0.5) for x, y in exclude], seed_radius)
    theirs &= region & ~ours
    if not theirs.any():
        return salient
    labels = np.where(region | ours, 0, -1).astype(np.int32)  # -1: outside the walk
    labels[ours] = 1
    labels[theirs] = 2
    colour = small(image, cv2.INTER_AREA).astype(np.float64) / 255.0
    with warnings.catch_warnings():  # probabilities a hair outside [0, 1] do not change which side is likelier
        warnings.filterwarnings("ignore", "The probability range is outside", UserWarning)
        side = random_walker(colour, labels, beta=_SPLIT_BETA, mode="cg_j", tol=1e-5, channel_axis=-1)
    mine = (side == 1).astype(np.float32)
    if size != (w, h):
        mine = cv2.resize(mine, (w, h), interpolation=cv2.INTER_LINEAR)
    return salient & (mine >= 0.5)


def prompted_mask(image: np.ndarray, prompt: Prompt, *, model: SalientModel | None = None,
                  iterations: int = 5) -> np.ndarray:
    """(H, W, 3) uint8 RGB image and a prompt in its pixels → (H, W) bool mask of the object prompted.

    Raises :class:`InputError` on a bad prompt (see :meth:`Prompt.check`) or when it selects nothing.
    """
    return prompted_regions(image, prompt, model=model, iterations=iterations)[0]


def prompted_regions(image: np.ndarray, prompt: Prompt, *, model: SalientModel | None = None,
                     iterations: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """The object prompted and what the excluded points put out: two disjoint (H, W) bool masks.

    The second holds the excluded points' discs, the salient things they lie on and, of a salient region
    shared with the points, the side split off (empty without excluded points). Raises as
    :func:`prompted_mask`.
    """
    check_image(image)
    h, w = image.shape[:2]
    prompt.check(w, h)
    if not prompt:
        raise InputError("a prompt needs a point or a box on the object")
    diagonal = float(np.hypot(w, h))
    radius = max(1, round(_POINT_RADIUS * diagonal))
    salient = _saliency(image, prompt, model) >= 0.5
    touch = max(radius, round(_TOUCH * diagonal))
    # A salient thing next to an excluded point and no point is background as a whole.
    near_points = _discs((h, w), prompt.points, touch)
    rejected = _components_touching(salient, _discs((h, w), prompt.exclude, touch), near_points)
    if prompt.points:  # keep the salient components a point is on (or next to)
        salient = _components_touching(salient, near_points)
    salient &= ~rejected
    split_off = np.zeros((h, w), bool)
    if prompt.points and prompt.exclude:
        kept = _split_at_exclusions(image, salient, prompt.points, prompt.exclude, radius)
        split_off, salient = salient & ~kept, kept
    inside = np.ones((h, w), bool)
    if prompt.box is not None:
        x0, y0, x1, y1 = _box_pixels(prompt.box, w, h)
        inside[:] = False
        inside[y0:y1, x0:x1] = True
    labels = np.full((h, w), cv2.GC_PR_BGD, np.uint8)
    labels[salient & inside] = cv2.GC_PR_FGD
    labels[_discs((h, w), prompt.points, max(radius, round(_SEED_RADIUS * diagonal))) & inside] = cv2.GC_PR_FGD
    labels[~inside] = cv2.GC_BGD
    labels[_discs((h, w), prompt.points, radius)] = cv2.GC_FGD
    excluded = _discs((h, w), prompt.exclude, radius)
    background = excluded | rejected
    if split_off.any():  # background but for a band along the split, where GrabCut may still move it
        ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * radius + 1,) * 2)
        background |= split_off & ~cv2.dilate(salient.astype(np.uint8), ring).astype(bool)
    labels[background] = cv2.GC_BGD
    if prompt.box is not None and not (labels == cv2.GC_PR_FGD).any() and not prompt.points:
        labels[inside & ~excluded] = cv2.GC_PR_FGD  # nothing salient in the box: the box itself starts GrabCut
    if (labels == cv2.GC_BGD).all() or not np.isin(labels, (cv2.GC_BGD, cv2.GC_PR_BGD)).any():
        raise InputError("the prompt leaves GrabCut no object or no background to compare it with")
    mask = grabcut_labels(image, labels, iterations) & ~excluded
    if prompt.points:  # the components holding a point
        mask = _components_touching(mask, _discs((h, w), prompt.points, radius))
    if not mask.any():
        raise InputError("the prompt selects nothing: no object found at the points or in the box given")
    mask = keep_main_object(mask, keep_fraction=0.0 if prompt.points else 0.2)
    return mask, (excluded | rejected | split_off) & ~mask
