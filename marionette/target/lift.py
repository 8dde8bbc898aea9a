"""Single image → pixel-aligned 3D Gaussians (Motion Marionette stage 4).

The paper lifts the target with an image-to-3D model; none can be had offline,
so the default is geometric: a shape prior chosen from the silhouette
(:mod:`.shapes`: inflated, revolved or extruded) gives the object's depth,
and its closed surface is sampled by area into flat Gaussians
(:mod:`.surfels`), one on each visible pixel's ray where the surface faces
the camera, so the reference view reproduces the image. A box or a pot is
rebuilt as a solid instead, and so is a mirror-symmetric object seen at an
angle (a car), each surface textured from where the photo shows it
(:mod:`.cuboid`, :mod:`.revolution`, :mod:`.mirror`) and lit as the photo was lit
(:mod:`.shading`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy import ndimage

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..segment import grabcut_mask, salient_mask
from .cuboid import MIN_BOX_IOU, cuboid_surfels, fit_cuboid
from .mirror import MIN_HULL_IOU, fit_mirror_hull, mirror_surfels
from .polish import polish_reference
from .revolution import MIN_REVOLUTION_IOU, Revolution, fit_revolution, revolution_surfels
from .shading import MIN_ALPHA, Light, deshade, estimate_light, normal_map, shaded_sh
from .shapes import SHAPES, ShapeChoice, choose_shape, inflate_silhouette, revolve_profile, shape_depth
from .surfels import sample_surface

__all__ = ["LiftOptions", "LiftedTarget", "lift_image", "object_mask", "alpha_mask", "inflate_silhouette",
           "depth_for_radius", "SHAPES", "ShapeChoice"]


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
    shape : str
        Shape prior: ``"auto"`` (chosen from the silhouette,
        :func:`~marionette.target.shapes.choose_shape`) or one of
        :data:`~marionette.target.shapes.SHAPES`.
    polish : int
        Adam steps fitting the colours and opacities of the surfels the
        reference view sees to the photo
        (:func:`~marionette.target.polish.polish_reference`); 0 skips it.
    solids : bool
        Rebuild a box as a box and a pot as a solid of revolution, each
        surface textured from where the photo shows it (a target seen from
        every side). False keeps every prior's sheets on the pixels' rays: an
        initial model that other views of the object will correct.
    relight : bool
        Read the photo's light off a solid's surfaces and take it out of the colours; each surfel then shows
        its colour shaded for the way it faces (:mod:`.shading`), so a side turned to the light brightens.
        False keeps the photo's colours on every side.
    """

    stride: int = 1
    thickness: float = 1.0
    fov_deg: float = 60.0
    radius: float = 1.0
    opacity: float = 0.98
    relative_depth: float | None = None
    depth: float | None = None
    shape: str = "auto"
    polish: int = 0
    solids: bool = True
    relight: bool = True


@dataclass(frozen=True)
class LiftedTarget:
    """A lifted target: Gaussians, the reference camera and the object mask.

    Attributes
    ----------
    gaussians : Gaussians, N of them, in the reference camera's frame.
    camera : Camera, the reference view (world_to_camera identity).
    mask : (H, W) bool, object pixels of the input image.
    pixel_of : (N, 2) int32, the (u, v) pixel each Gaussian was made from.
    shape : ShapeChoice or None, the shape prior used and why (None for Gaussians taken as given).
    image : (H, W, 3|4) uint8 or None, the photo lifted (None for Gaussians taken as given).
    """

    gaussians: Gaussians
    camera: Camera
    mask: np.ndarray
    pixel_of: np.ndarray
    shape: ShapeChoice | None = None
    image: np.ndarray | None = None


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


def _focal_for_relative_depth(mask: np.ndarray, relief: np.ndarray, ratio: float) -> float:
    """Focal length (pixels) at which the lifted object's distance is ``ratio`` times its RMS radius.

    In pixel units at the outline's depth the object's RMS radius is its lateral spread plus its relief,
    the lateral spread shrunk by perspective where the front lies ``relief`` nearer (``1 - relief / f``):
    a fixed point in ``f``, reached in a few steps.
    """
    v, u = np.nonzero(mask)
    lateral2 = (u - u.mean()) ** 2 + (v - v.mean()) ** 2
    depth = relief[v, u].astype(np.float64)
    focal = ratio * np.sqrt(lateral2.mean() + (depth**2).mean())
    for _ in range(8):
        focal = ratio * np.sqrt((lateral2 * (1.0 - depth / focal) ** 2).mean() + (depth**2).mean())
    return max(float(focal), 1.0)


def _lit(surfels: Callable[[np.ndarray], tuple[Gaussians, np.ndarray]], image: np.ndarray, pixels: np.ndarray,
         camera: Camera, options: LiftOptions) -> tuple[Gaussians, np.ndarray, Light | None]:
    """A solid's surfels coloured from ``image`` (``surfels(photo)``), relit as :mod:`.shading` says.

    ``pixels`` (H, W) bool: the photo's pixels that show the solid. Returns the Gaussians, their pixels
    (N, 2) and the light read (None when not relit: switched off, or the photo shows one face only).
    """
    gaussians, pixel_of = surfels(image)
    if not options.relight:
        return gaussians, pixel_of, None
    normals, alpha = normal_map(gaussians, camera)
    light = estimate_light(image, normals, pixels & (alpha >= MIN_ALPHA))
    if light is None:
        return gaussians, pixel_of, None
    albedo, scale = deshade(image, normals, alpha, light)
    gaussians, pixel_of = surfels(albedo)
    return gaussians.with_sh(shaded_sh(gaussians, gaussians.rgb / scale, light)), pixel_of, light


def _attached_depth(body: Revolution, pieces: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) camera z of each appendage's pixels (``pieces`` >= 2): the body's axis on the median row where the
    appendage meets the body (``pieces`` == 1); the body's pixels get the depth of its middle."""
    middle = float((body.base + 0.5 * body.heights[-1] * body.axis)[2])
    out = np.full(pieces.shape, middle)
    near_body = ndimage.binary_dilation(pieces == 1, iterations=2)
    for label in np.unique(pieces[pieces >= 2]):
        piece = pieces == label
        rows = np.nonzero(piece & near_body)[0]
        out[piece] = body.axis_depth(camera, float(np.median(rows))) if len(rows) else middle
    return out


def _solid(choice: ShapeChoice, image: np.ndarray, mask: np.ndarray, camera: Camera, depth: float,
           options: LiftOptions) -> tuple[ShapeChoice, tuple | None]:
    """The object rebuilt as a box, a solid of revolution or a mirror-symmetric solid.

    Returns the choice with the fit's measurements (a ``cuboid`` no box covers well enough becomes its
    fallback, which may be a solid of revolution; a round outline no solid of revolution explains may be a
    mirror-symmetric object seen at an angle, ``mirror``), and the solid, or None for sheets: (Gaussians,
    their pixels (N, 2), (H, W) bool pixels left to sheets: a handle, a spout, and the depth (H, W or scalar)
    those sheets move by to meet the solid).
    """
    radius_px = pixel_radius(mask)
    if choice.name == "cuboid":
        box = fit_cuboid(mask, camera, depth)
        if box is not None and (box.iou >= MIN_BOX_IOU or choice.forced):
            depthwise = np.argmax(np.abs(box.axes[:, 2])) == np.arange(3)
            box = replace(box, half=box.half * np.where(depthwise, options.thickness, 1.0))
            gaussians, pixel_of, light = _lit(lambda photo: cuboid_surfels(
                box, photo, mask, camera, options.stride, options.opacity, radius_px), image, mask, camera, options)
            return (replace(choice, solid_iou=box.iou, light=light),
                    (gaussians, pixel_of, np.zeros(mask.shape, bool), 0.0))
        if choice.forced:
            raise InputError("--shape cuboid: the target's outline shows no box (neither a box's hexagon nor a "
                             "rectangle)")
        choice = replace(choice, name=choice.fallback, solid_iou=None if box is None else box.iou)
    if choice.name == "revolve" and options.thickness == 1.0:
        radius, _, pieces = revolve_profile(mask, *choice.axis)
        body = fit_revolution(pieces == 1, radius, *choice.axis, camera, depth, image)
        if body is not None and body.iou >= MIN_REVOLUTION_IOU:
            gaussians, pixel_of, light = _lit(lambda photo: revolution_surfels(
                body, photo, pieces == 1, camera, options.stride, options.opacity, radius_px), image, pieces == 1,
                camera, options)
            return (replace(choice, solid_iou=body.iou, pitch=body.pitch, light=light),
                    (gaussians, pixel_of, pieces >= 2, _attached_depth(body, pieces, camera) - depth))
    wanted = choice.name == "mirror" or (not choice.forced and choice.name in ("revolve", "inflate"))
    if wanted and options.thickness == 1.0:
        hull = fit_mirror_hull(mask, camera, depth)
        if hull is not None and (hull.iou >= MIN_HULL_IOU or choice.forced):
            gaussians, pixel_of, light = _lit(lambda photo: mirror_surfels(
                hull, photo, mask, camera, options.stride, options.opacity, radius_px), image, mask, camera, options)
            return (replace(choice, name="mirror", solid_iou=hull.iou, light=light),
                    (gaussians, pixel_of, np.zeros(mask.shape, bool), 0.0))
        if choice.forced and choice.name == "mirror":
            raise InputError("--shape mirror: no box round the target's outline shows two upright sides to carve "
                             "it from")
    if choice.name == "mirror":
        choice = replace(choice, name=choice.fallback)
    return choice, None


def lift_image(image: np.ndarray, *, mask: np.ndarray | None = None, camera: Camera | None = None,
               depth_map: np.ndarray | None = None, options: LiftOptions = LiftOptions()) -> LiftedTarget:
    """Lift an (H, W, 3|4) uint8 image into Gaussians seen by ``camera`` as the image.

    The object sits at ``options.depth``, or else at the depth
    :func:`depth_for_radius` gives. The shape prior's half-thickness ``h``
    (scaled by ``thickness``) puts the front surface at ``m - h`` and the
    back at ``m + h`` about the mid-surface ``m``, the plane ``z0`` (offset
    where the prior says so: a box seen at an angle); with a
    ``depth_map`` (H, W) (camera z, any unit, NaN or <= 0 unknown) the front
    surface follows the map instead, scaled so that its median over the
    object is ``z0 - median(h)``, and ``m`` lies ``h`` behind it. The closed
    surface is sampled by area, one cell per ``stride`` x ``stride`` pixels
    (:func:`~marionette.target.surfels.sample_surface`).
    """
    h_img, w_img = image.shape[:2]
    if options.stride < 1:
        raise InputError(f"stride must be >= 1, got {options.stride}")
    if not 0 <= options.polish <= 10_000:
        raise InputError(f"polish must be a number of steps within 0..10000, got {options.polish}")
    if mask is None:
        mask = object_mask(image)
    if mask.shape != (h_img, w_img):
        raise InputError(f"target mask is {mask.shape[1]}x{mask.shape[0]}, image is {w_img}x{h_img}")
    if not mask.any():
        raise InputError("target mask is empty")
    choice = choose_shape(mask, options.shape)
    if choice.name in ("cuboid", "mirror") and (not options.solids or depth_map is not None):
        choice = replace(choice, name=choice.fallback)
    sheets = replace(choice, name=choice.fallback) if choice.name in ("cuboid", "mirror") else choice
    offset, relief, pieces = shape_depth(mask, sheets)  # (H, W) mid-surface offset, half-thickness (px), pieces
    offset, relief = offset * options.thickness, relief * options.thickness
    if camera is None and options.relative_depth is not None:
        if not (np.isfinite(options.relative_depth) and options.relative_depth > 0):
            raise InputError(f"relative depth must be positive, got {options.relative_depth}")
        camera = Camera.from_focal(w_img, h_img, _focal_for_relative_depth(mask, relief, options.relative_depth))
    camera = camera or Camera.from_fov(w_img, h_img, options.fov_deg)
    if (camera.width, camera.height) != (w_img, h_img):
        raise InputError("reference camera size differs from the target image size")
    f = 0.5 * (camera.fx + camera.fy)
    if options.depth is not None and not (np.isfinite(options.depth) and options.depth > 0):
        raise InputError(f"target depth must be positive, got {options.depth}")
    z0 = depth_for_radius(mask, f, options.radius) if options.depth is None else float(options.depth)
    # Half-thickness in world units: pixels at z0 are z0 / f world units wide.
    half = relief * (z0 / f)
    mid = z0 + offset * (z0 / f) if depth_map is None else _front_from_depth(depth_map, mask, z0, half) + half

    s = options.stride
    centre_v, centre_u = np.arange(s // 2, h_img, s), np.arange(s // 2, w_img, s)
    if options.solids and depth_map is None:
        choice, solid = _solid(choice, image, mask, camera, z0, options)
        if solid is not None:
            gaussians, pixel_of, appendages, shift = solid
            if appendages.any():  # a handle or a spout: sheets of its own, at the depth where they meet the body
                cells = np.where(appendages, pieces, 0)[np.ix_(centre_v, centre_u)]
                more, more_pixels = sample_surface(image, mask, cells, (mid + shift)[np.ix_(centre_v, centre_u)],
                                                   half[np.ix_(centre_v, centre_u)], camera, s, options.opacity,
                                                   pixel_radius(mask))
                gaussians = Gaussians.concatenate([gaussians, more])
                pixel_of = np.concatenate([pixel_of, more_pixels])
            gaussians, _ = polish_reference(gaussians, camera, image, mask, options.polish)
            return LiftedTarget(gaussians, camera, mask, pixel_of, choice, image)
    cells = pieces[np.ix_(centre_v, centre_u)]
    gaussians, pixel_of = sample_surface(image, mask, cells, mid[np.ix_(centre_v, centre_u)],
                                         half[np.ix_(centre_v, centre_u)], camera, s, options.opacity,
                                         pixel_radius(mask))
    gaussians, _ = polish_reference(gaussians, camera, image, mask, options.polish)
    return LiftedTarget(gaussians, camera, mask, pixel_of, choice, image)
