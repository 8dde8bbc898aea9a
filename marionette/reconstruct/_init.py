"""Initial Gaussians of a reconstruction: silhouette lifts of a few frames, moved to frame 0 and carved.

Each chosen frame ``t`` is lifted like the frame-0 target of ``eval-self``
(:func:`~marionette.target.lift.lift_image` in the prior's camera, the
mid-surface at the depth of the prior's centroid at ``t``); its Gaussians
are taken back to frame 0 by the inverse pose of their part. The union is
carved against every fitting mask (a visual hull): a Gaussian that falls off
the object in more than ``carve_fraction`` of the frames that see it is
dropped.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..camera import Camera
from ..gaussians import Gaussians
from ..geometry import invert_transform, matrix_to_quaternion, quaternion_multiply
from ..prior import SpatPrior
from ..render.sh import rotate_sh
from ..target.lift import LiftOptions, lift_image
from .posing import per_part

__all__ = ["initial_gaussians", "pose_gaussians", "part_layout"]


def pose_gaussians(gaussians: Gaussians, parts: np.ndarray, poses: np.ndarray) -> Gaussians:
    """Gaussians at frame 0 (N) with part indices (N,) moved by per-part poses (K, 4, 4).

    Means ``R μ + t``; quaternions ``q_R ⊗ q`` (not renormalised: the
    renderer normalises, and the product keeps the norm); SH coefficients
    turned with them.
    """
    means = per_part(gaussians.means, parts, poses[:, :3, :3], poses[:, :3, 3])
    q_r = matrix_to_quaternion(poses[:, :3, :3])[parts]  # (N, 4)
    quats = quaternion_multiply(q_r, gaussians.quats.astype(np.float64))
    return Gaussians(means.astype(np.float32), quats.astype(np.float32), gaussians.log_scales,
                     gaussians.opacity_logits, rotate_sh(gaussians.sh, poses[:, :3, :3], parts))


def part_layout(prior: SpatPrior, shape: tuple[int, int]) -> np.ndarray | None:
    """(H, W) int part of every pixel, the nearest labelled frame-0 pixel's; None without a stored layout."""
    labels = prior.extras.get("labels")
    if prior.num_parts == 1 or labels is None or np.ndim(labels) != 2:
        return None
    labels = np.asarray(labels)
    if labels.shape != shape:
        labels = cv2.resize(labels.astype(np.int16), shape[::-1], interpolation=cv2.INTER_NEAREST)
    known = labels >= 0
    if not known.any():
        return None
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return labels[iy, ix].astype(np.int32)


def _lift_frame(image: np.ndarray, mask: np.ndarray, prior: SpatPrior, t: int,
                cells: int) -> tuple[Gaussians, np.ndarray]:
    """Gaussians lifted from frame ``t`` in the prior's camera (world frame at time t), and their pixels (N, 2)."""
    w, h = (int(v) for v in prior.image_size)
    camera = Camera(prior.intrinsics, np.eye(4), w, h)
    depth = float(np.average(prior.centroids[:, t, 2], weights=prior.radii ** 2))
    inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    mask = inner if inner.any() else mask
    stride = max(1, int(round(np.sqrt(mask.sum() / max(cells, 1)))))
    options = LiftOptions(depth=depth, stride=stride, solids=False)  # sheets on the rays: the fit shapes them
    lifted = lift_image(image, mask=mask, camera=camera, options=options)
    return lifted.gaussians, lifted.pixel_of


def initial_gaussians(frames, masks, prior: SpatPrior, lift_frames: list[int], carve_frames: list[int], *,
                      cells: int = 2500, carve_fraction: float = 0.15,
                      max_gaussians: int = 20000, seed: int = 0) -> tuple[Gaussians, np.ndarray]:
    """Initial Gaussians at frame 0 (N) and their part indices (N,) int32.

    ``frames`` (T, H, W, 3) uint8 and ``masks`` (T, H, W) bool are indexable
    per frame at the prior's resolution; ``lift_frames`` are lifted (about
    ``cells`` cells each), ``carve_frames`` carve.
    """
    h, w = masks[lift_frames[0]].shape
    layout = part_layout(prior, (h, w))
    pieces, parts = [], []
    frame0_parts: list[tuple[np.ndarray, np.ndarray]] = []  # (means, part) of the first lift, for labelling others
    for t in lift_frames:
        g, pix = _lift_frame(np.asarray(frames[t]), np.asarray(masks[t], bool), prior, t, cells)
        if prior.num_parts == 1:
            part = np.zeros(len(g), np.int32)
        elif t == 0 and layout is not None:
            part = layout[pix[:, 1], pix[:, 0]]
        elif frame0_parts:
            # The part whose frame-0 Gaussians lie nearest once this frame's point is taken back by its pose.
            ref_means, ref_part = frame0_parts[0]
            dist = np.full((len(g), prior.num_parts), np.inf)
            for k in range(prior.num_parts):
                if not (ref_part == k).any():
                    continue
                inverse = invert_transform(prior.poses[k, t])
                back = g.means @ inverse[:3, :3].T + inverse[:3, 3]
                dist[:, k] = cKDTree(ref_means[ref_part == k]).query(back)[0]
            part = np.argmin(dist, axis=1).astype(np.int32)
        else:
            part = np.zeros(len(g), np.int32)
        back = pose_gaussians(g, part, invert_transform(prior.poses[:, t]))
        if not frame0_parts:
            frame0_parts.append((back.means, part))
        pieces.append(back)
        parts.append(part)
    gaussians = Gaussians.concatenate(pieces)
    part = np.concatenate(parts).astype(np.int32)
    keep = _carve(gaussians.means, part, masks, prior, carve_frames, carve_fraction)
    if keep.sum() >= 16:  # masks that disagree with the prior carve everything: keep the lift then
        gaussians, part = gaussians.subset(keep), part[keep]
    if len(gaussians) > max_gaussians:
        pick = np.sort(np.random.default_rng(seed).choice(len(gaussians), max_gaussians, replace=False))
        gaussians, part = gaussians.subset(pick), part[pick]
    return gaussians, part


def _carve(means: np.ndarray, part: np.ndarray, masks, prior: SpatPrior, frames: list[int],
           fraction: float) -> np.ndarray:
    """(N,) bool: Gaussians (N, 3) at frame 0 that stay on the (2 px dilated) mask in most frames that see them."""
    k = prior.intrinsics
    seen = np.zeros(len(means), np.int32)
    off = np.zeros(len(means), np.int32)
    for t in frames:
        mask = cv2.dilate(np.asarray(masks[t], np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        h, w = mask.shape
        pose = prior.poses[:, t]  # (K, 4, 4)
        p = per_part(means, part, pose[:, :3, :3], pose[:, :3, 3])
        z = p[:, 2]
        front = z > 1e-6
        u = np.rint(k[0, 0] * p[:, 0] / np.where(front, z, 1) + k[0, 2]).astype(np.int64)
        v = np.rint(k[1, 1] * p[:, 1] / np.where(front, z, 1) + k[1, 2]).astype(np.int64)
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        seen += inside
        hit = np.zeros(len(means), bool)
        hit[inside] = mask[v[inside], u[inside]]
        off += inside & ~hit
    return off <= fraction * np.maximum(seen, 1)
