"""The orientations of Gaussians turned by rigid rotations (:meth:`marionette.gaussians.Gaussians.turned`).

A numba kernel of its own module, so that :mod:`marionette.gaussians` (and with it every reader of a ``.ply``)
loads without numba.
"""

import numba
import numpy as np

from ..parallel import CHUNK, chunks, parallel_for

__all__ = ["turn_quaternions"]


def turn_quaternions(own, turns, labels):
    """Quaternions own (N, 4) float32, normalised, pre-multiplied by ``turns[labels[i]]`` (P, 4) float64,
    ``w >= 0`` (as :func:`~marionette.geometry.matrix_to_quaternion` gives) → (N, 4) float32.

    What ``quaternion_multiply(turns[labels], own / |own|)`` computes, without its (N, 4) float64
    temporaries: a frame of a moving target turns every Gaussian.
    """
    out = np.empty(own.shape, np.float32)
    parallel_for(_turn_chunks, chunks(own.shape[0]), own, turns, labels, out)
    return out


@numba.njit(nogil=True, cache=True)
def _turn_chunks(first, step, nchunks, own, turns, labels, out):
    """Chunks ``first, first + step, ...`` of ``turn_quaternions`` (one thread's share), into out (N, 4)."""
    for chunk in range(first, nchunks, step):
        for i in range(chunk * CHUNK, min(own.shape[0], (chunk + 1) * CHUNK)):
            w, x, y, z = np.float64(own[i, 0]), np.float64(own[i, 1]), np.float64(own[i, 2]), np.float64(own[i, 3])
            norm = max(np.sqrt(w * w + x * x + y * y + z * z), 1e-300)
            w, x, y, z = w / norm, x / norm, y / norm, z / norm
            a = turns[labels[i]]
            product = (a[0] * w - a[1] * x - a[2] * y - a[3] * z, a[0] * x + a[1] * w + a[2] * z - a[3] * y,
                       a[0] * y - a[1] * z + a[2] * w + a[3] * x, a[0] * z + a[1] * y - a[2] * x + a[3] * w)
            sign = -1.0 if product[0] < 0 else 1.0
            for k in range(4):
                out[i, k] = np.float32(sign * product[k])
