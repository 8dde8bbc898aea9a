"""Photometric polish of a lift's reference view: colours and opacities fitted to the photo.

A lift puts one surfel on each pixel's ray with that pixel's colour, but the
splats blur (each is at least the rasterizer's 0.3 px² low-pass wide) and the
rim's surfels, stacked edge-on, spill a pixel past the outline. A few Adam
steps on the colours (SH DC) and opacity logits of the surfels the reference
view sees, through the rasterizer's backward pass, bring edges and small
details back, so that rendering the reference view gives the photo:

    L = mean |I - P|² + mask_weight · mean (A - M)²

with ``I`` the render on white, ``P`` the photo's object on white, ``A`` the
rendered alpha and ``M`` the mask. Positions, shapes and every surfel the
reference view does not see (less than ``_MIN_VISIBLE`` of a pixel's weight
in total) are left alone, so the shape does not move and the sides and back
keep their colours.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..camera import Camera
from ..gaussians import SH_C0, Gaussians
from ..optim import Adam
from ..render.backward import render_with_grad

__all__ = ["polish_reference"]

# A surfel is polished when its total blending weight in the reference view reaches this share of a pixel.
_MIN_VISIBLE = 0.02
# Opacities stay within these bounds (logits), so that no surfel becomes a hole seen from the side.
_MIN_OPACITY, _MAX_OPACITY = 0.3, 0.99
_LR_COLOUR, _LR_OPACITY = 0.2, 0.1


def polish_reference(gaussians: Gaussians, camera: Camera, image: np.ndarray, mask: np.ndarray,
                     iterations: int, mask_weight: float = 1.0) -> tuple[Gaussians, list[float]]:
    """Fit the colours and opacities of the surfels seen by ``camera`` to ``image``.

    Parameters
    ----------
    gaussians : Gaussians, N of them (degree-0 colours are fitted; higher SH bands are kept).
    camera : Camera, the reference view.
    image : (H, W, 3|4) uint8 photo; mask : (H, W) bool its object pixels.
    iterations : int, Adam steps (0 returns the input).
    mask_weight : float, weight of the alpha term.

    Returns
    -------
    (Gaussians, losses): the polished Gaussians, and the loss before each step and after the last.
    """
    if iterations <= 0:
        return gaussians, []
    weight = mask.astype(np.float32)
    target = image[..., :3].astype(np.float32) / 255.0 * weight[..., None] + (1.0 - weight[..., None])
    npx = weight.size
    view = render_with_grad(gaussians, camera)
    # Each surfel's total blending weight in the view: the gradient of the summed image w.r.t. its colour.
    seen = view.backward(np.ones(target.shape, np.float32) / 3).sh[:, 0].sum(axis=1) / SH_C0 >= _MIN_VISIBLE
    params = {"dc": gaussians.sh[seen, 0].astype(np.float64),
              "logits": gaussians.opacity_logits[seen].astype(np.float64)}
    adam = Adam(params)
    low, high = np.log(_MIN_OPACITY / (1 - _MIN_OPACITY)), np.log(_MAX_OPACITY / (1 - _MAX_OPACITY))
    losses = []
    current = gaussians
    for step in range(iterations + 1):
        if step:
            view = render_with_grad(current, camera)
        residual = view.output.image - target
        alpha_residual = view.output.alpha - weight
        losses.append(float((residual**2).mean() + mask_weight * (alpha_residual**2).mean()))
        if step == iterations:
            break
        grads = view.backward(2 * residual / (3 * npx), 2 * mask_weight * alpha_residual / npx)
        adam.update(params, {"dc": grads.sh[seen, 0].astype(np.float64),
                             "logits": grads.opacity_logits[seen].astype(np.float64)},
                    {"dc": _LR_COLOUR, "logits": _LR_OPACITY})
        params["logits"] = np.clip(params["logits"], low, high)
        sh = current.sh.copy()
        sh[seen, 0] = params["dc"]
        logits = current.opacity_logits.copy()
        logits[seen] = params["logits"]
        current = replace(current, sh=sh, opacity_logits=logits)
    return current, losses
