"""Real spherical harmonics of degree 0 to 3, as the reference 3D Gaussian Splatting evaluates them.

Constants, basis order and signs follow ``eval_sh`` (``utils/sh_utils.py``) and
``computeColorFromSH`` (``cuda_rasterizer/forward.cu``) of Kerbl et al., "3D
Gaussian Splatting for Real-Time Radiance Field Rendering" (SIGGRAPH 2023):
``colour = max(SH(dir) + 0.5, 0)`` with ``dir`` the unit vector from the camera
centre to the Gaussian mean, in world coordinates. Colours are clamped from
below only, like the reference.

:func:`eval_sh` is the NumPy version; :func:`_eval_sh_one` is its numba twin
for one Gaussian, used inside the rasterizer.
"""

from __future__ import annotations

import numba
import numpy as np

from ..errors import InputError
from ..parallel import CHUNK, chunks, parallel_for

__all__ = ["eval_sh", "rotate_sh", "sh_rotations"]

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def _basis(dirs: np.ndarray, c: int) -> np.ndarray:
    """Unit directions (N, 3) float64 → the first ``c`` basis functions (N, C) float64."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    b = [np.full_like(x, SH_C0)]
    if c > 1:
        b += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if c > 4:
        xx, yy, zz = x * x, y * y, z * z
        b += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy),
              SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
    if c > 9:
        b += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
              SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
              SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(b, axis=1)


def eval_sh(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """View-dependent colours from SH coefficients.

    Parameters
    ----------
    sh : ndarray, shape (N, C, 3)
        Coefficients, ``C = (degree + 1)^2`` in 1, 4, 9, 16.
    dirs : ndarray, shape (N, 3)
        Viewing directions (camera centre → Gaussian mean, world frame); they
        are normalised here.

    Returns
    -------
    rgb : ndarray, shape (N, 3) float32
        ``max(SH(dir) + 0.5, 0)``.
    """
    sh = np.asarray(sh, dtype=np.float64)
    dirs = np.asarray(dirs, dtype=np.float64)
    if sh.ndim != 3 or sh.shape[2] != 3 or sh.shape[1] not in (1, 4, 9, 16):
        raise InputError(f"eval_sh: sh must have shape (N, C, 3) with C in 1, 4, 9, 16, got {sh.shape}")
    if dirs.shape != (sh.shape[0], 3):
        raise InputError(f"eval_sh: dirs must have shape ({sh.shape[0]}, 3), got {dirs.shape}")
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    rgb = np.einsum("nc,nck->nk", _basis(unit, sh.shape[1]), sh) + 0.5
    return np.maximum(rgb, 0.0).astype(np.float32)


def _fibonacci_sphere(k: int) -> np.ndarray:
    """k roughly even unit directions (k, 3) float64."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


#: Directions on which each band's rotation is solved: any 2l + 1 directions in general position
#: determine it, since a band is closed under rotation; 32 keep the solve well conditioned.
_FIT_DIRS = _fibonacci_sphere(32)
#: Bands l = 2, 3 (band 1 has a closed form): coefficient range and the solve (2l + 1, K) that
#: turns their basis on the directions into coefficients, computed once.
_BAND_SOLVES = tuple((lo, hi, np.linalg.pinv(_basis(_FIT_DIRS, hi)[:, lo:hi])) for lo, hi in ((4, 9), (9, 16)))
#: Band 1 is ``C1 (-y, z, -x)``: the direction's axes and signs, in coefficient order.
_BAND1_AXES, _BAND1_SIGNS = np.array([1, 2, 0]), np.array([-1.0, 1.0, -1.0])


def sh_rotations(rotations: np.ndarray, coefficients: int) -> np.ndarray:
    """Matrices that turn SH coefficients with their Gaussian.

    Parameters
    ----------
    rotations : (P, 3, 3) array
    coefficients : int
        ``C`` in 1, 4, 9, 16.

    Returns
    -------
    (P, C, C) float64
        ``M``, block diagonal by band (band 0 the identity), such that the
        coefficients ``M @ sh`` show in direction ``d`` the colour ``sh`` shows
        in ``Rᵀ d``: ``basis(Rᵀ d) = basis(d) M``. Band 1 is ``R`` itself with
        its axes permuted and signed (exact, so fits that use degree 1 do not
        depend on the LAPACK build); bands 2 and 3 are solved on fixed
        directions (to about 1e-15).
    """
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    out = np.zeros((len(rotations), coefficients, coefficients))
    out[:, 0, 0] = 1.0
    if coefficients > 1:
        signs = _BAND1_SIGNS[:, None] * _BAND1_SIGNS[None, :]
        out[:, 1:4, 1:4] = rotations[:, _BAND1_AXES[:, None], _BAND1_AXES[None, :]] * signs
    k = len(_FIT_DIRS)
    for lo, hi, solve in _BAND_SOLVES:
        if hi > coefficients:
            break
        for s in range(0, len(rotations), 4096):  # bounded temporaries for one rotation per Gaussian
            chunk = rotations[s:s + 4096]
            turned = (_FIT_DIRS @ chunk).reshape(-1, 3)  # rows dᵀ R = (Rᵀ d)ᵀ
            out[s:s + 4096, lo:hi, lo:hi] = solve @ _basis(turned, hi).reshape(len(chunk), k, hi)[..., lo:hi]
    return out


def rotate_sh(sh: np.ndarray, rotations: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """SH coefficients of Gaussians turned about their centres.

    sh (N, C, 3), rotations (P, 3, 3), labels (N,) int: Gaussian ``i`` turned
    by ``rotations[labels[i]]`` → (N, C, 3) float32 that show in direction
    ``d`` the colour ``sh`` shows in ``Rᵀ d``. Degree 0 has no direction: ``sh``
    itself comes back.
    """
    if sh.shape[1] == 1:
        return sh
    mats = sh_rotations(rotations, sh.shape[1])
    return _apply_sh_rotations(np.ascontiguousarray(sh, dtype=np.float32), mats,
                               np.ascontiguousarray(labels, dtype=np.int64))


def _apply_sh_rotations(sh, mats, labels):
    """sh (N, C, 3) float32, mats (P, C, C) block-diagonal float64, labels (N,) → (N, C, 3) float32."""
    out = np.empty_like(sh)
    parallel_for(_sh_rotation_chunks, chunks(sh.shape[0]), sh, mats, labels, out)
    return out


@numba.njit(nogil=True, cache=True)
def _sh_rotation_chunks(first, step, nchunks, sh, mats, labels, out):
    """Chunks ``first, first + step, ...`` of ``_apply_sh_rotations`` (one thread's share), into out."""
    n, c = sh.shape[0], sh.shape[1]
    for chunk in range(first, nchunks, step):
        for i in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            m = labels[i]
            for k in range(3):
                out[i, 0, k] = sh[i, 0, k]
            for band in range(1, 4):
                lo, hi = band * band, (band + 1) * (band + 1)
                if hi > c:
                    break
                for a in range(lo, hi):
                    for k in range(3):
                        acc = 0.0
                        for b in range(lo, hi):
                            acc += mats[m, a, b] * sh[i, b, k]
                        out[i, a, k] = acc


@numba.njit(cache=True, inline="always")
def _eval_sh_one(sh: np.ndarray, i: int, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Numba twin of :func:`eval_sh` for Gaussian ``i``: sh (N, C, 3), unit dir → (r, g, b)."""
    return (max(_sh_channel(sh, i, 0, x, y, z) + 0.5, 0.0),
            max(_sh_channel(sh, i, 1, x, y, z) + 0.5, 0.0),
            max(_sh_channel(sh, i, 2, x, y, z) + 0.5, 0.0))


@numba.njit(cache=True, inline="always")
def _sh_channel(sh: np.ndarray, i: int, k: int, x: float, y: float, z: float) -> float:
    """SH(dir) of colour channel ``k`` of Gaussian ``i``: sh (N, C, 3), unit dir → float."""
    c = sh.shape[1]
    xx, yy, zz = x * x, y * y, z * z
    v = SH_C0 * sh[i, 0, k]
    if c > 1:
        v += -SH_C1 * y * sh[i, 1, k] + SH_C1 * z * sh[i, 2, k] - SH_C1 * x * sh[i, 3, k]
    if c > 4:
        v += (SH_C2[0] * x * y * sh[i, 4, k] + SH_C2[1] * y * z * sh[i, 5, k]
              + SH_C2[2] * (2 * zz - xx - yy) * sh[i, 6, k] + SH_C2[3] * x * z * sh[i, 7, k]
              + SH_C2[4] * (xx - yy) * sh[i, 8, k])
    if c > 9:
        v += (SH_C3[0] * y * (3 * xx - yy) * sh[i, 9, k] + SH_C3[1] * x * y * z * sh[i, 10, k]
              + SH_C3[2] * y * (4 * zz - xx - yy) * sh[i, 11, k]
              + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[i, 12, k]
              + SH_C3[4] * x * (4 * zz - xx - yy) * sh[i, 13, k]
              + SH_C3[5] * z * (xx - yy) * sh[i, 14, k] + SH_C3[6] * x * (xx - 3 * yy) * sh[i, 15, k])
    return v
