"""Fitting views: each used source frame cropped to its object and downscaled, with its camera.

A view's camera is the prior's camera (world frame = source camera of frame
0, ``world_to_camera`` identity) with its intrinsics scaled to the working
resolution and its principal point moved by the crop's corner, so a point
projects to the same object pixel as in the full frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Camera

__all__ = ["FitView", "make_view", "crop_box", "box_size"]


@dataclass(frozen=True)
class FitView:
    """One source frame as the fit sees it.

    Attributes
    ----------
    frame : int
        Index of the source frame (the prior's time ``t``).
    camera : Camera
        Cropped, downscaled camera (H x W below), identity pose.
    target : (H, W, 3) float32
        The frame in [0, 1] with everything off the object set to white.
    mask : (H, W) float32
        Object coverage in [0, 1].
    frame_box : (4,) int or None
        The whole frame ``x0, y0, x1, y1`` (exclusive ends) in the crop's pixels; None: the crop is the
        frame. What projects inside the frame but outside the crop is off the object.
    covered : bool
        Something in front covers part of the object (:mod:`.occlusion`): the mask shows only the rest, and the
        fit is told only that the object is there and looks so, not that it is absent elsewhere.
    """

    frame: int
    camera: Camera
    target: np.ndarray
    mask: np.ndarray
    frame_box: tuple[int, int, int, int] | None = None
    covered: bool = False


def box_size(mask: np.ndarray) -> np.ndarray:
    """(2,) width and height in pixels of the box around the (H, W) bool mask's pixels (not empty)."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.max() - xs.min() + 1, ys.max() - ys.min() + 1], float)


def crop_box(mask: np.ndarray, margin: float = 0.1, pad: int = 4) -> tuple[int, int, int, int]:
    """(H, W) bool mask → box ``x0, y0, x1, y1`` (exclusive ends) around its pixels with a margin, in the image."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    m = int(round(margin * max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1))) + pad
    return (max(int(xs.min()) - m, 0), max(int(ys.min()) - m, 0),
            min(int(xs.max()) + 1 + m, w), min(int(ys.max()) + 1 + m, h))


def make_view(frame_index: int, image: np.ndarray, mask: np.ndarray, K: np.ndarray, scale: float, *,
              covered: bool = False) -> FitView:
    """A fitting view of one frame.

    Parameters
    ----------
    frame_index : source frame number ``t``.
    image : (H, W, 3) uint8 frame at the prior's resolution.
    mask : (H, W) bool object mask; not empty.
    K : (3, 3) intrinsics of the prior.
    scale : working resolution over the prior's (<= 1).
    covered : something in front covers part of the object (see :class:`FitView`).
    """
    h, w = mask.shape
    camera = Camera(K, np.eye(4), w, h)
    if scale < 1.0:
        sw, sh = max(int(round(w * scale)), 8), max(int(round(h * scale)), 8)
        image = cv2.resize(image, (sw, sh), interpolation=cv2.INTER_AREA)
        cover = cv2.resize(mask.astype(np.float32), (sw, sh), interpolation=cv2.INTER_AREA)
        camera = camera.resized(sw, sh)
    else:
        cover = mask.astype(np.float32)
    cover_full_h, cover_full_w = cover.shape
    x0, y0, x1, y1 = crop_box(cover > 0.5 if (cover > 0.5).any() else cover > 0)
    k = camera.K.copy()
    k[0, 2] -= x0
    k[1, 2] -= y0
    crop_cam = Camera(k, np.eye(4), x1 - x0, y1 - y0)
    rgb = image[y0:y1, x0:x1].astype(np.float32) / 255.0
    cover = np.ascontiguousarray(cover[y0:y1, x0:x1])
    target = rgb * cover[..., None] + (1.0 - cover[..., None])  # object composited onto white by its coverage
    frame_box = (-x0, -y0, cover_full_w - x0, cover_full_h - y0)
    return FitView(frame_index, crop_cam, np.ascontiguousarray(target, dtype=np.float32), cover, frame_box, covered)
