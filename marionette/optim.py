"""Adam (Kingma & Ba, "Adam: a method for stochastic optimization", ICLR 2015) over named arrays."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["Adam"]


@numba.njit(cache=True, error_model="numpy")  # no divide-by-zero checks: the loop vectorises
def _adam_kernel(param: np.ndarray, grad: np.ndarray, m: np.ndarray, v: np.ndarray, lr: float, b1: float,
                 b2: float, c1: float, c2: float, eps: float) -> None:
    """One Adam step in place over flat arrays: param (n,) float32 or float64, grad, m, v (n,) float64.

    The arithmetic of the textbook update element by element, in one pass (NumPy needs one per operation);
    the step is rounded to the parameter's type before it is subtracted."""
    for i in range(param.size):
        g = grad[i]
        m[i] = m[i] * b1 + (1 - b1) * g
        v[i] = v[i] * b2 + (1 - b2) * g * g
        param[i] -= param.dtype.type(m[i] / c1 * lr / (np.sqrt(v[i] / c2) + eps))


class Adam:
    """Adam over a dict of (N, ...) float arrays; state rows follow the Gaussians through densification."""

    def __init__(self, params: dict[str, np.ndarray], b1: float = 0.9, b2: float = 0.999, eps: float = 1e-15):
        self.m = {k: np.zeros(v.shape) for k, v in params.items()}
        self.v = {k: np.zeros(v.shape) for k, v in params.items()}
        self.b1, self.b2, self.eps, self.step = b1, b2, eps, 0

    def update(self, params: dict[str, np.ndarray], grads: dict[str, np.ndarray], lrs: dict[str, float]) -> None:
        self.step += 1
        c1, c2 = 1 - self.b1 ** self.step, 1 - self.b2 ** self.step
        for k, g in grads.items():
            param = params[k]
            flat = param.reshape(-1) if param.flags.c_contiguous else param.ravel()  # a view when it can be
            _adam_kernel(flat, np.ascontiguousarray(g, np.float64).reshape(-1), self.m[k].reshape(-1),
                         self.v[k].reshape(-1), float(lrs[k]), self.b1, self.b2, c1, c2, self.eps)
            if not np.shares_memory(flat, param):
                param[...] = flat.reshape(param.shape)

    def reindex(self, index: np.ndarray, fresh: int) -> None:
        """Keep rows ``index`` and append ``fresh`` zero rows."""
        for state in (self.m, self.v):
            for k, a in state.items():
                state[k] = np.concatenate([a[index], np.zeros((fresh,) + a.shape[1:])])
