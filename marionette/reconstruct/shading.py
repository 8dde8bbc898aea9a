"""Diffuse shading of a turning object under a fixed light, and its gradients.

An object that turns under a light fixed in the world (the frame-0 camera's
frame) changes its shading as its faces turn towards or away from the light.
When it turns about the viewing direction, the direction each face is seen
from does not change, so view-dependent colours (SH) cannot follow the change;
a normal per Gaussian and one light can. Each Gaussian's colour is its albedo
(the SH colour, in the object's frame) times

    s = (1 - k) + k max(0, n · l)

with ``n`` its unit normal turned with its part, ``l`` the unit direction
towards the light and ``k`` in (0, 1) the diffuse share (the rest is ambient).
The renderer's colour is ``max(SH(dir) + 0.5, 0)``, so scaling it by ``s``
scales the SH terms by ``s`` and moves the DC term by ``(s - 1) 0.5 / C0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..gaussians import Gaussians
from ..render.sh import SH_C0
from ..trajectory import Trajectory
from .posing import per_part

__all__ = ["Lighting", "Shading", "ShadedTrajectory", "shade_factors", "shade_sh", "shade_backward", "factor_backward",
           "tangent", "unit_rows"]


@dataclass(frozen=True)
class Lighting:
    """One directional light plus ambient light, fixed in the world (the frame-0 camera frame).

    Attributes
    ----------
    direction : (3,) float64, unit vector towards the light.
    diffuse : float in (0, 1), the share of the directional light (``k``).
    """

    direction: np.ndarray
    diffuse: float


@dataclass(frozen=True)
class Shading:
    """What a reconstruction needs to shade its Gaussians at any pose.

    Attributes
    ----------
    albedo : (N, C, 3) float32, SH coefficients of the unshaded colours (object frame).
    normals : (N, 3) float64, unit normals in the object frame at frame 0.
    lighting : Lighting
    """

    albedo: np.ndarray
    normals: np.ndarray
    lighting: Lighting

    def factors_at(self, rotations: np.ndarray, parts: np.ndarray) -> np.ndarray:
        """Shading factors (N,) float64 of the Gaussians with their parts (N,) turned by ``rotations`` (K, 3, 3)."""
        return shade_factors(per_part(self.normals, parts, rotations), self.lighting)

    def lit(self, gaussians: Gaussians, parts: np.ndarray, rotations: np.ndarray) -> Gaussians:
        """The Gaussians (N) at rest, coloured as they look with their parts (N,) turned by ``rotations`` (K, 3, 3)."""
        return gaussians.with_sh(shade_sh(self.albedo, self.factors_at(rotations, parts)))

    def sh_at(self, rotations: np.ndarray, parts: np.ndarray, turned_albedo: np.ndarray) -> np.ndarray:
        """SH (N, C, 3) of the Gaussians with their parts turned by ``rotations`` (K, 3, 3), given the albedo
        already turned with them (``turned_albedo`` (N, C, 3))."""
        return shade_sh(turned_albedo, self.factors_at(rotations, parts))


@dataclass(frozen=True)
class ShadedTrajectory(Trajectory):
    """A trajectory whose frames are shaded as each part then faces the light (the Gaussians' own
    colours are replaced by ``shading.albedo``, shaded at every frame)."""

    shading: Shading

    def frame(self, gaussians: Gaussians, t: int) -> Gaussians:
        posed = super().frame(gaussians.with_sh(self.shading.albedo), t)
        return posed.with_sh(self.shading.sh_at(self.part_rotations[t].astype(np.float64), self.labels, posed.sh))


def unit_rows(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors → unit vectors (a zero vector stays zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, 1e-12)


def shade_factors(normals: np.ndarray, lighting: Lighting) -> np.ndarray:
    """Unit world normals (N, 3) → shading factors ``s`` (N,) float64."""
    # einsum, not BLAS: BLAS threads spin after a call and slow the rasterizer's threads that follow
    lit = np.maximum(np.einsum("ni,i->n", normals, np.asarray(lighting.direction, np.float64)), 0.0)
    return (1.0 - lighting.diffuse) + lighting.diffuse * lit


def shade_sh(sh: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """SH coefficients (N, C, 3) of the albedo → those of the albedo times ``factors`` (N,), float32."""
    s = factors[:, None].astype(np.float64)
    out = sh.astype(np.float64) * s[:, :, None]
    out[:, 0] += 0.5 * (s - 1.0) / SH_C0
    return out.astype(np.float32)


def shade_backward(sh: np.ndarray, factors: np.ndarray, grad_shaded: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients through :func:`shade_sh`.

    Parameters
    ----------
    sh : (N, C, 3) albedo coefficients; factors : (N,) ``s``; grad_shaded : (N, C, 3) ∂L/∂(shaded coefficients).

    Returns
    -------
    ∂L/∂sh (N, C, 3) float64 and ∂L/∂s (N,) float64.
    """
    g = grad_shaded.astype(np.float64)
    grad_sh = g * factors[:, None, None]
    grad_s = np.einsum("nck,nck->n", g, sh.astype(np.float64)) + g[:, 0].sum(axis=1) * (0.5 / SH_C0)
    return grad_sh, grad_s


def factor_backward(normals: np.ndarray, lighting: Lighting, grad_s: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, float]:
    """Gradients of ``s`` (:func:`shade_factors`) given ∂L/∂s (N,).

    Returns ∂L/∂n (N, 3) for the unit world normals, ∂L/∂l (3,) for the unit light
    direction and ∂L/∂k.
    """
    light = np.asarray(lighting.direction, np.float64)
    dot = np.einsum("ni,i->n", normals, light)
    on = dot > 0
    weighted = grad_s * on * lighting.diffuse
    grad_n = weighted[:, None] * light
    grad_l = np.einsum("n,ni->i", weighted, normals)
    grad_k = float(np.sum(grad_s * (np.maximum(dot, 0.0) - 1.0)))
    return grad_n, grad_l, grad_k


def tangent(grad: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """Gradient (..., 3) with respect to ``unit_rows(raw)`` → with respect to ``raw``: ``(I - u uᵀ) g / |raw|``."""
    norm = np.maximum(np.linalg.norm(raw, axis=-1, keepdims=True), 1e-12)
    u = raw / norm
    return (grad - u * np.sum(grad * u, axis=-1, keepdims=True)) / norm
