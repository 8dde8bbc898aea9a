"""The same answer on every machine: values rounded onto a grid before a choice that could flip on their last bits.

Two machines compute the same matrix product or render a few units in the
last place apart: OpenBLAS picks its kernel by CPU (``OPENBLAS_CORETYPE``
overrides it), numba compiles for the CPU at hand, NumPy and OpenCV dispatch
SIMD code by CPU. Most of the pipeline carries such differences on at their
size, but a fit with a discrete choice in it (RANSAC keeping its best random
sample, an inlier gate) can turn them into another answer, poses degrees
apart under two BLAS kernels of one machine
(``docs/benchmarks/reproducibility_real.md``).
Rounding what such a choice starts from onto a grid far finer than its
accuracy and far coarser than the rounding noise hands every machine the
same numbers, unless a value lies within that noise of a grid boundary (a
chance of about noise / step per value).
"""

from __future__ import annotations

import numpy as np

from .geometry import matrix_to_axis_angle, rodrigues_terms

__all__ = ["snap", "snap_pose"]

#: The grid a rebuilt rotation matrix's entries are rounded to: its sines and cosines, and NumPy's SIMD paths
#: for them, differ by an ulp (1e-16) from machine to machine; the matrix stays orthonormal to 1e-12.
_ENTRY_STEP = 2.0 ** -40


def snap(values: np.ndarray, step: float) -> np.ndarray:
    """``values`` (any shape) rounded to the nearest multiple of ``step``, as float64 (NaN stays NaN)."""
    return np.round(np.asarray(values, dtype=np.float64) / step) * step


def snap_pose(pose: np.ndarray, step: float) -> np.ndarray:
    """Rigid transforms (..., 4, 4) with their rotation vectors (radians) and translations rounded to ``step``.

    The rotation is rebuilt from the rounded vector by Rodrigues' formula in elementwise operations only (a
    matrix product would go through BLAS), then its entries are rounded to a 2^-40 grid, so that the result is
    the same bits on every machine.
    """
    pose = np.asarray(pose, dtype=np.float64)
    v = snap(matrix_to_axis_angle(pose[..., :3, :3]), step)  # (..., 3)
    theta, cross, a, b = rodrigues_terms(v)
    # K² = v vᵀ - |v|² I, elementwise
    rotation = np.eye(3) + a * cross + b * (v[..., :, None] * v[..., None, :] - theta ** 2 * np.eye(3))
    out = np.zeros_like(pose)
    out[..., :3, :3] = snap(rotation, _ENTRY_STEP)
    out[..., :3, 3] = snap(pose[..., :3, 3], step)
    out[..., 3, 3] = 1.0
    return out
