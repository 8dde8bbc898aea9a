"""GrabCut object masks and the mask clean-up shared by the segmenters.

GrabCut (Rother, Kolmogorov and Blake, "GrabCut: interactive foreground
extraction using iterated graph cuts", SIGGRAPH 2004) fits colour mixture
models to foreground and background and cuts the image graph between them.
Here it is started either from a rectangle (a fallback needing no model) or
from a saliency map, whose uncertain boundary it snaps to colour edges.

Images are RGB ``uint8`` of shape (H, W, 3); masks (H, W) bool.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from ..errors import InputError

__all__ = ["check_image", "keep_main_object", "grabcut_mask", "grabcut_labels", "refine_with_grabcut"]


def check_image(image: np.ndarray) -> None:
    """Raise InputError unless ``image`` is an (H, W, 3) uint8 array."""
    if not isinstance(image, np.ndarray):
        raise InputError(f"image must be an (H, W, 3) uint8 RGB array, got {type(image).__name__}")
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"image must be an (H, W, 3) uint8 RGB array, got {image.dtype} of shape {image.shape}")
    if min(image.shape[:2]) < 8:
        raise InputError(f"image is too small to segment: {image.shape[1]}x{image.shape[0]} pixels")


def keep_main_object(mask: np.ndarray, *, keep_fraction: float = 0.2, hole_fraction: float = 0.003) -> np.ndarray:
    """(H, W) bool → (H, W) bool: the main object of a noisy mask.

    Keeps the largest 8-connected component and every other one of at least
    ``keep_fraction`` of its area (an object split by an occluder), then fills
    holes smaller than ``hole_fraction`` of the kept area. Large holes stay:
    they are real (between a chair's legs, inside a handle).

    Raises InputError if the mask is empty.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n < 2:
        raise InputError("no object found in the image: the mask is empty")
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(n, bool)
    keep[1:] = areas >= keep_fraction * areas.max()
    out = keep[labels]
    # Holes are the background components the border cannot reach (4-connected,
    # the dual of the 8-connected foreground).
    holes, count = ndimage.label(ndimage.binary_fill_holes(out) & ~out)
    if count:
        sizes = np.bincount(holes.ravel())
        small = sizes < hole_fraction * out.sum()
        small[0] = False
        out |= small[holes]
    return out


def _central_rect(H: int, W: int, margin: float = 0.05) -> tuple[int, int, int, int]:
    """(x, y, w, h) of the image's centre, ``margin`` of each side left out."""
    mx, my = max(1, round(margin * W)), max(1, round(margin * H))
    return mx, my, W - 2 * mx, H - 2 * my


def _labels_from_prior(prior: np.ndarray, *, sure_fg: float, sure_bg: float) -> np.ndarray:
    """(H, W) float probability → (H, W) uint8 GrabCut labels.

    Definite foreground/background where the map is confident (``>= sure_fg``
    / ``<= sure_bg``), probable foreground/background on either side of 0.5
    in between: GrabCut may move the uncertain boundary, not invent objects.
    """
    labels = np.where(prior >= 0.5, cv2.GC_PR_FGD, cv2.GC_PR_BGD).astype(np.uint8)
    labels[prior >= sure_fg] = cv2.GC_FGD
    labels[prior <= sure_bg] = cv2.GC_BGD
    return labels


def grabcut_mask(image: np.ndarray, *, rect: tuple[int, int, int, int] | None = None,
                 prior: np.ndarray | None = None, iterations: int = 5,
                 sure_fg: float = 0.7, sure_bg: float = 0.3) -> np.ndarray:
    """(H, W, 3) uint8 RGB image → (H, W) bool GrabCut foreground.

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB.
    rect : (x, y, w, h), optional
        Box holding the object; everything outside is background. Default:
        the centre of the image with 5 % of each side left out.
    prior : (H, W) float in [0, 1], optional
        Foreground probability (e.g. :meth:`SalientModel.predict`) to start
        from instead of a box; see ``sure_fg`` and ``sure_bg``.
    iterations : int
        GrabCut iterations (colour-model re-estimations).
    sure_fg, sure_bg : float
        Prior levels at or above / at or below which pixels are fixed to
        foreground / background; GrabCut decides the others, starting from
        the 0.5 level. The defaults suit U²-Netp maps, which are nearly
        binary: GrabCut then snaps their soft, upsampled edges.

    Raises InputError on bad arguments or when the result is empty (as on a
    uniform image, where both colour models agree). GrabCut has no notion of
    "no object", though: on a graded or busy background it returns some
    region; :func:`salient_mask` is the one that can tell.
    """
    check_image(image)
    H, W = image.shape[:2]
    if not np.ptp(image.reshape(-1, 3), axis=0).any():  # OpenCV's colour models stall on one colour (a minute)
        raise InputError("no object found in the image: it is all one colour")
    if iterations < 1:
        raise InputError(f"iterations must be at least 1, got {iterations}")
    labels = np.zeros((H, W), np.uint8)
    if prior is not None:
        if rect is not None:
            raise InputError("give either rect or prior to grabcut_mask, not both")
        prior = np.asarray(prior)
        if prior.shape != (H, W) or not np.all(np.isfinite(prior)):
            raise InputError(f"prior must be a finite ({H}, {W}) array, got shape {prior.shape}")
        if not 0.0 <= sure_bg < 0.5 <= sure_fg <= 1.0:
            raise InputError(f"need 0 <= sure_bg < 0.5 <= sure_fg <= 1, got sure_bg={sure_bg}, sure_fg={sure_fg}")
        labels = _labels_from_prior(prior, sure_fg=sure_fg, sure_bg=sure_bg)
    else:
        if rect is not None and len(rect) != 4:
            raise InputError(f"rect must be (x, y, w, h), got {rect}")
        x, y, w, h = _central_rect(H, W) if rect is None else (int(v) for v in rect)
        if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > W or y + h > H or w * h == H * W:
            raise InputError(f"rect (x, y, w, h) = {rect} must lie inside the {W}x{H} image "
                             "and leave some background outside it")
        labels[y:y + h, x:x + w] = cv2.GC_PR_FGD
    fg_like = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    if not fg_like.any():
        raise InputError("no object found in the image: the prior has no pixel >= 0.5")
    if fg_like.all():
        raise InputError("the prior marks the whole image as object; GrabCut needs some background")
    out = grabcut_labels(image, labels, iterations)
    if not out.any():
        raise InputError("no object found in the image: GrabCut left no foreground")
    return out


def grabcut_labels(image: np.ndarray, labels: np.ndarray, iterations: int = 5) -> np.ndarray:
    """GrabCut from a label map (H, W) uint8 of ``cv2.GC_*`` values → (H, W) bool foreground.

    Works on the neighbourhood of what is not sure background only: far
    background adds time, not information. Raises InputError when GrabCut
    cannot fit its colour models (one side has too few pixels).
    """
    h, w = labels.shape
    ys, xs = np.nonzero(labels != cv2.GC_BGD)
    pad = max(8, round(0.1 * max(np.ptp(ys), np.ptp(xs))))
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, h)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, w)
    # The crop always holds background-like pixels (a rect's surroundings, or
    # the prior's PR_BGD), which GrabCut needs to fit its background model.
    crop = np.ascontiguousarray(labels[y0:y1, x0:x1])
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = cv2.cvtColor(np.ascontiguousarray(image[y0:y1, x0:x1]), cv2.COLOR_RGB2BGR)
    cv2.setRNGSeed(0)  # GrabCut seeds its colour models (k-means++) from OpenCV's global RNG: make it repeatable
    try:
        cv2.grabCut(bgr, crop, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        raise InputError("GrabCut could not separate the object from its surroundings") from None
    out = np.zeros((h, w), bool)
    out[y0:y1, x0:x1] = (crop == cv2.GC_FGD) | (crop == cv2.GC_PR_FGD)
    return out


def refine_with_grabcut(image: np.ndarray, prob: np.ndarray, *, iterations: int = 5,
                        keep_fraction: float = 0.2) -> np.ndarray:
    """Snap a saliency map's boundary to colour edges → (H, W) bool mask.

    ``prob`` is the (H, W) float map of :meth:`SalientModel.predict`. Of the
    GrabCut foreground only the components that overlap the map's ``>= 0.5``
    region are kept (a similar-looking second object nearby must not join),
    then cleaned like :func:`salient_mask` (main components, small holes).
    """
    mask = grabcut_mask(image, prior=prob, iterations=iterations)
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    touches = np.zeros(n, bool)
    touches[labels[np.asarray(prob) >= 0.5]] = True
    touches[0] = False
    return keep_main_object(touches[labels], keep_fraction=keep_fraction)
