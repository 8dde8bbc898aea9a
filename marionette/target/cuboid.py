"""A box in a photo rebuilt as a box: six flat faces, each textured from where the photo shows it.

A lift of sheets over the silhouette (:mod:`.shapes`, :mod:`.surfels`) has to
guess the hidden side of every pixel; a box needs no guess. Its outline (a
hexagon seen from above or below, a rectangle seen square on) gives its three
edges (:func:`~.shapes.box_edges`), refined in the photo's perspective camera until the
projected box covers the mask (:func:`fit_cuboid`). Each face is then sampled
on its own grid of flat Gaussians (:func:`cuboid_surfels`), coloured:

- on a face the photo shows, by projecting each sample into the photo and
  reading only that face's pixels: a face seen at a grazing angle is
  unwarped from its sliver, not stretched from the outline;
- on a hidden face whose opposite face shows, by mirror symmetry through the
  box's mid-plane (a box's back from its front, as a car's far side is its
  near side mirrored);
- on a face neither shows (the top and bottom of a box seen level, the sides
  of one seen square on), by texture synthesis (:mod:`.synthesis`): patches
  of the best-seen face's unwarped texture, at its scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..geometry import axis_angle_to_matrix, matrix_to_quaternion
from ._solid import FLATNESS, MIN_VIEW_COSINE, OVERLAP, blur_level, project, sample_spacing
from .shapes import box_outline, box_outline_edges, largest_outline
from .surfels import MaskedTexture
from .synthesis import quilt

__all__ = ["Cuboid", "box_depth", "fit_cuboid", "cuboid_surfels", "MIN_BOX_IOU"]

# The fitted box must cover the mask this well (IoU of its projection) to be taken for a box.
MIN_BOX_IOU = 0.93
# Points along the projected outline and along the mask's outline in the fit's residuals.
_OUTLINE_SAMPLES = 128
# Generic starting views of a box's fit (yaw, pitch degrees), and how much better (IoU) a later start's box
# must cover the mask to replace the outline's own reading.
_GENERIC_VIEWS = ((0.0, 0.0), (0.0, 25.0), (30.0, 0.0), (30.0, 25.0), (60.0, 0.0), (60.0, 25.0))
_BETTER_START = 0.005
# A box covering the mask this well ends the search.
_GOOD_FIT = 0.98
# Pull (pixels per unit of log size) of each half-length towards its start: an edge the outline cannot
# measure (a thin bar's depth seen square on) keeps the start's guess instead of drifting to nothing.
_SIZE_PRIOR = 3.0
# Finite-difference steps of the fit's parameters: turn (rad), log half-lengths, centre (px).
_STEPS = (1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 0.05, 0.05)
# Robust scale of the outline residuals (pixels): what sticks out of the box (a handle) does not pull it.
_ROBUST_PX = 1.5
# A five-corner outline is a box's only when a box explains it this well (a house's gable end is none).
_PENTAGON_FIT = 0.97
# No corner of a box comes nearer the camera than this share of its centre's depth (else the fit explained
# the outline by a box stretched towards the lens, e.g. a house's gable end as a tunnel seen end on).
_NEAREST = 0.25
# Across a face's edge row the Gaussians are narrower (their alpha past the edge would grow the silhouette).
_EDGE_OVERLAP = 0.4


@dataclass(frozen=True)
class Cuboid:
    """A box in the camera frame (world units).

    Attributes
    ----------
    centre : (3,) its centre.
    axes : (3, 3) its edge directions as rows, a right-handed orthonormal frame.
    half : (3,) its half-lengths along them.
    iou : float, the IoU of its projection with the photo's mask.
    """

    centre: np.ndarray
    axes: np.ndarray
    half: np.ndarray
    iou: float = 0.0

    def corners(self) -> np.ndarray:
        """(8, 3) corners."""
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], np.float64)
        return self.centre + (signs * self.half) @ self.axes


def box_depth(cuboid: Cuboid, k: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W) depth of the box's nearest face along the ray of each pixel of ``mask`` (H, W) bool (NaN off it);
    a pixel the box's projection misses (its outline a pixel off the mask's) takes its nearest pixel's."""
    vv, uu = np.nonzero(mask)
    rays = np.linalg.solve(k, np.stack([uu, vv, np.ones_like(uu)]).astype(np.float64)).T  # (N, 3), z = 1
    nearest = np.full(len(vv), np.inf)
    for i in range(3):
        normal = cuboid.axes[i]
        facing = rays @ normal
        for side in (-1.0, 1.0):
            depth = ((cuboid.centre + side * cuboid.half[i] * normal) @ normal) / np.where(facing == 0, np.nan, facing)
            hit = depth[:, None] * rays - cuboid.centre
            on_face = depth > 0
            for j in range(3):
                if j != i:
                    on_face &= np.abs(hit @ cuboid.axes[j]) <= cuboid.half[j] * (1 + 1e-6)
            nearest = np.where(on_face & (depth < nearest), depth, nearest)
    out = np.full(mask.shape, np.nan)
    out[vv, uu] = np.where(np.isfinite(nearest), nearest, np.nan)
    missed = ~np.isfinite(out)
    if missed.all():
        return out
    _, (iy, ix) = ndimage.distance_transform_edt(missed, return_indices=True)
    return np.where(mask, out[iy, ix], np.nan)


def _hull(cuboid: Cuboid, camera: Camera) -> np.ndarray:
    """(K, 2) the projected box's outline, a convex polygon."""
    points = project(cuboid.corners(), camera)
    return points[cv2.convexHull(points.astype(np.float32), returnPoints=False)[:, 0]]


def _along(polygon: np.ndarray, count: int) -> np.ndarray:
    """(count, 2) points evenly spaced along a closed polygon (K, 2)."""
    closed = np.vstack([polygon, polygon[:1]])
    run = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    at = np.linspace(0.0, run[-1], count, endpoint=False)
    return np.stack([np.interp(at, run, closed[:, 0]), np.interp(at, run, closed[:, 1])], axis=1)


def _distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(M,) distance of each point (M, 2) to the closed polygon's (K, 2) boundary."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)


def _fill(polygon: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool pixels whose centres lie in the convex polygon (K, 2)."""
    out = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(out, np.rint(polygon * 16).astype(np.int32), 1, cv2.LINE_8, shift=4)
    return out.astype(bool)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _starts(mask: np.ndarray, corners: np.ndarray | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(axes (3, 3) rows, half-lengths (3,) pixels) to start a box's fit from: the outline's orthographic
    reading when it has one, then boxes turned 0-60° and seen level or from above, as large as the outline
    (a box seen square on, or under strong perspective, is not read right orthographically)."""
    starts = []
    read = None if corners is None else box_outline_edges(mask, corners)
    if read is not None:
        starts.append(read)
    _, _, w, h = cv2.boundingRect(mask.astype(np.uint8))
    for yaw, pitch in _GENERIC_VIEWS:
        turn = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ axis_angle_to_matrix([0.0, np.radians(yaw), 0.0])
        starts.append((turn.T, np.array([0.35 * w, 0.4 * h, 0.3 * w])))
    return starts


def fit_cuboid(mask: np.ndarray, camera: Camera, depth: float, any_outline: bool = False) -> Cuboid | None:
    """The box whose projection covers the (H, W) bool mask, its centre ``depth`` away; None if none is seen.

    From each of a few starts (:func:`_starts`), fits its turn, size and place across the image in the
    perspective camera: the projected outline onto the mask's (robust least squares of the distances both
    ways); the one that covers the mask best is kept (the first that covers ``_GOOD_FIT`` of it ends the
    search). Its ``iou`` says how well; None when the outline is not a box's (4 to 6 corners; five only when a
    box covers ``_PENTAGON_FIT`` of it). ``any_outline``: fit whatever the outline, from generic starts when it
    shows no box's corners (the box round an object).
    """
    mask = np.asarray(mask, dtype=bool)
    corners = box_outline(mask)
    if corners is None and not any_outline:
        return None
    f = 0.5 * (camera.fx + camera.fy)
    v, u = np.nonzero(mask)
    centre_px = np.array([u.mean(), v.mean()])
    outline = largest_outline(mask)[:, 0].astype(np.float64)
    outline = outline[np.linspace(0, len(outline) - 1, min(len(outline), _OUTLINE_SAMPLES)).astype(int)]
    inside = ndimage.distance_transform_edt(mask)
    signed = ndimage.distance_transform_edt(~mask) - np.maximum(inside - 1.0, 0.0)  # 0 on the outline's pixels
    best = None
    for axes0, half_px in _starts(mask, corners):

        def box(x: np.ndarray) -> Cuboid:
            axes = axis_angle_to_matrix(x[:3]) @ axes0.T
            at = centre_px + x[6:8]
            centre = np.array([(at[0] - camera.cx) / camera.fx, (at[1] - camera.cy) / camera.fy, 1.0]) * depth
            return Cuboid(centre, axes.T, half_px * np.exp(x[3:6]) * depth / f)

        def residuals(x: np.ndarray) -> np.ndarray:
            hull = _hull(box(x), camera)
            on_hull = _along(hull, _OUTLINE_SAMPLES)
            from_hull = ndimage.map_coordinates(signed, [on_hull[:, 1], on_hull[:, 0]], order=1, mode="nearest")
            return np.concatenate([from_hull, _distance_to_polygon(outline, hull), _SIZE_PRIOR * x[3:6]])

        def jacobian(x: np.ndarray) -> np.ndarray:  # central differences of fixed size: rel. steps vanish at x = 0
            columns = []
            for k, step in enumerate(_STEPS):
                dx = np.zeros_like(x)
                dx[k] = step
                columns.append((residuals(x + dx) - residuals(x - dx)) / (2 * step))
            return np.stack(columns, axis=1)

        fit = least_squares(residuals, np.zeros(8), jac=jacobian, loss="soft_l1", f_scale=_ROBUST_PX,
                            max_nfev=100)
        found = box(fit.x)
        found = Cuboid(found.centre, found.axes, found.half, _iou(_fill(_hull(found, camera), mask.shape), mask))
        if found.corners()[:, 2].min() < _NEAREST * found.centre[2]:  # a tunnel reaching to the lens, no box
            continue
        if best is None or found.iou > best.iou + _BETTER_START:
            best = found
        if best.iou >= _GOOD_FIT:  # the outline's own reading fits: no need to look further
            break
    if best is not None and corners is not None and len(corners) == 5 and best.iou < _PENTAGON_FIT:
        return None
    return best


def _faces(cuboid: Cuboid) -> list[tuple[int, float, np.ndarray]]:
    """(axis k, side ±1, face centre (3,)) of the six faces."""
    return [(k, s, cuboid.centre + s * cuboid.half[k] * cuboid.axes[k]) for k in range(3) for s in (-1.0, 1.0)]


def _cosine(normal: np.ndarray, point: np.ndarray) -> float:
    """How squarely a face with outward ``normal`` through ``point`` faces a camera at the origin (< 0: away)."""
    return float(-normal @ point / max(np.linalg.norm(point), 1e-12))


def _face_pixels(cuboid: Cuboid, k: int, s: float, camera: Camera, mask: np.ndarray) -> np.ndarray:
    """(H, W) bool object pixels inside the projection of face (k, s)."""
    i, j = [m for m in range(3) if m != k]
    centre = cuboid.centre + s * cuboid.half[k] * cuboid.axes[k]
    quad = [centre + a * cuboid.half[i] * cuboid.axes[i] + b * cuboid.half[j] * cuboid.axes[j]
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    return _fill(project(np.array(quad), camera), mask.shape) & mask


def cuboid_surfels(cuboid: Cuboid, image: np.ndarray, mask: np.ndarray, camera: Camera, stride: int,
                   opacity: float, radius_px: float) -> tuple[Gaussians, np.ndarray]:
    """Flat Gaussians over the box's six faces, coloured as the module says, in the camera's world frame.

    Parameters
    ----------
    cuboid : the box in the camera frame; image : (H, W, 3|4) uint8 photo; mask : (H, W) bool its object.
    camera : the photo's camera. stride : int, sample spacing in pixels at the box's centre (at least; a
        budget of samples per object pixel may widen it). opacity : float, of every Gaussian.
    radius_px : float, the object's RMS radius in pixels (scales the blur of slanted faces).

    Returns
    -------
    (Gaussians, pixel_of): N Gaussians, and the (N, 2) int32 (u, v) photo pixel each took its colour from
    (for a synthesised face, the one it covers in the photo).
    """
    rgb = image[..., :3]
    area = 8.0 * (cuboid.half[0] * cuboid.half[1] + cuboid.half[1] * cuboid.half[2] + cuboid.half[0] * cuboid.half[2])
    spacing = sample_spacing(area, float(cuboid.centre[2]), camera, stride, int(mask.sum()))
    faces = _faces(cuboid)
    cosines = [_cosine(s * cuboid.axes[k], c) for k, s, c in faces]
    grids, seen = [], {}
    for index, (k, s, centre) in enumerate(faces):
        i, j = [m for m in range(3) if m != k]
        n_i, n_j = (max(1, int(np.ceil(2 * cuboid.half[m] / spacing))) for m in (i, j))
        a = (np.arange(n_i) + 0.5) / n_i * 2 - 1
        b = (np.arange(n_j) + 0.5) / n_j * 2 - 1
        points = (centre + a[:, None, None] * cuboid.half[i] * cuboid.axes[i]
                  + b[None, :, None] * cuboid.half[j] * cuboid.axes[j])  # (n_i, n_j, 3)
        grids.append((points, np.array([2 * cuboid.half[i] / n_i, 2 * cuboid.half[j] / n_j])))
        if cosines[index] >= MIN_VIEW_COSINE:
            seen[index] = MaskedTexture(rgb, _face_pixels(cuboid, k, s, camera, mask), radius_px)
    colours: list[np.ndarray | None] = [None] * 6
    sources = [grids[i][0] for i in range(6)]
    for index, (k, s, _) in enumerate(faces):  # a face the photo shows, or its mirror image
        mirror = index ^ 1  # faces come in pairs (k, -1), (k, +1)
        owner = index if index in seen else mirror if mirror in seen else None
        if owner is None:
            continue
        points = grids[index][0] - (0.0 if owner == index else 2 * s * cuboid.half[k] * cuboid.axes[k])
        sources[index] = points
        uv = project(points.reshape(-1, 3), camera)
        level = np.full(len(uv), blur_level(cosines[owner]))
        colours[index] = seen[owner].sample(uv[:, 0], uv[:, 1], level).reshape(
            *points.shape[:2], 3)
    if any(c is None for c in colours):  # faces nobody sees: quilted from the best-seen face
        coloured = [i for i in range(6) if colours[i] is not None]
        if not coloured:
            raise InputError("the box fitted to the target's outline shows none of its faces to the camera")
        best = max(coloured, key=lambda i: cosines[i] * np.prod(grids[i][0].shape[:2]))
        rng = np.random.default_rng(0)
        for index in range(6):
            if colours[index] is None:
                colours[index] = quilt(colours[best], grids[index][0].shape[:2], rng)
    c2w = np.linalg.inv(camera.world_to_camera)
    means, scales, quats, rgbs, pixels = [], [], [], [], []
    for index, (k, s, _) in enumerate(faces):
        i, j = [m for m in range(3) if m != k]
        frame = np.stack([cuboid.axes[i], cuboid.axes[j], s * cuboid.axes[k]], axis=1)  # columns: in-plane, normal
        if np.linalg.det(frame) < 0:
            frame[:, 0] *= -1
        points, step = grids[index]
        count = points.shape[0] * points.shape[1]
        n_i, n_j = points.shape[:2]
        width = np.empty((n_i, n_j, 3))
        width[..., 0] = np.where(np.isin(np.arange(n_i), (0, n_i - 1)), _EDGE_OVERLAP, OVERLAP)[:, None] * step[0]
        width[..., 1] = np.where(np.isin(np.arange(n_j), (0, n_j - 1)), _EDGE_OVERLAP, OVERLAP)[None, :] * step[1]
        width[..., 2] = FLATNESS * OVERLAP * step.min()
        means.append(points.reshape(-1, 3))
        scales.append(width.reshape(-1, 3))
        quats.append(np.tile(matrix_to_quaternion(c2w[:3, :3] @ frame), (count, 1)))
        rgbs.append(colours[index].reshape(-1, 3))
        uv = project(sources[index].reshape(-1, 3), camera)
        pixels.append(np.clip(np.rint(uv), 0, [camera.width - 1, camera.height - 1]))
    means = np.concatenate(means) @ c2w[:3, :3].T + c2w[:3, 3]
    gaussians = Gaussians.from_rgb(means, np.clip(np.concatenate(rgbs), 0.0, 1.0), np.concatenate(scales), opacity,
                                   np.concatenate(quats))
    return gaussians, np.concatenate(pixels).astype(np.int32)
