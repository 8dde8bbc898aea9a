"""The photo without its object: the object's region inpainted from the scene around it."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["clean_plate", "INPAINT_METHODS"]

#: How the vacated region is filled: ``fsr`` continues edges and coarse texture, smoothly (OpenCV's
#: frequency-selective reconstruction, Genser et al. 2018); ``patch`` copies patches of the scene in (OpenCV's
#: shift-map, He and Sun 2012: sharp texture, but whole objects may be copied too); ``telea`` diffuses colour
#: inwards (fastest, streaky).
INPAINT_METHODS = ("fsr", "patch", "telea")

#: The object's region is grown by this share of its RMS radius (at least 2 px): a mask's edge leaves a
#: ring of the object's own colours (anti-aliasing, shadows in its crease) that would outline the hole.
_GROW = 0.03
#: The fill's cost grows fast with the hole (FSR about 2 s, shift-map about 5 s for a third of a 256² photo);
#: above these long sides the region is filled at a reduced size and scaled up.
_WORK_SIDE = {"fsr": 256, "patch": 192}


def _grown(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool mask grown by ``_GROW`` of the object's RMS radius."""
    v, u = np.nonzero(mask)
    radius = np.sqrt(((u - u.mean()) ** 2 + (v - v.mean()) ** 2).mean()) if len(u) else 0.0
    grow = max(2, int(round(_GROW * radius)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1,) * 2)
    return cv2.dilate(mask.astype(np.uint8), disc).astype(bool)


def _fill(image: np.ndarray, hole: np.ndarray, method: str) -> np.ndarray:
    """``hole`` of ``image`` filled by OpenCV's FSR or shift-map at a reduced working size; the rest untouched."""
    h, w = hole.shape
    scale = min(1.0, _WORK_SIDE[method] / max(h, w))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    small = cv2.resize(image, size, interpolation=cv2.INTER_AREA) if scale < 1 else image
    # Any share of hole makes a working pixel hole (uint8 area averages would round small shares away).
    small_hole = (cv2.resize(hole.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0) if scale < 1 else hole
    # The hidden object's own colours must not reach the fill (FSR reads the hole's values as its start):
    # the hole starts as a diffusion of its surroundings.
    small = cv2.inpaint(np.ascontiguousarray(small), small_hole.astype(np.uint8), 3, cv2.INPAINT_TELEA)
    filled = np.empty_like(small)
    known = (~small_hole).astype(np.uint8)
    if method == "fsr":
        cv2.xphoto.inpaint(small, known, filled, cv2.xphoto.INPAINT_FSR_FAST)
    else:  # shift-map compares patches in CIELab
        cv2.xphoto.inpaint(cv2.cvtColor(small, cv2.COLOR_RGB2Lab), known, filled, cv2.xphoto.INPAINT_SHIFTMAP)
        filled = cv2.cvtColor(filled, cv2.COLOR_Lab2RGB)
    if scale < 1:
        filled = cv2.resize(filled, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.where(hole[..., None], filled, image)


def clean_plate(image: np.ndarray, mask: np.ndarray, method: str = "fsr") -> np.ndarray:
    """The photo with its object removed.

    Parameters
    ----------
    image : (H, W, 3|4) uint8 photo (an alpha channel is ignored).
    mask : (H, W) bool, the object's pixels; the region filled is this mask grown a little.
    method : one of :data:`INPAINT_METHODS`.

    Returns
    -------
    (H, W, 3) uint8: the photo outside the grown mask, the scene continued inside it.
    """
    if method not in INPAINT_METHODS:
        raise InputError(f"inpainting method must be one of {', '.join(INPAINT_METHODS)}, got {method!r}")
    rgb = np.ascontiguousarray(image[..., :3])
    if mask.shape != rgb.shape[:2]:
        raise InputError(f"mask is {mask.shape[1]}x{mask.shape[0]} but the photo is {rgb.shape[1]}x{rgb.shape[0]}")
    hole = _grown(mask)
    if hole.all():
        raise InputError("the object covers the whole photo: there is no scene to keep around it")
    if not hole.any():
        return rgb.copy()
    if method == "telea":
        radius = max(3, int(round(0.01 * max(hole.shape))))
        return cv2.inpaint(rgb, hole.astype(np.uint8), radius, cv2.INPAINT_TELEA)
    return _fill(rgb, hole, method)
