"""Gaussians that draw off the object: dropped once the fit is done.

The fit sees each frame cropped to the object's box, and a Gaussian off every
crop is pushed transparent (:func:`.fit._outside`); one inside the crops but
off the mask in many frames survives where a single rigid model cannot explain
them all (a rider who moves on the bike, a pose a little off): rendered in
full, it is a floater. A Gaussian whose centre lands farther than
:data:`STRAY_REACH_PX` from the mask in more than :data:`STRAY_FRAMES` of the
fitted frames it projects into is not on the object.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera
from .posing import per_part

__all__ = ["stray_gaussians", "STRAY_REACH_PX", "STRAY_FRAMES"]

#: A centre farther than this many pixels (at the masks' resolution) from the mask is off the object there ...
STRAY_REACH_PX = 15.0
#: ... and one off it in more than this share of the frames it projects into is a stray.
STRAY_FRAMES = 0.25


def stray_gaussians(means: np.ndarray, parts: np.ndarray, poses: dict, masks, K: np.ndarray) -> np.ndarray:
    """(N,) bool: the Gaussians off the object in more than :data:`STRAY_FRAMES` of the frames.

    means : (N, 3) at frame 0; parts : (N,) int; poses : frame t -> (K, 4, 4) camera-from-part pose of each part
    as filmed; masks : (T, H, W) bool, any per-frame indexable; K : (3, 3) intrinsics at the masks' resolution.
    """
    off, seen = np.zeros(len(means)), np.zeros(len(means))
    for t, pose in poses.items():
        mask = np.asarray(masks[t], bool)
        if not mask.any():
            continue
        h, w = mask.shape
        uv, z = Camera(K, np.eye(4), w, h).project(per_part(means.astype(np.float64), parts, pose[:, :3, :3],
                                                            pose[:, :3, 3]))
        u, v = np.floor(uv).astype(np.int64).T
        inside = (z > 1e-9) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        far = np.zeros(len(means), bool)
        far[inside] = distance[v[inside], u[inside]] > STRAY_REACH_PX
        off += far
        seen += inside
    return off > STRAY_FRAMES * np.maximum(seen, 1)
