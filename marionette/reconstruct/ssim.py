"""Structural dissimilarity (D-SSIM) of a render against its target, with its gradient.

3D Gaussian Splatting (Kerbl et al. 2023, Eq. 7) adds ``λ (1 - SSIM)`` to its
L1 loss: the L1 term alone fits the mean colour of a patch but not its
contrast and structure, which is what SSIM and LPIPS score. SSIM (Wang et al.
2004) over an 11x11 Gaussian window (σ = 1.5) per channel, the frame
zero-padded at its border; the gradient follows the SSIM map through the
five filtered moments (means, second moments, cross moment). A zero-padded
filter with a symmetric kernel is its own adjoint, so the backward pass
filters with the same kernel.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["ssim_window", "dssim_and_grad"]

#: Stabilisers of SSIM for a data range of 1 (Wang et al.: K1 = 0.01, K2 = 0.03).
C1, C2 = 0.01 ** 2, 0.03 ** 2


def ssim_window(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """(size,) float64 normalised 1D Gaussian; the 2D window is its outer product."""
    return cv2.getGaussianKernel(size, sigma, cv2.CV_64F)[:, 0]


def _blur(a: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``a`` (H, W, C) filtered by the separable window, zero outside the frame, in ``a``'s precision."""
    out = cv2.sepFilter2D(a, -1, kernel, kernel, borderType=cv2.BORDER_CONSTANT)
    return out.reshape(a.shape)  # cv2 drops a trailing channel axis of 1


def dssim_and_grad(image: np.ndarray, target: np.ndarray, *,
                   kernel: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """``1 - mean SSIM`` of ``image`` against ``target`` and its gradient with respect to ``image``.

    Parameters
    ----------
    image, target : (H, W, C) float arrays in [0, 1]
        Computed in float64 when ``image`` is float64, else in float32 (a fit's gradient
        needs no more, and it halves the filters' work).
    kernel : (k,) float64 1D window (default :func:`ssim_window`)

    Returns
    -------
    loss : float, the mean over pixels and channels of ``1 - SSIM``.
    grad : (H, W, C) float32 or float64 (as computed), ∂loss/∂image.
    """
    dtype = np.float64 if np.asarray(image).dtype == np.float64 else np.float32
    kernel = (ssim_window() if kernel is None else kernel).astype(dtype)
    x = np.asarray(image, dtype)
    y = np.asarray(target, dtype)
    mu_x, mu_y = _blur(x, kernel), _blur(y, kernel)
    var_x = _blur(x * x, kernel) - mu_x ** 2
    var_y = _blur(y * y, kernel) - mu_y ** 2
    cov = _blur(x * y, kernel) - mu_x * mu_y
    a1, a2 = 2 * mu_x * mu_y + C1, 2 * cov + C2
    b1, b2 = mu_x ** 2 + mu_y ** 2 + C1, var_x + var_y + C2
    ssim = a1 * a2 / (b1 * b2)
    n = ssim.size
    # ∂SSIM per pixel with respect to the filtered moments μx, E[x²] and E[xy].
    d_mu = 2 * mu_y * (a2 - a1) / (b1 * b2) - 2 * mu_x * ssim * (1 / b1 - 1 / b2)
    d_xx = -ssim / b2
    d_xy = 2 * a1 / (b1 * b2)
    grad = _blur(d_mu, kernel) + 2 * x * _blur(d_xx, kernel) + y * _blur(d_xy, kernel)
    return float(1 - ssim.mean(dtype=np.float64)), grad * dtype(-1 / n)
