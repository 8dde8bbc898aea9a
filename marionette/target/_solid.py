"""What the solids (:mod:`.cuboid`, :mod:`.revolution`) share: sampling density, surfel shape, texture blur."""

from __future__ import annotations

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
