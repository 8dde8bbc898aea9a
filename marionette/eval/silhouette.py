"""The rendered object's silhouette against the true masks, frame by frame: overlap and stray pixels.

Measured on full-frame renders, independently of any fit (a fit that sees
each frame cropped to its object never sees what it draws outside the crop).
The silhouette is where the render's alpha is at least one half; a *stray*
pixel is one the render visibly draws (alpha at least ``drawn``, a tenth: a
tenth darker than a white background shows) farther than ``reach`` pixels
from the mask: a floater, or an object drawn where the frame does not show it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["SilhouetteReport", "silhouette_frame", "STRAY_REACH_PX", "STRAY_SHARE", "DRAWN_ALPHA"]

#: A drawn pixel farther than this from the mask is stray.
STRAY_REACH_PX = 15.0
#: A frame with more than this share of its pixels stray counts as a stray frame.
STRAY_SHARE = 0.005
#: Alpha from which a pixel is drawn, for the stray count.
DRAWN_ALPHA = 0.1


def silhouette_frame(alpha: np.ndarray, mask: np.ndarray, *, reach: float = STRAY_REACH_PX,
                     drawn: float = DRAWN_ALPHA) -> tuple[float, float]:
    """Silhouette IoU and the share of the frame's pixels drawn stray, for one frame.

    alpha : (H, W) float render alpha in [0, 1]; mask : (H, W) bool true object mask.
    An empty mask and an empty silhouette agree (IoU 1); with an empty mask every drawn pixel is stray.
    """
    alpha, mask = np.asarray(alpha), np.asarray(mask, bool)
    if alpha.shape != mask.shape or alpha.ndim != 2:
        raise InputError(f"alpha {alpha.shape} and mask {mask.shape} must be (H, W) arrays of one size")
    silhouette = alpha >= 0.5
    union = np.count_nonzero(silhouette | mask)
    iou = np.count_nonzero(silhouette & mask) / union if union else 1.0
    visible = alpha >= drawn
    if mask.any():
        # distance of every pixel to the nearest mask pixel (exact Euclidean)
        distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        stray = np.count_nonzero(visible & (distance > reach))
    else:
        stray = np.count_nonzero(visible)
    return float(iou), stray / mask.size


@dataclass(frozen=True)
class SilhouetteReport:
    """Per frame: silhouette IoU against the mask and the share of the frame drawn stray.

    iou : (T,) float; stray_share : (T,) float in [0, 1].
    """

    iou: np.ndarray
    stray_share: np.ndarray

    @classmethod
    def of(cls, alphas, masks, **kwargs) -> SilhouetteReport:
        """The report of (T, H, W) alphas against (T, H, W) masks (any iterables of frames)."""
        rows = [silhouette_frame(a, m, **kwargs) for a, m in zip(alphas, masks, strict=True)]
        return cls(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]))

    @property
    def stray_frames(self) -> np.ndarray:
        """Frames with more than :data:`STRAY_SHARE` of their pixels stray, (S,) int."""
        return np.flatnonzero(self.stray_share > STRAY_SHARE)

    def summary(self) -> dict:
        """Median and worst IoU (and its frame), stray frames and the largest stray share, every frame's IoU;
        JSON-ready."""
        worst = int(np.argmin(self.iou))
        return {"iou_median": round(float(np.median(self.iou)), 4), "iou_worst": round(float(self.iou[worst]), 4),
                "worst_frame": worst, "stray_frames": self.stray_frames.tolist(),
                "stray_share_max": round(float(self.stray_share.max()), 5),
                "iou_per_frame": [round(float(x), 4) for x in self.iou]}
