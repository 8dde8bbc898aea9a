"""Rows moved by their part's matrix: the rigid posing of Gaussians and the gradients carried back through it.

Every Gaussian of part ``k`` is moved by that part's pose at a frame: its centre by ``R_k μ + t_k``, its
quaternion by the left-multiplication matrix of ``q_{R_k}``, its normal by ``R_k``; the gradients come back
through the transposes. With a few parts and many Gaussians, gathering an (N, D, D) stack of matrices and
``einsum`` over it costs several times the arithmetic; one numba pass reads each part's matrix in place.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["per_part"]


@numba.njit(cache=True, error_model="numpy")
def _per_part_kernel(rows: np.ndarray, parts: np.ndarray, matrices: np.ndarray, shift: np.ndarray) -> np.ndarray:
    n, d = rows.shape
    out = np.empty((n, d))
    for i in range(n):
        a = matrices[parts[i]]
        for r in range(d):
            acc = 0.0
            for c in range(d):
                acc += a[r, c] * rows[i, c]
            out[i, r] = acc + shift[parts[i], r]
    return out


def per_part(rows: np.ndarray, parts: np.ndarray, matrices: np.ndarray, shift: np.ndarray | None = None,
             transpose: bool = False) -> np.ndarray:
    """Each row times its part's matrix (or that matrix's transpose), plus its part's shift.

    Parameters
    ----------
    rows : (N, D) float32 or float64
    parts : (N,) int, in ``0..K-1``
    matrices : (K, D, D)
    shift : (K, D), optional
    transpose : bool
        Multiply by ``matrices[k].T`` (the gradient's way back through a linear map).

    Returns
    -------
    (N, D) float64: ``matrices[parts[n]] @ rows[n] + shift[parts[n]]``.
    """
    matrices = np.ascontiguousarray(np.swapaxes(matrices, 1, 2) if transpose else matrices, np.float64)
    shift = np.zeros(matrices.shape[:2]) if shift is None else np.ascontiguousarray(shift, np.float64)
    return _per_part_kernel(np.ascontiguousarray(rows), np.ascontiguousarray(parts, np.int64), matrices, shift)
