"""Slow, obviously-correct twin of :func:`marionette.render.render`, in plain NumPy.

No tiles, no numba: every Gaussian is projected with the reference 3D
Gaussian Splatting formulas (Kerbl et al., SIGGRAPH 2023,
``cuda_rasterizer/forward.cu``), in float64:

- camera point ``t = W μ + w``; culled when ``t_z <= 0.2`` (reference near plane);
- ``Σ = R S Sᵀ Rᵀ`` from the normalised quaternion (a zero quaternion gives the
  identity, as in the reference) and ``S = diag(exp(log_scales))``;
- ``J`` the perspective Jacobian at ``t`` with ``t_x / t_z`` and ``t_y / t_z``
  clamped to 1.3× the half field of view (written for any principal point:
  ``[-(cx + ½)/fx - 0.15 W/fx, (W - ½ - cx)/fx + 0.15 W/fx]``, the reference's
  ``±1.3 tan(fov_x / 2)`` when it is centred);
- ``Σ' = J W Σ Wᵀ Jᵀ + 0.3 I`` (low-pass), culled when ``det Σ' <= 0``;
- radius ``r = ceil(3 sqrt(mid + sqrt(max(0.1, mid² - det))))``, ``mid`` the
  half trace;
- centre ``(u, v) = K (X/Z, Y/Z, 1)``: pixel ``(x, y)`` is evaluated at exactly
  ``(x, y)`` (OpenCV, (0, 0) the centre of the top-left pixel);
- colour ``max(SH(dir) + 0.5, 0)`` with ``dir = μ - camera centre``.

**The 3σ box.** The reference CUDA code evaluates a Gaussian on every pixel of
every 16×16 tile its square ``[u ± r] × [v ± r]`` touches. Here a Gaussian is
evaluated only on the pixels of that square itself (``|x - u| <= r`` and
``|y - v| <= r``), which is what the fast renderer does too, so both agree
exactly rather than up to the tile rounding.

Gaussians are sorted by float32 camera depth, ties by index (the reference's
radix sort is stable), and composited front to back, independently per pixel:
``power = -½ dᵀ Σ'^-1 d`` with ``d`` = pixel − centre, skipped if ``power > 0``;
``α = min(0.99, o exp(power))``, skipped if ``α < 1/255``; if
``T (1 - α) < 1e-4`` the pixel is finished and this Gaussian is not added;
otherwise ``C += α T c``, ``T *= 1 - α``. Finally ``C + T · background``,
clipped to [0, 1].

The loop runs over Gaussians in depth order and updates all the pixels of one
Gaussian's box at once; since pixels are independent, that is the same as the
per-pixel loop above.
"""

from __future__ import annotations

import numpy as np

from marionette.camera import Camera
from marionette.gaussians import Gaussians
from marionette.render.sh import eval_sh

NEAR = 0.2
LOW_PASS = 0.3


def _covariances(quats: np.ndarray, log_scales: np.ndarray) -> np.ndarray:
    """quats (N, 4) ``w, x, y, z``, log_scales (N, 3) → world covariances (N, 3, 3) float64."""
    q = quats.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), 0.0)
    w, x, y, z = q.T
    rot = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=1).reshape(-1, 3, 3)
    m = rot * np.exp(log_scales.astype(np.float64))[:, None, :]  # R S
    return m @ np.swapaxes(m, 1, 2)


def project(gaussians: Gaussians, camera: Camera) -> dict[str, np.ndarray]:
    """Screen-space Gaussians, front to back, culled ones removed.

    Returns a dict of arrays over the M kept Gaussians: ``index (M,)`` into the
    input, ``mean2d (M, 2)``, ``cov2d (M, 2, 2)``, ``conic (M, 2, 2)`` (the
    inverse of ``cov2d``), ``radius (M,)`` int, ``depth (M,)``, ``opacity (M,)``,
    ``rgb (M, 3)``.
    """
    n = len(gaussians)
    w, h = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    view = camera.world_to_camera
    t = gaussians.means.astype(np.float64) @ view[:3, :3].T + view[:3, 3]
    z = t[:, 2]
    zs = np.where(z > NEAR, z, 1.0)  # placeholder for culled rows, never used
    lim_x = (-(cx + 0.5) / fx - 0.15 * w / fx, (w - 0.5 - cx) / fx + 0.15 * w / fx)
    lim_y = (-(cy + 0.5) / fy - 0.15 * h / fy, (h - 0.5 - cy) / fy + 0.15 * h / fy)
    xz = np.clip(t[:, 0] / zs, *lim_x)
    yz = np.clip(t[:, 1] / zs, *lim_y)
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = fx / zs
    jac[:, 0, 2] = -fx * xz / zs
    jac[:, 1, 1] = fy / zs
    jac[:, 1, 2] = -fy * yz / zs
    tw = jac @ view[:3, :3]
    cov2d = tw @ _covariances(gaussians.quats, gaussians.log_scales) @ np.swapaxes(tw, 1, 2)
    cov2d = cov2d + LOW_PASS * np.eye(2)
    det = np.linalg.det(cov2d)
    mid = 0.5 * (cov2d[:, 0, 0] + cov2d[:, 1, 1])
    lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
    keep = (z > NEAR) & (det > 0)
    radius = np.ceil(3.0 * np.sqrt(np.where(keep, lam, 0.0))).astype(np.int64)
    mean2d = np.stack([fx * t[:, 0] / zs + cx, fy * t[:, 1] / zs + cy], axis=1)
    # Keep a Gaussian only if its square box meets the image.
    keep &= (mean2d[:, 0] + radius >= 0) & (mean2d[:, 0] - radius <= w - 1)
    keep &= (mean2d[:, 1] + radius >= 0) & (mean2d[:, 1] - radius <= h - 1)
    index = np.flatnonzero(keep)
    index = index[np.argsort(z[index].astype(np.float32), kind="stable")]
    return {
        "index": index,
        "mean2d": mean2d[index],
        "cov2d": cov2d[index],
        "conic": np.linalg.inv(cov2d[index]),
        "radius": radius[index],
        "depth": z[index],
        "opacity": gaussians.opacities.astype(np.float64)[index],
        "rgb": eval_sh(gaussians.sh[index], gaussians.means[index] - camera.center).astype(np.float64),
    }


def splat_footprint(mean2d: np.ndarray, radius: float, conic: np.ndarray, w: int,
                    h: int) -> tuple[tuple[slice, slice], np.ndarray, np.ndarray, np.ndarray] | None:
    """The pixels of a splat's square 3σ box clipped to the image, and ``-½ dᵀ Σ'^-1 d`` at each of them.

    mean2d (2,) pixel centre, conic (2, 2); returns (box slices, dx, dy, power), each array
    (h', w') with ``d = pixel - mean2d``, or None when the box misses the image.
    """
    (u, v), r = mean2d, radius
    x0, x1 = max(int(np.ceil(u - r)), 0), min(int(np.floor(u + r)), w - 1)
    y0, y1 = max(int(np.ceil(v - r)), 0), min(int(np.floor(v + r)), h - 1)
    if x0 > x1 or y0 > y1:
        return None
    ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
    dx, dy = xs - u, ys - v
    power = -0.5 * (conic[0, 0] * dx * dx + conic[1, 1] * dy * dy) - conic[0, 1] * dx * dy
    return np.s_[y0:y1 + 1, x0:x1 + 1], dx, dy, power


def render_reference(gaussians: Gaussians, camera: Camera,
                     background=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference render → ``image (H, W, 3)``, ``alpha (H, W)``, ``depth (H, W)``, all float64.

    Same outputs and meaning as :func:`marionette.render.render`.
    """
    w, h = camera.width, camera.height
    proj = project(gaussians, camera)
    trans = np.ones((h, w))
    color = np.zeros((h, w, 3))
    zsum = np.zeros((h, w))
    done = np.zeros((h, w), bool)
    for i in range(len(proj["index"])):
        footprint = splat_footprint(proj["mean2d"][i], proj["radius"][i], proj["conic"][i], w, h)
        if footprint is None:
            continue
        box, _, _, power = footprint
        alpha = np.minimum(0.99, proj["opacity"][i] * np.exp(power))
        use = ~done[box] & (power <= 0) & (alpha >= 1.0 / 255.0)
        test_t = trans[box] * (1.0 - alpha)
        finish = use & (test_t < 1e-4)
        done[box] |= finish
        add = use & ~finish
        weight = np.where(add, alpha * trans[box], 0.0)
        color[box] += weight[..., None] * proj["rgb"][i]
        zsum[box] += weight * proj["depth"][i]
        trans[box] = np.where(add, test_t, trans[box])
    image = np.clip(color + trans[..., None] * np.asarray(background, np.float64), 0.0, 1.0)
    alpha = 1.0 - trans
    depth = np.where(alpha > 0, zsum / np.where(alpha > 0, alpha, 1.0), 0.0)
    return image, alpha, depth
