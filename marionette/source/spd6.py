"""Cholesky factorisation and solve of 6 × 6 symmetric positive definite systems, as compiled loops.

Shared by the kernels that solve one small normal system per point or pose (the tracker's affine refinement,
the part fits' pose refinement): written out, with no LAPACK call, so their rounding is the same on every
machine.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["cholesky6", "cholesky6_solve"]


@numba.njit(cache=True)
def cholesky6(a):
    """Lower Cholesky factor of a symmetric positive definite (6, 6) matrix."""
    low = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            acc = a[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = np.sqrt(acc) if i == j else acc / low[j, j]
    return low


@numba.njit(cache=True)
def cholesky6_solve(low, b):
    """Solve ``L Lᵀ x = b`` for (6,) ``b``."""
    y = np.empty(6)
    for i in range(6):
        acc = b[i]
        for k in range(i):
            acc -= low[i, k] * y[k]
        y[i] = acc / low[i, i]
    x = np.empty(6)
    for i in range(5, -1, -1):
        acc = y[i]
        for k in range(i + 1, 6):
            acc -= low[k, i] * x[k]
        x[i] = acc / low[i, i]
    return x
