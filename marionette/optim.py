"""Adam (Kingma & Ba, "Adam: a method for stochastic optimization", ICLR 2015) over named arrays."""

from __future__ import annotations

import numpy as np

__all__ = ["Adam"]


class Adam:
    """Adam over a dict of (N, ...) float arrays; state rows follow the Gaussians through densification."""

    def __init__(self, params: dict[str, np.ndarray], b1: float = 0.9, b2: float = 0.999, eps: float = 1e-15):
        self.m = {k: np.zeros_like(v, dtype=np.float64) for k, v in params.items()}
        self.v = {k: np.zeros_like(v, dtype=np.float64) for k, v in params.items()}
        self.b1, self.b2, self.eps, self.step = b1, b2, eps, 0

    def update(self, params: dict[str, np.ndarray], grads: dict[str, np.ndarray], lrs: dict[str, float]) -> None:
        self.step += 1
        c1, c2 = 1 - self.b1 ** self.step, 1 - self.b2 ** self.step
        for k, g in grads.items():
            m, v = self.m[k], self.v[k]  # updated in place: the same arithmetic without new arrays
            m *= self.b1
            m += (1 - self.b1) * g
            v *= self.b2
            v += (1 - self.b2) * g * g
            step = m / c1
            step *= lrs[k]
            scale = np.sqrt(v / c2)
            scale += self.eps
            step /= scale
            params[k] -= step.astype(params[k].dtype)

    def reindex(self, index: np.ndarray, fresh: int) -> None:
        """Keep rows ``index`` and append ``fresh`` zero rows."""
        for state in (self.m, self.v):
            for k, a in state.items():
                state[k] = np.concatenate([a[index], np.zeros((fresh,) + a.shape[1:])])
