"""Single image → pixel-aligned 3D Gaussians (Motion Marionette stage 4).

The paper lifts the target with an image-to-3D model; none can be had offline,
so the default is geometric: the object's silhouette is inflated into a
rounded closed volume (front and back surfaces meeting at the outline), and
one Gaussian sits on each visible pixel so the reference view reproduces the
image. The back surface takes the colour of the front pixel it lies behind.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.linalg import spsolve

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..segment import grabcut_mask, salient_mask

__all__ = ["LiftOptions", "LiftedTarget", "lift_image", "object_mask", "alpha_mask", "inflate_silhouette",
           "depth_for_radius"]


@dataclass(frozen=True)
class LiftOptions:
    """Settings of the silhouette lift.

    Attributes
    ----------
    stride : int
        One Gaussian per ``stride`` x ``stride`` pixels (1 = every pixel).
    thickness : float
        Depth of the inflated volume relative to a sphere-like profile
        (1.0: a disc silhouette becomes a ball).
    fov_deg : float
        Horizontal field of view of the reference camera when none is given.
    radius : float
        Object size in world units (RMS distance of the front surface to its
        centroid, roughly); fixes the otherwise unknowable monocular scale.
    opacity : float
        Opacity of each Gaussian.
    relative_depth : float or None
        Camera distance over object radius. When set (and no camera is
        given), the focal length is chosen so the object keeps its size in
        the image at that distance: a source filmed from afar then drives a
        target seen with the same perspective, so translations scaled by
        object size move both alike on screen. None: ``fov_deg`` decides.
    depth : float or None
        Depth of the object's mid-surface along the camera's optical axis, in
        world units. When set, it places the object (e.g. where a source
        prior put it) and its size follows from the camera; ``radius`` is
        then unused. None: the depth follows from ``radius``.
    """

    stride: int = 1
    thickness: float = 1.0
    fov_deg: float = 60.0
    radius: float = 1.0
    opacity: float = 0.98
    relative_depth: float | None = None
    depth: float | None = None


@dataclass(frozen=True)
class LiftedTarget:
    """A lifted target: Gaussians, the reference camera and the object mask.

    Attributes
    ----------
    gaussians : Gaussians, N of them, in the reference camera's frame.
    camera : Camera, the reference view (world_to_camera identity).
    mask : (H, W) bool, object pixels of the input image.
    pixel_of : (N, 2) int32, the (u, v) pixel each Gaussian was made from.
    """

    gaussians: Gaussians
    camera: Camera
    mask: np.ndarray
    pixel_of: np.ndarray


def alpha_mask(image: np.ndarray) -> np.ndarray | None:
    """(H, W) bool mask from an RGBA image's alpha channel; None when it has none or it is fully opaque.

    Raises :class:`InputError` for a fully transparent image (nothing to lift).
    """
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise InputError(f"target image must be RGB or RGBA, got shape {image.shape}")
    if image.shape[2] == 3:
        return None
    mask = image[..., 3] >= 128
    if not mask.any():
        raise InputError("target image is fully transparent: its alpha channel holds no object")
    return None if mask.all() else mask


def _front_from_depth(depth_map: np.ndarray, mask: np.ndarray, z0: float, half: np.ndarray) -> np.ndarray:
    """(H, W) front-surface depth in world units from a depth map in any unit (see :func:`lift_image`)."""
    depth = np.asarray(depth_map, dtype=np.float64)
    if depth.shape != mask.shape:
        raise InputError(f"target depth map is {depth.shape[1]}x{depth.shape[0]}, image is "
                         f"{mask.shape[1]}x{mask.shape[0]}")
    if np.isinf(depth).any():
        raise InputError("target depth map contains infinite values")
    with np.errstate(invalid="ignore"):
        known = mask & (depth > 0)
    if known.sum() < 0.5 * mask.sum():
        raise InputError("target depth map has valid (positive) depth on less than half of the object")
    front = depth * ((z0 - np.median(half[mask])) / np.median(depth[known]))
    # Unknown depth inside the object takes its nearest known value.
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    return front[iy, ix]


def object_mask(image: np.ndarray) -> np.ndarray:
    """(H, W, 3 or 4) uint8 image → (H, W) bool object mask.

    In order: the alpha channel when it holds a mask; the object keyed from a
    plain background (what differs from the colour along the image border,
    exact for product shots and renders); the bundled salient-object model
    (U²-Netp); GrabCut from a centred box when the model finds nothing.
    """
    mask = alpha_mask(image)
    if mask is not None:
        return mask
    image = image[..., :3]  # an opaque alpha channel carries no mask
    keyed = _key_plain_background(image)
    if keyed is not None:
        return keyed
    try:
        return salient_mask(image)
    except InputError:
        mask = grabcut_mask(image)
        if not mask.any():
            raise InputError("no object found in the target image; give an RGBA image (alpha = object) or "
                             "--target-mask FILE") from None
        return mask


def _key_plain_background(rgb: np.ndarray) -> np.ndarray | None:
    """The object on a plain background (largest component, holes filled), or None if the border is busy."""
    rgb = rgb.astype(np.float32)
    border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
    bg = np.median(border, axis=0)
    spread = np.median(np.abs(border - bg).sum(axis=1))
    if spread > 30:
        return None
    diff = np.abs(rgb - bg).sum(axis=2)
    mask = (diff > max(40.0, 4 * spread)).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    keep = (lab == 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])).astype(np.uint8)
    filled = keep.copy()
    flood = np.zeros((keep.shape[0] + 2, keep.shape[1] + 2), np.uint8)
    cv2.floodFill(filled, flood, (0, 0), 1)
    return (keep | (1 - filled)).astype(bool) if not keep[0, 0] else keep.astype(bool)


def inflate_silhouette(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool mask → (H, W) float32 half-thickness in pixels, 0 outside.

    Solves the Poisson problem ``∇²u = −4`` inside the mask with ``u = 0``
    outside (5-point Laplacian, scipy.sparse), and takes ``h = sqrt(u)``: for
    a disc of radius ``R`` the solution is ``u = R² − r²``, so ``h`` is a
    ball's profile; any other silhouette gets a smooth, rounded volume that
    meets itself at the outline and is thicker where the shape is wide.
    """
    mask = np.asarray(mask, dtype=bool).copy()
    mask[[0, -1], :] = False  # the image border counts as outside
    mask[:, [0, -1]] = False
    out = np.zeros(mask.shape, np.float32)
    count = int(mask.sum())
    if count == 0:
        return out
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(count)
    rows, cols = np.nonzero(mask)
    centre = index[rows, cols]
    i, j = [centre], [centre]
    values = [np.full(count, 4.0)]
    for dv, du in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        nb = index[rows + dv, cols + du]
        inside = nb >= 0
        i.append(centre[inside])
        j.append(nb[inside])
        values.append(np.full(int(inside.sum()), -1.0))
    lap = sparse.csr_matrix((np.concatenate(values), (np.concatenate(i), np.concatenate(j))), shape=(count, count))
    u = spsolve(lap, np.full(count, 4.0))
    out[mask] = np.sqrt(np.clip(u, 0.0, None))
    return out


def pixel_radius(mask: np.ndarray) -> float:
    """RMS distance in pixels of the (H, W) mask's pixels to their centroid (at least 1)."""
    v, u = np.nonzero(mask)
    return max(float(np.sqrt(((u - u.mean()) ** 2 + (v - v.mean()) ** 2).mean())), 1.0)


def depth_for_radius(mask: np.ndarray, focal: float, radius: float = 1.0) -> float:
    """Camera distance at which the masked object has RMS radius ``radius``.

    The RMS pixel distance of mask pixels to their centroid, times depth over
    focal, equals the object's RMS radius in the image plane.
    """
    return focal * radius / pixel_radius(mask)


def lift_image(image: np.ndarray, *, mask: np.ndarray | None = None, camera: Camera | None = None,
               depth_map: np.ndarray | None = None, options: LiftOptions = LiftOptions()) -> LiftedTarget:
    """Lift an (H, W, 3|4) uint8 image into Gaussians seen by ``camera`` as the image.

    The object sits at ``options.depth``, or else at the depth
    :func:`depth_for_radius` gives; each
    ``stride``-pixel cell inside the mask gets a front Gaussian at
    ``m - h`` and a back one at ``m + h`` (``h`` from
    :func:`inflate_silhouette`, scaled by ``thickness``), plus fill-in
    Gaussians along steep walls so the volume stays closed when it turns.
    The mid-surface ``m`` is the plane ``z0``; with a ``depth_map``
    (H, W) (camera z, any unit, NaN or <= 0 unknown) the front surface
    follows the map instead, scaled so that its median over the object is
    ``z0 - median(h)``, and ``m`` lies ``h`` behind it.
    """
    h_img, w_img = image.shape[:2]
    if options.stride < 1:
        raise InputError(f"stride must be >= 1, got {options.stride}")
    if mask is None:
        mask = object_mask(image)
    if mask.shape != (h_img, w_img):
        raise InputError(f"target mask is {mask.shape[1]}x{mask.shape[0]}, image is {w_img}x{h_img}")
    if not mask.any():
        raise InputError("target mask is empty")
    relief = inflate_silhouette(mask) * options.thickness  # (H, W) half-thickness in pixels
    if camera is None and options.relative_depth is not None:
        if not (np.isfinite(options.relative_depth) and options.relative_depth > 0):
            raise InputError(f"relative depth must be positive, got {options.relative_depth}")
        # RMS radius of the inflated volume in pixel units: lateral spread plus relief.
        r3 = np.sqrt(pixel_radius(mask) ** 2 + float((relief[mask] ** 2).mean()))
        camera = Camera.from_focal(w_img, h_img, options.relative_depth * r3)
    camera = camera or Camera.from_fov(w_img, h_img, options.fov_deg)
    if (camera.width, camera.height) != (w_img, h_img):
        raise InputError("reference camera size differs from the target image size")
    f = 0.5 * (camera.fx + camera.fy)
    if options.depth is not None and not (np.isfinite(options.depth) and options.depth > 0):
        raise InputError(f"target depth must be positive, got {options.depth}")
    z0 = depth_for_radius(mask, f, options.radius) if options.depth is None else float(options.depth)
    # Half-thickness in world units: pixels at z0 are z0 / f world units wide.
    half = relief * (z0 / f)
    mid = np.full((h_img, w_img), z0) if depth_map is None else _front_from_depth(depth_map, mask, z0, half) + half

    s = options.stride
    vs, us = np.mgrid[s // 2:h_img:s, s // 2:w_img:s]
    keep = mask[vs, us]
    us, vs = us[keep], vs[keep]
    rgb = image[vs, us, :3].astype(np.float32) / 255.0
    hz, mz = half[vs, us], mid[vs, us]
    spacing = s * z0 / f  # lateral spacing of cells, world units

    border = np.pad(np.zeros(mask.shape, bool), s, constant_values=True)
    zs, idx = [], []
    for sign in (-1.0, 1.0):
        surface = mid + sign * half
        zs.append(mz + sign * hz)
        idx.append(np.arange(len(us)))
        # Depth step to the steepest 4-neighbour cell outside the surface: a wall that needs filling,
        # one fill-in layer per spacing from the surface toward the mid-surface.
        sp = np.pad(np.where(mask, surface, mid), s, mode="edge")
        sp[border] = np.pad(mid, s, mode="edge")[border]  # beyond the image: outside the object
        steep = np.zeros_like(hz)
        for dv, du in ((s, 0), (-s, 0), (0, s), (0, -s)):
            steep = np.maximum(steep, sign * (surface[vs, us] - sp[vs + s + dv, us + s + du]))
        layers = np.floor(np.minimum(steep, 2 * hz) / spacing).astype(int)
        for k in range(1, int(layers.max(initial=0)) + 1):
            sel = np.nonzero(layers >= k)[0]
            zs.append(mz[sel] + sign * (hz[sel] - k * spacing))
            idx.append(sel)
    z = np.concatenate(zs)
    idx = np.concatenate(idx)
    u, v = us[idx].astype(np.float64), vs[idx].astype(np.float64)
    x = (u - camera.cx) / camera.fx * z
    y = (v - camera.cy) / camera.fy * z
    means_cam = np.stack([x, y, z], axis=1)
    c2w = np.linalg.inv(camera.world_to_camera)
    means = means_cam @ c2w[:3, :3].T + c2w[:3, 3]
    # Gaussians a little wider than the cell so neighbours overlap without gaps.
    sigma = 0.6 * s * z / f
    g = Gaussians.from_rgb(means, rgb[idx], sigma, options.opacity)
    return LiftedTarget(g, camera, mask, np.stack([u, v], axis=1).astype(np.int32))
