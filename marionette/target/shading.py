"""The photo's light on a solid target: read, taken out of the colours, and put back as the solid turns.

A photo bakes its light into the colours: a box's side seen in shadow would stay dark when a turn brings it
round to the light. Where the lift rebuilt a solid (a box, a solid of revolution) every surfel knows its
outward normal (its local ``z`` axis), so the shading can be modelled as one distant light and an ambient
term,

    colour = albedo · (ambient + (1 − ambient) · max(n · l, 0)),

``l`` the unit direction towards the light. Light and ambient are fitted to the median brightness of the
photo's pixels grouped by the way the surface faces there (the albedo is taken not to depend on it). Priors
settle what one photo cannot tell (a box seen level shows two ways of facing): weak ones of light from above
and in front, and of half the brightness ambient. A light found below is taken for faces painted apart, not
lit apart, and the photo's colours are kept. Else the photo divided by the shading gives the albedo the
surfaces are coloured from; each surfel then shows its albedo shaded for the direction it is seen from
(degree-2 spherical harmonics), the light keeping its place relative to the view as a lamp beside a still
camera would: the reference view shows the photo again, a face turned towards the light brightens.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from ..camera import Camera
from ..gaussians import SH_C0, Gaussians, rgb_to_sh
from ..geometry import quaternion_to_matrix
from ..render import render
from ..render.sh import _basis

__all__ = ["MIN_ALPHA", "Light", "estimate_light", "outward_normals", "normal_map", "deshade", "shaded_sh"]

# Prior: light from above and in front of the camera (camera y points down, z away), a moderate ambient.
_PRIOR_DIRECTION = np.array([0.0, -1.0, -1.0]) / np.sqrt(2.0)
_PRIOR_AMBIENT = 0.5
_PRIOR_WEIGHT_DIRECTION, _PRIOR_WEIGHT_AMBIENT = 0.05, 0.2
# A light found further below the camera's horizontal than this (the y of its direction, y down) is taken
# for faces painted apart, not lit apart: the photo's colours are kept.
_MAX_LIGHT_BELOW = 0.1
# The ambient share is kept within these bounds: at the lower one a face in shadow is brightened 4x.
_MIN_AMBIENT, _MAX_AMBIENT = 0.25, 1.0
# Normals are grouped on a grid of this step; a group counts with at least this share of the pixels.
_NORMAL_STEP, _MIN_GROUP_SHARE, _MIN_GROUP_PIXELS = 0.25, 0.01, 20
# Pixels whose rendered normal is this opaque or more are read (the outline's mixed normals are not).
MIN_ALPHA = 0.99
_SH_COEFFICIENTS = 9  # degree 2: a clamped cosine has nothing in band 3
_DIRECTIONS = 512
_NORMAL_CELL = 0.02
_LUMA = np.array([0.299, 0.587, 0.114])


class Light(NamedTuple):
    """One distant light and an ambient term, as the reference view saw them.

    direction : (3,) unit vector towards the light, in the reference camera's frame (x right, y down, z away).
    ambient : float in [0.25, 1], the share of the brightness that does not depend on the normal.
    """

    direction: tuple[float, float, float]
    ambient: float

    def as_dict(self) -> dict:
        """JSON-ready fields."""
        return {"direction": [round(float(v), 4) for v in self.direction], "ambient": round(float(self.ambient), 4)}


def outward_normals(gaussians: Gaussians) -> np.ndarray:
    """(N, 3) unit outward normals of a solid's surfels: the local ``z`` axis of each orientation."""
    q = gaussians.quats / np.linalg.norm(gaussians.quats, axis=1, keepdims=True)
    return quaternion_to_matrix(q.astype(np.float64))[:, :, 2]


def _view_frames(dirs: np.ndarray) -> np.ndarray:
    """(..., 3) view directions → (..., 3, 3) rows: right, up-negated (image down), forward.

    At the optical axis this is the camera's own frame, so a light given in camera coordinates is the same
    light for every direction relative to its view: ``l(d) = frame(d)ᵀ · light``.
    """
    forward = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    camera_up = np.array([0.0, -1.0, 0.0])
    up = camera_up - (forward @ camera_up)[..., None] * forward  # square to the view
    up = up / np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-12)
    right = np.cross(forward, up)
    return np.stack([right, -up, forward], axis=-2)


def _shading(cosine: np.ndarray, ambient: float) -> np.ndarray:
    return ambient + (1.0 - ambient) * np.maximum(cosine, 0.0)


def _pixel_rays(camera: Camera) -> np.ndarray:
    """(H, W, 3) unnormalised rays through the pixel centres, in the camera frame."""
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], axis=-1)


def normal_map(gaussians: Gaussians, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """A solid's normals as the reference camera sees them, in each pixel's view frame.

    Returns ``(normals (H, W, 3), alpha (H, W))``: unit normals expressed in :func:`_view_frames` of the
    pixel's ray (their dot product with a light's camera-frame direction is the cosine of its shading).
    """
    normals = outward_normals(gaussians)
    out = render(gaussians.with_sh(rgb_to_sh(0.5 + 0.5 * normals)[:, None, :]), camera, (0.0, 0.0, 0.0))
    drawn = 2.0 * out.image.astype(np.float64) - out.alpha[..., None]
    drawn /= np.maximum(np.linalg.norm(drawn, axis=-1, keepdims=True), 1e-9)
    return np.einsum("hwij,hwj->hwi", _view_frames(_pixel_rays(camera)), drawn), out.alpha


def estimate_light(image: np.ndarray, normals: np.ndarray, pixels: np.ndarray) -> Light | None:
    """The light that best explains the brightness of ``pixels`` by the way the surface faces there.

    image : (H, W, 3|4) uint8; normals : (H, W, 3) from :func:`normal_map`; pixels : (H, W) bool, those to
    read. None when fewer than two directions of the surface are seen (nothing to compare), or when the light
    would come from below (the brightness is more likely paint than light).
    """
    seen = normals[pixels]
    brightness = np.log(np.maximum(image[..., :3][pixels].astype(np.float64) @ _LUMA, 1.0))
    if len(seen) < _MIN_GROUP_PIXELS:
        return None
    _, group, counts = np.unique(np.rint(seen / _NORMAL_STEP).astype(np.int64), axis=0, return_inverse=True,
                                 return_counts=True)
    group = group.ravel()
    kept = np.flatnonzero(counts >= max(_MIN_GROUP_PIXELS, _MIN_GROUP_SHARE * len(seen)))
    if len(kept) < 2:
        return None
    members = [group == k for k in kept]
    level = np.array([np.median(brightness[m]) for m in members])
    weight = np.sqrt(counts[kept] / len(seen))
    facing = np.stack([seen[m].mean(axis=0) for m in members])
    facing /= np.linalg.norm(facing, axis=1, keepdims=True)

    def direction(polar: float, azimuth: float) -> np.ndarray:
        return np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])

    def residuals(x: np.ndarray) -> np.ndarray:
        light = direction(x[2], x[3])
        fit = weight * (level - x[0] - np.log(_shading(facing @ light, x[1])))
        return np.concatenate([fit, _PRIOR_WEIGHT_DIRECTION * (light - _PRIOR_DIRECTION),
                               [_PRIOR_WEIGHT_AMBIENT * (x[1] - _PRIOR_AMBIENT)]])

    start = [float(np.median(level)), _PRIOR_AMBIENT, float(np.arccos(_PRIOR_DIRECTION[2])),
             float(np.arctan2(_PRIOR_DIRECTION[1], _PRIOR_DIRECTION[0]))]
    x = least_squares(residuals, start, bounds=([-np.inf, _MIN_AMBIENT, 0.0, -4 * np.pi],
                                                [np.inf, _MAX_AMBIENT, np.pi, 4 * np.pi])).x
    light = direction(x[2], x[3])
    if light[1] > _MAX_LIGHT_BELOW:  # lit from below: more likely faces painted apart than a lamp on the floor
        return None
    return Light(tuple(float(v) for v in light), float(x[1]))


def deshade(image: np.ndarray, normals: np.ndarray, alpha: np.ndarray, light: Light) -> tuple[np.ndarray, float]:
    """The photo with the light taken out where the solid covers it: ``(albedo image, scale)``.

    image : (H, W, 3|4) uint8; normals, alpha : from :func:`normal_map`. The albedo, scaled by ``scale``
    (<= 1) so that it fits in uint8, replaces the colours where ``alpha`` is opaque (blended in along the
    outline); other pixels are kept.
    """
    shade = _shading(normals @ np.asarray(light.direction), light.ambient)
    weight = np.clip(alpha, 0.0, 1.0)[..., None]
    rgb = image[..., :3].astype(np.float64)
    albedo = rgb / (1.0 - weight + weight * shade[..., None])
    scale = min(1.0, 255.0 / max(float(albedo.max()), 1e-9))
    out = image.copy()
    out[..., :3] = np.clip(np.rint(albedo * scale), 0, 255).astype(np.uint8)
    return out, scale


def shaded_sh(gaussians: Gaussians, albedo: np.ndarray, light: Light) -> np.ndarray:
    """Degree-2 SH (N, 9, 3) showing each solid surfel's ``albedo`` (N, 3) shaded for the direction seen from.

    The view direction from the reference camera's centre (the origin) is where the surfel shows exactly
    its albedo shaded by ``light``; other directions see the light kept where it was relative to the view.
    """
    normals = outward_normals(gaussians)
    directions = _fibonacci_sphere(_DIRECTIONS)
    lights = np.einsum("dij,i->dj", _view_frames(directions), np.asarray(light.direction))  # (D, 3)
    basis = _basis(directions, _SH_COEFFICIENTS)  # (D, C)
    # Surfels facing alike (within ~1°) share their coefficients: a box's faces have six sets.
    cells = np.rint(normals / _NORMAL_CELL).astype(np.int64) + 64
    _, first, index = np.unique((cells[:, 0] * 129 + cells[:, 1]) * 129 + cells[:, 2], return_index=True,
                                return_inverse=True)
    coefficients = (_shading(normals[first] @ lights.T, light.ambient) @ np.linalg.pinv(basis).T)[index]  # (N, C)
    # Exact where the photo saw it: the band-limited fit's error there moves into the DC term.
    reference = gaussians.means / np.linalg.norm(gaussians.means, axis=1, keepdims=True)
    at_reference = _shading(np.einsum("nij,i,nj->n", _view_frames(reference), np.asarray(light.direction),
                                      normals), light.ambient)
    coefficients[:, 0] += (at_reference - np.einsum("nc,nc->n", _basis(reference, _SH_COEFFICIENTS),
                                                     coefficients)) / SH_C0
    sh = albedo[:, None, :] * coefficients[:, :, None]
    sh[:, 0] -= 0.5 / SH_C0
    return sh.astype(np.float32)


def _fibonacci_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / count)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
