"""A set of 3D Gaussians in the reference 3D Gaussian Splatting parameterisation."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import InputError

__all__ = ["Gaussians", "SH_C0", "rgb_to_sh", "sh_to_rgb"]

#: Zeroth-order real spherical-harmonic constant, ``rgb = 0.5 + SH_C0 * f_dc``.
SH_C0 = 0.28209479177387814


def rgb_to_sh(rgb: np.ndarray) -> np.ndarray:
    """Colours in [0, 1] (..., 3) → degree-0 SH coefficients (..., 3)."""
    return (np.asarray(rgb, dtype=np.float32) - 0.5) / SH_C0


def sh_to_rgb(dc: np.ndarray) -> np.ndarray:
    """Degree-0 SH coefficients (..., 3) → colours (..., 3) (not clipped)."""
    return 0.5 + SH_C0 * np.asarray(dc, dtype=np.float32)


@dataclass(frozen=True)
class Gaussians:
    """N anisotropic 3D Gaussians, stored as 3DGS stores them.

    Attributes
    ----------
    means : (N, 3) float32
        Centres in world coordinates.
    quats : (N, 4) float32
        Orientation quaternions ``w, x, y, z`` (not necessarily normalised;
        renderers normalise).
    log_scales : (N, 3) float32
        Natural log of the standard deviations along the local axes.
    opacity_logits : (N,) float32
        ``opacity = sigmoid(opacity_logits)``.
    sh : (N, C, 3) float32
        Spherical-harmonic colour coefficients, ``C = (degree + 1)^2`` with
        degree 0 to 3; ``sh[:, 0]`` is the DC term (``rgb = 0.5 + SH_C0 * sh[:, 0]``).
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.means).shape[0] if np.ndim(self.means) == 2 else -1
        expected = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,),
        }
        for name, shape in expected.items():
            value = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if value.shape != shape or n < 0:
                raise InputError(f"Gaussians.{name} must have shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        sh = np.ascontiguousarray(self.sh, dtype=np.float32)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3 or sh.shape[1] not in (1, 4, 9, 16):
            raise InputError(f"Gaussians.sh must have shape ({n}, C, 3) with C in 1, 4, 9, 16, got {sh.shape}")
        object.__setattr__(self, "sh", sh)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        """Spherical-harmonic degree, 0 to 3."""
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    @property
    def opacities(self) -> np.ndarray:
        """(N,) float32 opacities in (0, 1)."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits))).astype(np.float32)

    @property
    def scales(self) -> np.ndarray:
        """(N, 3) float32 standard deviations."""
        return np.exp(self.log_scales)

    @property
    def rgb(self) -> np.ndarray:
        """(N, 3) float32 view-independent colour from the DC term."""
        return sh_to_rgb(self.sh[:, 0])

    def check_finite(self) -> None:
        """Raise :class:`InputError` naming the first attribute with NaN or infinity."""
        for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise InputError(f"Gaussians.{name} contains NaN or infinite values")

    def subset(self, index: np.ndarray) -> "Gaussians":
        """Gaussians selected by a boolean mask (N,) or an index array (M,)."""
        return Gaussians(self.means[index], self.quats[index], self.log_scales[index],
                         self.opacity_logits[index], self.sh[index])

    def with_means(self, means: np.ndarray) -> "Gaussians":
        """The same Gaussians moved to ``means`` (N, 3)."""
        return replace(self, means=means)

    def with_sh(self, sh: np.ndarray) -> "Gaussians":
        """The same Gaussians with colours ``sh`` (N, C, 3)."""
        return replace(self, sh=sh)

    def turned(self, quats: np.ndarray, labels: np.ndarray | None = None) -> "Gaussians":
        """Orientations pre-multiplied by unit quaternions ``w, x, y, z``; means unchanged.

        ``quats`` is one quaternion (4,) for all, one per Gaussian (N, 4), or with ``labels`` (N,) int
        one per group (P, 4), Gaussian i turned by ``quats[labels[i]]``.

        SH coefficients turn with them (:func:`~marionette.render.sh.rotate_sh`): a
        turned Gaussian shows towards ``d`` the colour it showed towards ``Rᵀ d``.
        """
        turns = np.ascontiguousarray(np.asarray(quats, dtype=np.float64).reshape(-1, 4))
        if labels is None:
            if len(turns) not in (1, len(self)):
                raise InputError(f"turned: {len(turns)} quaternions for {len(self)} Gaussians")
            labels = np.zeros(len(self), np.int64) if len(turns) == 1 else np.arange(len(self))
        labels = np.asarray(labels)
        if labels.shape != (len(self),) or (len(labels) and (labels.min() < 0 or labels.max() >= len(turns))):
            raise InputError(f"turned: labels must be ({len(self)},) indices into {len(turns)} quaternions")
        from .geometry import quaternion_to_matrix
        from .render.sh import rotate_sh  # imported here: the renderer imports this module
        from .render.turn import turn_quaternions

        return replace(self, quats=turn_quaternions(self.quats, turns, labels),
                       sh=rotate_sh(self.sh, quaternion_to_matrix(turns), labels))

    @staticmethod
    def concatenate(parts: list["Gaussians"]) -> "Gaussians":
        """Join several sets; SH is padded with zeros to the highest degree."""
        c = max(p.sh.shape[1] for p in parts)
        sh = [np.pad(p.sh, ((0, 0), (0, c - p.sh.shape[1]), (0, 0))) for p in parts]
        return Gaussians(
            np.concatenate([p.means for p in parts]), np.concatenate([p.quats for p in parts]),
            np.concatenate([p.log_scales for p in parts]),
            np.concatenate([p.opacity_logits for p in parts]), np.concatenate(sh),
        )

    @staticmethod
    def from_rgb(means: np.ndarray, rgb: np.ndarray, scales: np.ndarray,
                 opacities: np.ndarray | float = 0.99, quats: np.ndarray | None = None) -> "Gaussians":
        """Build degree-0 Gaussians from plain values.

        means (N, 3), rgb (N, 3) in [0, 1], scales (N, 3) or (N,) standard
        deviations, opacities (N,) or a scalar in (0, 1), quats (N, 4) (identity by default).
        """
        means = np.asarray(means, dtype=np.float32)
        n = len(means)
        scales = np.asarray(scales, dtype=np.float32)
        if scales.ndim == 1:
            scales = np.repeat(scales[:, None], 3, axis=1)
        op = np.clip(np.broadcast_to(np.asarray(opacities, dtype=np.float64), (n,)), 1e-6, 1 - 1e-6)
        if quats is None:
            quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
        return Gaussians(means, quats, np.log(scales), np.log(op / (1 - op)),
                         rgb_to_sh(rgb)[:, None, :])
