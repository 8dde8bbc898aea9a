"""What the solids (:mod:`.cuboid`, :mod:`.revolution`, :mod:`.mirror`) share: sampling density, surfel shape,
texture blur, visibility."""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import Camera

# Gaussian standard deviation over sample spacing (neighbours overlap), and thickness over width.
OVERLAP = 0.6
FLATNESS = 0.2
# A surface shows in the photo when it faces the camera at least this much (cosine): a thinner sliver
# holds too few pixels to read its texture from.
MIN_VIEW_COSINE = 0.08
# Surface samples per object pixel of the photo at most (a solid shows about half its surface).
_SAMPLES_PER_PIXEL = 3.0
# Blur level (of :class:`~.surfels.MaskedTexture`) a surface's colours are read at, by its cosine to the camera:
# a slanted surface holds less detail per unit of area, and the photo's pixel grid must not print as stripes.
_BLUR_BY_COSINE = ((0.5, 0), (0.25, 1), (0.0, 2))


def project(points: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 3) camera-frame points → (..., 2) pixels."""
    z = np.maximum(points[..., 2], 1e-9)
    return np.stack([camera.fx * points[..., 0] / z + camera.cx, camera.fy * points[..., 1] / z + camera.cy], -1)


def sample_spacing(area: float, depth: float, camera: Camera, stride: int, object_pixels: int) -> float:
    """World distance between samples of a surface of ``area`` (world units²) ``depth`` away: ``stride`` photo
    pixels, widened to keep within ``_SAMPLES_PER_PIXEL`` samples per object pixel."""
    f = 0.5 * (camera.fx + camera.fy)
    area_px = area * (f / depth) ** 2
    return stride * max(1.0, float(np.sqrt(area_px / (_SAMPLES_PER_PIXEL * max(object_pixels, 1))))) * depth / f


def blur_level(cosine: np.ndarray) -> np.ndarray:
    """(N,) cosines to the camera → (N,) int blur levels."""
    level = np.full(np.shape(cosine), _BLUR_BY_COSINE[-1][1])
    for bound, value in _BLUR_BY_COSINE[::-1]:
        level = np.where(np.asarray(cosine) >= bound, value, level)
    return level


def surface_zbuffer(points: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) nearest depth of a surface's (N, 3) sample points at the photo's pixels (inf where none falls);
    pixels between samples take their neighbours' nearest depth. What lies behind it does not show."""
    uv = project(points, camera)
    col = np.clip(np.rint(uv[:, 0]).astype(int), 0, camera.width - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(int), 0, camera.height - 1)
    zbuffer = np.full((camera.height, camera.width), np.inf)
    np.minimum.at(zbuffer, (row, col), points[:, 2])
    holes = np.isinf(zbuffer)
    return np.where(holes, cv2.erode(np.where(holes, np.float32(3e38), zbuffer.astype(np.float32)),
                                     np.ones((3, 3), np.uint8)), zbuffer)


def surfel_frames(normals: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals → (N, 3, 3) rotations whose columns are two tangents and the normal (a flat
    Gaussian's thin axis last)."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    tangent = np.cross(normals, helper)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    return np.stack([tangent, np.cross(normals, tangent), normals], axis=2)
