"""A mirror-symmetric object rebuilt from one photo, which shows it from two sides.

An object symmetric about a plane (a car about its long mid-plane) looks from the camera's mirror image
across that plane as the photo shows it, mirrored: one photo is two views. The object is carved out of
the box round it (:func:`~.cuboid.fit_cuboid` on the outline's convex hull, seen at an angle so that two
of its upright sides show) as the points whose projections fall inside the mask from both, the plane
running along the box's longer horizontal side. The carved volume's surface (marching cubes) is sampled
into flat Gaussians, each coloured from the photo where it shows there, else from where its mirror image
shows (the far side from the near side), else from its nearest coloured neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..camera import Camera
from ..gaussians import Gaussians
from ..geometry import matrix_to_quaternion
from ._solid import FLATNESS, MIN_VIEW_COSINE, blur_level, project, sample_spacing, surface_zbuffer, surfel_frames
from .cuboid import Cuboid, fit_cuboid
from .shapes import largest_outline
from .surfels import MaskedTexture

__all__ = ["MirrorHull", "fit_mirror_hull", "mirror_surfels", "MIN_HULL_IOU"]

# The carved object's outline must cover the mask this well (IoU) to be taken.
MIN_HULL_IOU = 0.9
# The box round the object must cover the outline's convex hull this well.
_MIN_BOX_IOU = 0.9
# Both upright sides of the box must face the camera at least this much (cosine): seen square on, one
# side's depth is a guess and the mirror carves nothing.
_MIN_SIDE_COSINE = 0.2
# Cells along the box's longest side.
_CELLS = 64
# A sample shows in the photo when it lies within this many spacings of the nearest surface at its pixel.
_DEPTH_SLACK = 3.0
# Gaussian width over sample spacing: samples drawn at random leave gaps a grid's OVERLAP would not cover.
_RANDOM_OVERLAP = 1.0
# Colours of samples no view shows: the mean of this many nearest coloured ones.
_NEIGHBOURS = 6


@dataclass(frozen=True)
class MirrorHull:
    """The carved object in the camera frame.

    box : Cuboid round it; plane : int, the box axis square to the mirror plane (through the box's centre).
    vertices (V, 3), faces (F, 3) int: its surface, outward-facing. iou : float, its outline's IoU with the mask.
    """

    box: Cuboid
    plane: int
    vertices: np.ndarray
    faces: np.ndarray
    iou: float

    def reflect(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points mirrored through the plane."""
        axis = self.box.axes[self.plane]
        return points - 2.0 * ((points - self.box.centre) @ axis)[..., None] * axis

    def reflect_directions(self, directions: np.ndarray) -> np.ndarray:
        """(..., 3) directions (normals) mirrored through the plane."""
        axis = self.box.axes[self.plane]
        return directions - 2.0 * (directions @ axis)[..., None] * axis


def _inside(points: np.ndarray, mask: np.ndarray, camera: Camera) -> np.ndarray:
    """(...) bool: the (..., 3) points project into the (H, W) mask."""
    z = points[..., 2]
    uv = project(points, camera)
    u, v = np.floor(uv[..., 0]).astype(np.int64), np.floor(uv[..., 1]).astype(np.int64)
    on = (z > 0) & (u >= 0) & (u < mask.shape[1]) & (v >= 0) & (v < mask.shape[0])
    return on & mask[np.clip(v, 0, mask.shape[0] - 1), np.clip(u, 0, mask.shape[1] - 1)]


def _outline(vertices: np.ndarray, faces: np.ndarray, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the surface's triangles drawn in the camera."""
    out = np.zeros(shape, np.uint8)
    triangles = np.rint(project(vertices, camera)[faces] * 16).astype(np.int32)
    cv2.fillPoly(out, list(triangles), 1, cv2.LINE_8, shift=4)
    return out.astype(bool)


def fit_mirror_hull(mask: np.ndarray, camera: Camera, depth: float) -> MirrorHull | None:
    """The object in the (H, W) bool ``mask`` carved as the module says, its box's centre ``depth`` away; None
    when no box fits round it seen at an angle, or the carving does not explain the outline."""
    from skimage.measure import marching_cubes

    mask = np.asarray(mask, dtype=bool)
    convex = np.zeros(mask.shape, np.uint8)
    cv2.fillConvexPoly(convex, cv2.convexHull(largest_outline(mask)), 1)
    box = fit_cuboid(convex.astype(bool), camera, depth, any_outline=True)
    if box is None or box.iou < _MIN_BOX_IOU:
        return None
    upright = int(np.argmax(np.abs(box.axes[:, 1])))
    sides = [k for k in range(3) if k != upright]
    view = box.centre / np.linalg.norm(box.centre)
    if min(abs(float(box.axes[k] @ view)) for k in sides) < _MIN_SIDE_COSINE:
        return None
    plane = min(sides, key=lambda k: box.half[k])  # square to the shorter side: a car's long mid-plane
    step = 2.0 * box.half.max() / _CELLS
    counts = np.maximum(2, np.ceil(2.0 * box.half / step).astype(int))
    ticks = [((np.arange(c) + 0.5) / c * 2.0 - 1.0) * h for c, h in zip(counts, box.half)]
    points = box.centre + np.stack(np.meshgrid(*ticks, indexing="ij"), axis=-1) @ box.axes  # (a, b, c, 3)
    axis = box.axes[plane]
    mirrored = points - 2.0 * ((points - box.centre) @ axis)[..., None] * axis
    occupied = _inside(points, mask, camera) & _inside(mirrored, mask, camera)
    if occupied.sum() < 8:
        return None
    field = ndimage.gaussian_filter(np.pad(occupied.astype(np.float32), 1), 0.7)
    verts, faces, _, _ = marching_cubes(field, 0.5)
    faces = faces[:, ::-1]  # wound so that the normals point out of the occupied cells
    cell = 2.0 * box.half / counts
    local = (verts - 1.0 + 0.5) * cell - box.half  # cell centres sit at (index + 0.5) · cell − half
    vertices = box.centre + local @ box.axes
    drawn = _outline(vertices, faces, camera, mask.shape)
    iou = float((drawn & mask).sum() / max((drawn | mask).sum(), 1))
    return MirrorHull(box, plane, vertices, np.ascontiguousarray(faces), iou)


def mirror_surfels(hull: MirrorHull, image: np.ndarray, mask: np.ndarray, camera: Camera, stride: int,
                   opacity: float, radius_px: float) -> tuple[Gaussians, np.ndarray]:
    """Flat Gaussians over the carved surface, coloured as the module says, in the camera's world frame.

    Arguments and result as :func:`~marionette.target.cuboid.cuboid_surfels`.
    """
    import trimesh  # here: only this lift needs it

    mesh = trimesh.Trimesh(hull.vertices, hull.faces, process=False)
    depth = float(hull.box.centre[2])
    spacing = sample_spacing(float(mesh.area), depth, camera, stride, int(mask.sum()))
    count = max(64, int(mesh.area / spacing**2))
    points, face = trimesh.sample.sample_surface(mesh, count, seed=0)
    points = np.asarray(points, np.float64)
    normals = np.asarray(mesh.face_normals, np.float64)[np.asarray(face)]
    zbuffer = surface_zbuffer(points, camera)
    slack = _DEPTH_SLACK * spacing

    def shown(p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        at = project(p, camera)
        c = np.clip(np.rint(at[:, 0]).astype(int), 0, camera.width - 1)
        r = np.clip(np.rint(at[:, 1]).astype(int), 0, camera.height - 1)
        cosine = -np.einsum("ij,ij->i", n, p) / np.linalg.norm(p, axis=1)
        visible = _inside(p, mask, camera) & (p[:, 2] <= zbuffer[r, c] + slack) & (cosine >= MIN_VIEW_COSINE)
        return visible, at, cosine

    own, own_uv, own_cos = shown(points, normals)
    other, other_uv, other_cos = shown(hull.reflect(points), hull.reflect_directions(normals))
    use_uv = np.where(own[:, None], own_uv, other_uv)
    texture = MaskedTexture(image[..., :3], mask, radius_px)
    colour = texture.sample(use_uv[:, 0], use_uv[:, 1], blur_level(np.where(own, own_cos, other_cos)))
    known = own | other
    if known.any() and not known.all():  # what no view shows: its nearest coloured neighbours' mean
        _, nearest = cKDTree(points[known]).query(points[~known], k=min(_NEIGHBOURS, int(known.sum())))
        colour[~known] = colour[known][nearest.reshape(int((~known).sum()), -1)].mean(axis=1)
    elif not known.any():
        colour[:] = texture.fallback
    frames = surfel_frames(normals)
    c2w = np.linalg.inv(camera.world_to_camera)
    width = _RANDOM_OVERLAP * spacing
    scales = np.tile([width, width, FLATNESS * width], (count, 1))
    gaussians = Gaussians.from_rgb(points @ c2w[:3, :3].T + c2w[:3, 3], np.clip(colour, 0.0, 1.0), scales, opacity,
                                   matrix_to_quaternion(c2w[:3, :3] @ frames))
    return gaussians, np.clip(np.rint(use_uv), 0, [camera.width - 1, camera.height - 1]).astype(np.int32)
