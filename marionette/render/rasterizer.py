"""CPU Gaussian rasterizer: tile-based EWA splatting with numba.

Follows the forward pass of the reference 3D Gaussian Splatting rasterizer
(Kerbl et al., SIGGRAPH 2023, ``cuda_rasterizer/forward.cu``), with the EWA
projection of Zwicker et al., "EWA Volume Splatting" (2001), Eq. 31:

1. ``_activations`` (NumPy, whose exp and log are SIMD) and ``_preprocess``
   (numba, parallel over Gaussians, branch-free): camera point ``t = W μ + w``,
   culled when ``t_z <= 0.2``; ``Σ = R S Sᵀ Rᵀ``; ``Σ' = J W Σ Wᵀ Jᵀ + 0.3 I``
   with ``J`` the perspective Jacobian at ``t``, whose ``t_x / t_z`` and
   ``t_y / t_z`` are clamped to 1.3× the half field of view; conic
   ``Σ'^-1``; radius ``ceil(3 sqrt(λ_max(Σ')))`` (with the reference's
   ``max(0.1, ·)`` under the square root); colour from SH
   (:mod:`marionette.render.sh`) seen from the camera centre.
2. ``_depth_order``: one global sort by (float32 depth, index), stable like
   the reference's radix sort; ``_gather`` copies the visible Gaussians' rows
   in that order.
3. ``_bin``: per-tile lists of Gaussians built by counting, filled in
   depth order so each list comes out sorted.
4. ``_blend`` (parallel over 16×16 tiles): front-to-back compositing,
   ``α = min(0.99, o exp(-½ dᵀ Σ'^-1 d))``, skip ``α < 1/255``, a pixel stops
   when ``T (1 - α) < 1e-4`` (that Gaussian is not added), then
   ``T · background`` is added. ``_blend_lanes`` updates 8 or 16 pixels of a
   tile row without branches so that LLVM vectorises it; for that, ``exp`` is
   a polynomial (``_exp_clamped``, absolute error < 3e-7 on ``[-5.6, 0]``;
   below -5.6, ``α < 1/255`` whatever the opacity). With ``save`` (for
   :func:`marionette.render.backward.render_with_grad`) the same kernel also
   keeps the per-pixel state of the backward pass, outside the vectorised
   lanes.

Conventions (OpenCV, see :mod:`marionette.camera`): pixel ``(x, y)`` is
evaluated at exactly ``(x, y)``, (0, 0) the centre of the top-left pixel, and a
Gaussian projects to ``K (X/Z, Y/Z, 1)``. The 1.3× clamp is written for any
principal point: ``X/Z`` lies in ``[-(cx + ½)/fx - 0.15 W/fx, (W - ½ - cx)/fx +
0.15 W/fx]``, which is the reference's ``±1.3 tan(fov_x / 2)`` when the
principal point is centred.

Each Gaussian touches only the pixels of its square 3σ box
``|x - u| <= r, |y - v| <= r`` (``r`` the radius above). The reference
rasterizer evaluates whole tiles instead; ``tests/reference_rasterizer.py``
uses the same square box so the two agree exactly. The box is further cut to
the bounding box of the ellipse ``dᵀ Σ'^-1 d <= 2 ln(255 o)`` (slightly
enlarged): outside it ``α < 1/255`` and the pixel would be skipped anyway, so
this is a pure speed-up that changes no result.

The parallel loops hand their items (chunks of Gaussians, tiles) to threads with
:func:`marionette.parallel.parallel_for`; every item writes its own outputs, so
the image does not depend on the thread count.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..parallel import CHUNK, chunks, parallel_for
from .sh import _eval_sh_one

__all__ = ["render", "RenderOutput"]

#: Tile side in pixels.
TILE = 16
#: Reference near plane: Gaussians with camera ``z <= NEAR`` are culled.
NEAR = 0.2
#: Reference low-pass filter added to the diagonal of the 2D covariance (px²).
LOW_PASS = 0.3
#: Parallel runs in ``_bin`` (a few per thread).
_BIN_RUNS = 8
#: Added to the alpha ellipse ``2 ln(255 o)`` so rounding never drops a pixel
#: that the ``α >= 1/255`` test would keep.
_ELLIPSE_MARGIN = 0.01

# Columns of the per-Gaussian parameter table built by ``_preprocess``.
_U, _V, _CA, _CB, _CC, _OPACITY, _R, _G, _B, _Z = range(10)
_NPARAM = 10

#: ``exp(x)`` for x in [_EXP_LO, 0] as a polynomial in ``s = 2 x / -_EXP_LO + 1`` in [-1, 1]
#: (coefficients of s^0 .. s^11): Chebyshev interpolation of degree 11, turned
#: into monomials. Evaluated in float32 its absolute error is below 3e-7
#: (``tests/test_rasterizer.py::test_exp_polynomial``). 0.99 exp(-5.6) < 1/255,
#: so clamping the exponent at -5.6 changes no kept alpha.
_EXP_LO = -5.6
_EXP_COEFFS = (0.06081004625171854, 0.17026817188351973, 0.23837662369895252,
               0.22248399862922671, 0.1557249198640588, 0.08721072638215376,
               0.040757803591588995, 0.01629219784471777, 0.0055872161390079595,
               0.0017491825369783476, 0.000592305233112711, 0.0001467872682117862)


@dataclass(frozen=True)
class RenderOutput:
    """A rendered view.

    Attributes
    ----------
    image : (H, W, 3) float32
        RGB composited over the background, clipped to [0, 1].
    alpha : (H, W) float32
        Opacity ``1 - T``, ``T`` the final transmittance.
    depth : (H, W) float32
        Expected camera-space ``z`` of the splats, ``Σ T_i α_i z_i / alpha``;
        0 where ``alpha == 0``.
    """

    image: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray


def render(gaussians: Gaussians, camera: Camera,
           background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> RenderOutput:
    """Render Gaussians seen by a camera.

    Parameters
    ----------
    gaussians : Gaussians
        N Gaussians (any SH degree 0 to 3).
    camera : Camera
        OpenCV pinhole camera; the image is ``camera.height × camera.width``.
    background : three floats in [0, 1]
        RGB behind the splats.

    Returns
    -------
    RenderOutput
        ``image (H, W, 3)``, ``alpha (H, W)`` and ``depth (H, W)``, float32.

    Raises
    ------
    InputError
        If an argument has the wrong type, the background is not three finite
        numbers in [0, 1], or the Gaussians hold NaN or infinite values.
    """
    if not isinstance(gaussians, Gaussians):
        raise InputError(f"render: gaussians must be a Gaussians, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise InputError(f"render: camera must be a Camera, got {type(camera).__name__}")
    bg = _check_background(background)
    return RenderOutput(*_rasterize(gaussians, camera, bg))


def _rasterize(gaussians: Gaussians, camera: Camera, background: np.ndarray,
               lap: Callable[[str], None] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pipeline behind :func:`render` on checked inputs: background (3,) float32 →
    image (H, W, 3), alpha (H, W), depth (H, W).

    ``lap(stage)``, if given, is called as each stage ends (the benchmark times
    them this way).
    """
    frame = _forward(gaussians, camera, background, lap)
    return frame.image, frame.alpha, frame.depth


@dataclass(frozen=True)
class _Frame:
    """Everything one pass of the pipeline makes (M visible Gaussians, P tile pairs).

    The last four are empty (0 × 0) unless asked for with ``save``: they are
    what the backward pass (:mod:`marionette.render.backward`) needs per pixel.
    """

    variances: np.ndarray   # (N, 3) float32, from _activations
    opacities: np.ndarray   # (N,) float32
    order: np.ndarray       # (M,) int32, row in depth order → Gaussian
    params: np.ndarray      # (M, 10) float32, front to back
    boxes: np.ndarray       # (M, 4) int32
    tile_start: np.ndarray  # (n_tiles + 1,) int64
    tile_ids: np.ndarray    # (P,) int32
    image: np.ndarray       # (H, W, 3) float32
    alpha: np.ndarray       # (H, W) float32
    depth: np.ndarray       # (H, W) float32
    t_final: np.ndarray     # (H, W) float32 final transmittance
    stop: np.ndarray        # (H, W) int32 tile-list position of the Gaussian that stopped the pixel, -1 if none
    row_last: np.ndarray    # (n_tiles, TILE) int32 last list position that visited a tile row, -1 if none
    unclipped: np.ndarray   # (H, W, 3) bool, the colour before clipping lies in [0, 1]


def _forward(gaussians: Gaussians, camera: Camera, background: np.ndarray,
             lap: Callable[[str], None] | None = None, save: bool = False) -> _Frame:
    """:func:`_rasterize`, returning every intermediate table; ``save`` also keeps the
    per-pixel state of the backward pass (see ``_blend``)."""
    lap = lap or (lambda stage: None)
    w, h = camera.width, camera.height
    variances, opacities, ellipse = _activations(gaussians.log_scales, gaussians.opacity_logits)
    params, boxes, depths, status = _preprocess(
        gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits,
        gaussians.sh, variances, opacities, ellipse, camera.world_to_camera, camera.K,
        camera.center, w, h)
    if np.any(status < 0):
        gaussians.check_finite()  # raises, naming the attribute
    lap("preprocess")
    order = _depth_order(depths, status)
    params, boxes = _gather(order, params, boxes)
    lap("sort")
    tile_start, tile_ids = _bin(boxes, w, h, _BIN_RUNS)
    lap("bin")
    out = _blend(tile_start, tile_ids, params, boxes, w, h, background, bool(save))
    lap("blend")
    return _Frame(variances, opacities, order, params, boxes, tile_start, tile_ids, *out)


def _check_background(background: object) -> np.ndarray:
    """Background → (3,) float32, or :class:`InputError`."""
    try:
        bg = np.asarray(background, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"render: background must be 3 numbers in [0, 1], got {background!r}") from None
    if bg.shape != (3,) or not np.all(np.isfinite(bg)) or np.any(bg < 0) or np.any(bg > 1):
        raise InputError(f"render: background must be 3 finite numbers in [0, 1], got {background!r}")
    return bg.astype(np.float32)


def _activations(log_scales: np.ndarray, opacity_logits: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transcendental per-Gaussian terms, in NumPy because its exp and log are
    SIMD-vectorised (numba calls libm one value at a time).

    log_scales (N, 3), opacity_logits (N,) float32 → variances (N, 3)
    ``exp(2 log_scales)``, opacities (N,) ``sigmoid(logits)`` and ellipse (N,)
    ``2 ln(255 o) + _ELLIPSE_MARGIN``, all float32. Overflows give inf
    variances or zero opacities (ellipse -inf), which ``_preprocess`` culls.
    """
    with np.errstate(over="ignore", divide="ignore"):
        variances = np.exp(np.float32(2.0) * log_scales)
        opacities = np.float32(1.0) / (np.float32(1.0) + np.exp(-opacity_logits))
        ellipse = np.float32(2.0) * np.log(np.float32(255.0) * opacities) + np.float32(_ELLIPSE_MARGIN)
    return variances, opacities, ellipse


def _depth_order(depths: np.ndarray, status: np.ndarray) -> np.ndarray:
    """Visible Gaussians sorted by (depth, index): depths (N,) float32, status (N,) int8 → (M,) int32.

    Depths are > 0, so their float32 bit patterns sort like the values; packing
    ``bits << 32 | index`` into one uint64 key makes a plain sort stable.
    """
    idx = np.flatnonzero(status == 1).astype(np.uint64)
    keys = (depths.view(np.uint32)[idx].astype(np.uint64) << np.uint64(32)) | idx
    keys.sort()
    return (keys & np.uint64(0xFFFFFFFF)).astype(np.int32)


@numba.njit(cache=True, error_model="numpy")
def _preprocess_range(lo, hi, means, quats, log_scales, opacity_logits, sh, variances, opacities, ellipse,
                      view, K, campos, width, height, params, boxes, depths, status):
    """``_preprocess`` for Gaussians ``lo .. hi - 1``, written into its outputs."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lims = _direction_limits(K, width, height)
    w00, w01, w02, w03 = view[0, 0], view[0, 1], view[0, 2], view[0, 3]
    w10, w11, w12, w13 = view[1, 0], view[1, 1], view[1, 2], view[1, 3]
    w20, w21, w22, w23 = view[2, 0], view[2, 1], view[2, 2], view[2, 3]
    for i in range(lo, hi):
        # 0 * x is NaN exactly when x is NaN or infinite.
        zero = np.float32(0.0)
        nan = (zero * opacity_logits[i] + zero * means[i, 0] + zero * means[i, 1]
               + zero * means[i, 2] + zero * log_scales[i, 0] + zero * log_scales[i, 1]
               + zero * log_scales[i, 2] + zero * quats[i, 0] + zero * quats[i, 1]
               + zero * quats[i, 2] + zero * quats[i, 3])
        mx, my, mz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
        tx = w00 * mx + w01 * my + w02 * mz + w03
        ty = w10 * mx + w11 * my + w12 * mz + w13
        tz = w20 * mx + w21 * my + w22 * mz + w23
        itz = 1.0 / max(tz, NEAR)  # culled below the near plane; this only keeps values finite
        sigma = _world_covariance(_rotation(quats, i)[2], variances, i)
        xz, yz = tx * itz, ty * itz
        a, b, c = _screen_covariance(view, fx, fy, lims, xz, yz, itz, sigma)[-3:]
        det = a * c - b * b
        mid = 0.5 * (a + c)
        radius = math.ceil(3.0 * math.sqrt(mid + math.sqrt(max(0.1, mid * mid - det))))
        q = np.float64(ellipse[i])
        u, v = fx * xz + cx, fy * yz + cy
        # Half-sizes of the box: the alpha ellipse's bounding box, within the 3σ square.
        ex = min(math.sqrt(max(q * a, 0.0)), radius)
        ey = min(math.sqrt(max(q * c, 0.0)), radius)
        # Clip in float before converting, so far-off Gaussians cannot overflow int32.
        x0 = max(math.ceil(min(max(u - ex, -1.0), width)), 0)
        x1 = min(math.floor(max(min(u + ex, width), -1.0)), width - 1)
        y0 = max(math.ceil(min(max(v - ey, -1.0), height)), 0)
        y1 = min(math.floor(max(min(v + ey, height), -1.0)), height - 1)
        # det < inf rejects overflowing scales; ellipse <= margin means opacity <= 1/255,
        # where every alpha would be skipped.
        visible = ((tz > NEAR) & (det > 0.0) & (det < np.inf) & (q > _ELLIPSE_MARGIN)
                   & (x0 <= x1) & (y0 <= y1))
        dx, dy, dz = mx - campos[0], my - campos[1], mz - campos[2]
        inv = 1.0 / math.sqrt(max(dx * dx + dy * dy + dz * dz, 1e-300))
        red, green, blue = _eval_sh_one(sh, i, dx * inv, dy * inv, dz * inv)
        # A non-finite SH coefficient makes its channel's sum NaN or inf.
        nan += zero * red + zero * green + zero * blue
        status[i] = -1 if nan != zero else (1 if visible else 0)
        idet = 1.0 / det
        params[i, _U] = u
        params[i, _V] = v
        params[i, _CA] = c * idet
        params[i, _CB] = -b * idet
        params[i, _CC] = a * idet
        params[i, _OPACITY] = opacities[i]
        params[i, _R], params[i, _G], params[i, _B] = red, green, blue
        params[i, _Z] = tz
        boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3] = x0, x1, y0, y1
        depths[i] = tz


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _preprocess_chunks(first, step, nchunks, means, quats, log_scales, opacity_logits, sh, variances, opacities,
                       ellipse, view, K, campos, width, height, params, boxes, depths, status):
    """Chunks ``first, first + step, ...`` of ``CHUNK`` Gaussians of ``_preprocess`` (one thread's share)."""
    n = means.shape[0]
    for chunk in range(first, nchunks, step):
        _preprocess_range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK), means, quats, log_scales,
                          opacity_logits, sh, variances, opacities, ellipse, view, K, campos, width, height,
                          params, boxes, depths, status)


def _preprocess(means, quats, log_scales, opacity_logits, sh, variances, opacities, ellipse,
                view, K, campos, width, height):
    """Project Gaussians to screen space, without branches (culling is a flag).

    Colours are evaluated for all Gaussians: streaming through ``sh`` in order
    is far cheaper than fetching the visible ones' rows in depth order.

    Parameters
    ----------
    means (N, 3), quats (N, 4), log_scales (N, 3), opacity_logits (N,), sh (N, C, 3) : float32
        The Gaussians; scales and logits are only checked for finiteness here.
    variances (N, 3), opacities (N,), ellipse (N,) : float32
        From ``_activations``.
    view : (4, 4) float64 world-to-camera; K : (3, 3) float64; campos : (3,) float64
    width, height : int

    Returns
    -------
    params : (N, 10) float32
        ``u, v, conic_a, conic_b, conic_c, opacity, r, g, b, z`` with
        ``power = -½ (a dx² + c dy²) - b dx dy``.
    boxes : (N, 4) int32
        Inclusive pixel box ``x0, x1, y0, y1``: the square 3σ box cut to the
        image and to the alpha ellipse.
    depths : (N,) float32
        Camera-space z.
    status : (N,) int8
        1 visible, 0 culled, -1 non-finite input.
    """
    n = means.shape[0]
    params = np.empty((n, _NPARAM), np.float32)
    boxes = np.empty((n, 4), np.int32)
    depths = np.empty(n, np.float32)
    status = np.empty(n, np.int8)
    parallel_for(_preprocess_chunks, chunks(n), means, quats, log_scales, opacity_logits, sh,
                 variances, opacities, ellipse, view, K, campos, width, height, params, boxes, depths, status)
    return params, boxes, depths, status


@numba.njit(cache=True)
def _direction_limits(K, width, height):
    """Clamp of ``x/z`` and ``y/z`` in the perspective Jacobian: 1.3× the half field of view, for
    any principal point → ``(x0, x1, y0, y1)``."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return (-(cx + 0.5) / fx - 0.15 * width / fx, (width - 0.5 - cx) / fx + 0.15 * width / fx,
            -(cy + 0.5) / fy - 0.15 * height / fy, (height - 0.5 - cy) / fy + 0.15 * height / fy)


@numba.njit(cache=True)
def _rotation(quats, i):
    """Quaternion ``i`` of quats (N, 4) ``w, x, y, z``, normalised, in float64 → ``(w, x, y, z)``,
    ``1 / |q|`` and the rotation matrix's rows ``(r00, r01, r02), (r10, ...), (r20, ...)``.

    A zero quaternion gives the identity, as in the reference (its
    normalisation leaves zeros, which the matrix formula turns into the
    identity); ``1 / |q|`` is then 0.
    """
    w, x, y, z = (np.float64(quats[i, 0]), np.float64(quats[i, 1]), np.float64(quats[i, 2]),
                  np.float64(quats[i, 3]))
    norm2 = w * w + x * x + y * y + z * z
    inv = 1.0 / math.sqrt(norm2) if norm2 > 0.0 else 0.0
    w, x, y, z = w * inv, x * inv, y * inv, z * inv
    return ((w, x, y, z), inv,
            ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
             (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
             (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))))


@numba.njit(cache=True)
def _world_covariance(rows, variances, i):
    """Σ = R S Sᵀ Rᵀ of Gaussian ``i`` from the rows of its rotation ``R`` (:func:`_rotation`) and
    variances (N, 3) (``S²``) → its upper triangle ``(s00, s01, s02, s11, s12, s22)`` in float64."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
    v0, v1, v2 = np.float64(variances[i, 0]), np.float64(variances[i, 1]), np.float64(variances[i, 2])
    return (r00 * r00 * v0 + r01 * r01 * v1 + r02 * r02 * v2,
            r00 * r10 * v0 + r01 * r11 * v1 + r02 * r12 * v2,
            r00 * r20 * v0 + r01 * r21 * v1 + r02 * r22 * v2,
            r10 * r10 * v0 + r11 * r11 * v1 + r12 * r12 * v2,
            r10 * r20 * v0 + r11 * r21 * v1 + r12 * r22 * v2,
            r20 * r20 * v0 + r21 * r21 * v1 + r22 * r22 * v2)


@numba.njit(cache=True)
def _screen_covariance(view, fx, fy, lims, xz, yz, itz, sigma):
    """EWA projection of a world covariance: ``Σ' = T Σ Tᵀ + low-pass``, ``T = J W`` (2 × 3), ``J``
    the perspective Jacobian at the direction ``(xz, yz) = (t_x / t_z, t_y / t_z)`` clamped to
    ``lims`` (:func:`_direction_limits`), ``itz = 1 / t_z``, ``sigma`` the upper triangle of ``Σ``.

    Returns the clamped direction ``(cxz, cyz)``, the rows ``p``, ``q`` of ``T``, ``Σ p``,
    ``Σ q`` and ``a, b, c``: ``Σ' = [[a, b], [b, c]]``, all float64.
    """
    s00, s01, s02, s11, s12, s22 = sigma
    w00, w01, w02 = view[0, 0], view[0, 1], view[0, 2]
    w10, w11, w12 = view[1, 0], view[1, 1], view[1, 2]
    w20, w21, w22 = view[2, 0], view[2, 1], view[2, 2]
    cxz, cyz = min(max(xz, lims[0]), lims[1]), min(max(yz, lims[2]), lims[3])
    j00, j11 = fx * itz, fy * itz
    j02, j12 = -j00 * cxz, -j11 * cyz
    p = (j00 * w00 + j02 * w20, j00 * w01 + j02 * w21, j00 * w02 + j02 * w22)
    q = (j11 * w10 + j12 * w20, j11 * w11 + j12 * w21, j11 * w12 + j12 * w22)
    sp = (s00 * p[0] + s01 * p[1] + s02 * p[2], s01 * p[0] + s11 * p[1] + s12 * p[2],
          s02 * p[0] + s12 * p[1] + s22 * p[2])
    sq = (s00 * q[0] + s01 * q[1] + s02 * q[2], s01 * q[0] + s11 * q[1] + s12 * q[2],
          s02 * q[0] + s12 * q[1] + s22 * q[2])
    return ((cxz, cyz), p, q, sp, sq,
            p[0] * sp[0] + p[1] * sp[1] + p[2] * sp[2] + LOW_PASS,
            q[0] * sp[0] + q[1] * sp[1] + q[2] * sp[2],
            q[0] * sq[0] + q[1] * sq[1] + q[2] * sq[2] + LOW_PASS)


@numba.njit(nogil=True, cache=True)
def _gather_chunks(first, step, nchunks, order, params, boxes, params_out, boxes_out):
    """Chunks ``first, first + step, ...`` of ``CHUNK`` rows of ``_gather`` (one thread's share). Element
    loops: a row slice would bump a reference count shared by all threads."""
    m = order.shape[0]
    for chunk in range(first, nchunks, step):
        for i in range(chunk * CHUNK, min(m, (chunk + 1) * CHUNK)):
            g = order[i]
            for k in range(_NPARAM):
                params_out[i, k] = params[g, k]
            for k in range(4):
                boxes_out[i, k] = boxes[g, k]


def _gather(order, params, boxes):
    """Rows of params (N, 10) float32 and boxes (N, 4) int32 picked by order (M,) int32 →
    (M, 10), (M, 4): one pass of scattered reads, after which ``_bin`` reads
    sequentially and each tile's list walks memory forwards."""
    m = order.shape[0]
    params_out = np.empty((m, _NPARAM), np.float32)
    boxes_out = np.empty((m, 4), np.int32)
    parallel_for(_gather_chunks, chunks(m), order, params, boxes, params_out, boxes_out)
    return params_out, boxes_out


@numba.njit(nogil=True, cache=True)
def _bin_count(first, step, nruns, boxes, ntx, counts):
    """Runs ``first, first + step, ...`` of ``_bin``: count each run's hits per tile into counts (nruns, n_tiles)."""
    m = boxes.shape[0]
    for run in range(first, nruns, step):
        for g in range(run * m // nruns, (run + 1) * m // nruns):
            for ty in range(boxes[g, 2] // TILE, boxes[g, 3] // TILE + 1):
                for tx in range(boxes[g, 0] // TILE, boxes[g, 1] // TILE + 1):
                    counts[run, ty * ntx + tx] += 1


@numba.njit(cache=True)
def _bin_offsets(counts):
    """Prefix sum of counts (nruns, n_tiles) in (tile, run) order: each run's first slot per tile
    (nruns, n_tiles) and each tile's first slot (n_tiles + 1,), both int64."""
    nruns, ntiles = counts.shape
    cursor = np.empty((nruns, ntiles), np.int64)
    tile_start = np.empty(ntiles + 1, np.int64)
    total = 0
    for t in range(ntiles):
        tile_start[t] = total
        for run in range(nruns):
            cursor[run, t] = total
            total += counts[run, t]
    tile_start[ntiles] = total
    return cursor, tile_start


@numba.njit(nogil=True, cache=True)
def _bin_fill(first, step, nruns, boxes, ntx, cursor, tile_ids):
    """Runs ``first, first + step, ...`` of ``_bin``: write each run's rows into its slots, advancing cursor."""
    m = boxes.shape[0]
    for run in range(first, nruns, step):
        for g in range(run * m // nruns, (run + 1) * m // nruns):
            for ty in range(boxes[g, 2] // TILE, boxes[g, 3] // TILE + 1):
                for tx in range(boxes[g, 0] // TILE, boxes[g, 1] // TILE + 1):
                    t = ty * ntx + tx
                    tile_ids[cursor[run, t]] = g
                    cursor[run, t] += 1


def _bin(boxes, width, height, nruns):
    """Per-tile lists of Gaussians, each front to back.

    Counting sort: the depth-sorted Gaussians are cut into ``nruns`` runs that
    count their tile hits in parallel; a prefix sum over (tile, run) gives
    every run its own slot range per tile, so filling is parallel too and the
    lists stay sorted.

    Parameters
    ----------
    boxes : (M, 4) int32
        Pixel boxes ``x0, x1, y0, y1`` of the visible Gaussians, front to back.
    width, height, nruns : int

    Returns
    -------
    tile_start : (n_tiles + 1,) int64
        Tile ``t`` (row-major, ``ceil(W / 16)`` per row) owns
        ``tile_ids[tile_start[t]:tile_start[t + 1]]``.
    tile_ids : (P,) int32
        Rows of ``boxes``; P is the number of (Gaussian, tile) pairs.
    """
    ntx = (width + TILE - 1) // TILE
    ntiles = ntx * ((height + TILE - 1) // TILE)
    counts = np.zeros((nruns, ntiles), np.int64)
    parallel_for(_bin_count, nruns, boxes, ntx, counts)
    cursor, tile_start = _bin_offsets(counts)
    tile_ids = np.empty(tile_start[ntiles], np.int32)
    parallel_for(_bin_fill, nruns, boxes, ntx, cursor, tile_ids)
    return tile_start, tile_ids


@numba.njit(cache=True, inline="always")
def _exp_clamped(x):
    """``exp(max(x, _EXP_LO))`` for float32 ``x <= 0`` (scalar or array), by the polynomial
    ``_EXP_COEFFS``, so that loops calling it vectorise."""
    f32 = np.float32
    s = np.maximum(x, f32(_EXP_LO)) * f32(-2.0 / _EXP_LO) + f32(1.0)  # [-5.6, 0] → [-1, 1]
    c = _EXP_COEFFS
    # Estrin's scheme: a dependency chain 4 deep instead of Horner's 11.
    s2 = s * s
    s4 = s2 * s2
    return (((f32(c[0]) + f32(c[1]) * s) + s2 * (f32(c[2]) + f32(c[3]) * s))
            + s4 * ((f32(c[4]) + f32(c[5]) * s) + s2 * (f32(c[6]) + f32(c[7]) * s))
            + s4 * s4 * ((f32(c[8]) + f32(c[9]) * s) + s2 * (f32(c[10]) + f32(c[11]) * s)))


@numba.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _blend_lanes(state, base, j0, nlanes, du, a2, b1, c0, xlo, xhi, opacity, red, green, blue, z):
    """Composite one Gaussian onto lanes ``j0 .. j0 + nlanes - 1`` of one tile row.

    Branch-free so that it vectorises. ``state`` (5 · 256,) float32 holds the
    tile's planes T (negated once stopped), R, G, B, Σ w z; ``base`` (uint64) is
    the row's offset; ``dx = lane + du``; ``power = (a2 dx + b1) dx + c0``; the
    box spans lanes ``xlo .. xhi``. Returns the number of pixels that stopped.
    """
    f32 = np.float32
    zero, one = f32(0.0), f32(1.0)
    min_alpha, max_alpha, min_t = f32(1.0 / 255.0), f32(0.99), f32(1e-4)
    # uint64 offsets (uint64 * int64 would be float64 in numba), written here as
    # constants so LLVM proves the planes disjoint.
    p_r, p_g, p_b, p_z = (np.uint64(TILE * TILE), np.uint64(2 * TILE * TILE),
                          np.uint64(3 * TILE * TILE), np.uint64(4 * TILE * TILE))
    stopped = 0
    for jj in range(nlanes):
        j = j0 + jj
        lane = f32(j)
        dx = lane + du
        power = (a2 * dx + b1) * dx + c0
        alpha = min(max_alpha, opacity * _exp_clamped(power))
        i = base + np.uint64(j)
        tr = state[i]
        use = (lane >= xlo) & (lane <= xhi) & (tr > zero) & (power <= zero) & (alpha >= min_alpha)
        test_t = tr * (one - alpha)
        stop = use & (test_t < min_t)
        add = use & (test_t >= min_t)
        w = alpha * tr if add else zero
        state[i + p_r] += w * red
        state[i + p_g] += w * green
        state[i + p_b] += w * blue
        state[i + p_z] += w * z
        state[i] = test_t if add else (-tr if stop else tr)
        stopped += stop
    return stopped


@numba.njit(cache=True, inline="always")
def _tile_origin(t, ntx, width, height):
    """Tile ``t`` (row-major, ``ntx`` per row) → its first pixel ``xs, ys`` and its size ``tw, th``."""
    xs, ys = (t % ntx) * TILE, (t // ntx) * TILE
    return xs, ys, min(TILE, width - xs), min(TILE, height - ys)


@numba.njit(cache=True, inline="always")
def _splat(params, boxes, g, xs, ys, tw, th):
    """Row ``g`` of the Gaussian tables as one tile (first pixel ``xs, ys``, size ``tw × th``) sees it.

    Returns ``bx0, bx1, by0, by1`` (the box in tile coordinates, inclusive),
    ``du`` (``dx = lane + du``), ``xlo, xhi`` (``bx0, bx1`` as float32) and
    ``a2 = -½ conic_a``, the terms of ``_blend_lanes`` that do not depend on the row.
    """
    f32 = np.float32
    bx0, bx1 = max(boxes[g, 0] - xs, 0), min(boxes[g, 1] - xs, tw - 1)
    by0, by1 = max(boxes[g, 2] - ys, 0), min(boxes[g, 3] - ys, th - 1)
    du = f32(xs) - params[g, _U]
    return bx0, bx1, by0, by1, du, f32(bx0), f32(bx1), -f32(0.5) * params[g, _CA]


@numba.njit(cache=True, inline="always")
def _splat_row(params, g, ys, ly):
    """Tile row ``ly``'s terms of ``power = (a2 dx + b1) dx + c0`` for row ``g``: ``dy, b1, c0``.

    ``power = -½ (a dx² + c dy²) - b dx dy`` with ``(a, b, c)`` the conic.
    """
    f32 = np.float32
    dy = f32(ys + ly) - params[g, _V]
    return dy, -params[g, _CB] * dy, -f32(0.5) * params[g, _CC] * dy * dy


@numba.njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def _blend_tiles(first, step, ntiles, ntx, tile_start, tile_ids, params, boxes, width, height, background, save,
                 image, alpha_out, depth_out, t_final, stop_out, row_last, unclipped):
    """Tiles ``first, first + step, ...`` of ``_blend`` (one thread's share), each written into its pixels of
    the outputs."""
    f32 = np.float32
    zero, one = f32(0.0), f32(1.0)
    for t in range(first, ntiles, step):
        xs, ys, tw, th = _tile_origin(t, ntx, width, height)
        state = np.zeros(5 * TILE * TILE, np.float32)
        state[:TILE * TILE] = one
        stop = np.full(TILE * TILE if save else 0, -1, np.int32)
        row_done = np.zeros(TILE, np.int64)
        ndone = 0
        for k in range(tile_start[t], tile_start[t + 1]):
            g = tile_ids[k]
            bx0, bx1, by0, by1, du, xlo, xhi, a2 = _splat(params, boxes, g, xs, ys, tw, th)
            opacity, z = params[g, _OPACITY], params[g, _Z]
            red, green, blue = params[g, _R], params[g, _G], params[g, _B]
            for ly in range(by0, by1 + 1):
                if row_done[ly] == tw:
                    continue
                dy, b1, c0 = _splat_row(params, g, ys, ly)
                base = np.uint64(ly * TILE)
                # The 8 lanes of the aligned half holding the box, or all 16: fixed trip
                # counts, which LLVM turns into one or two 8-wide vector iterations.
                h0 = bx0 - bx0 % 8
                if bx1 < h0 + 8:
                    nd = _blend_lanes(state, base, h0, 8, du, a2, b1, c0, xlo, xhi, opacity,
                                      red, green, blue, z)
                else:
                    nd = _blend_lanes(state, base, 0, TILE, du, a2, b1, c0, xlo, xhi, opacity,
                                      red, green, blue, z)
                row_done[ly] += nd
                ndone += nd
                if save:
                    row_last[t, ly] = k
                    if nd > 0:
                        for lx in range(bx0, bx1 + 1):
                            p = ly * TILE + lx
                            if state[p] < zero and stop[p] < 0:
                                stop[p] = k
            if ndone == tw * th:
                break
        planes = state.reshape(5, TILE, TILE)
        for ly in range(th):
            for lx in range(tw):
                tr = abs(planes[0, ly, lx])
                y, x = ys + ly, xs + lx
                for ch in range(3):
                    raw = planes[1 + ch, ly, lx] + tr * background[ch]
                    image[y, x, ch] = min(max(raw, zero), one)
                    if save:
                        unclipped[y, x, ch] = (raw >= zero) & (raw <= one)
                a = one - tr
                alpha_out[y, x] = a
                depth_out[y, x] = planes[4, ly, lx] / a if a > zero else zero
                if save:
                    t_final[y, x] = tr
                    stop_out[y, x] = stop[ly * TILE + lx]


# ``contract`` only lets LLVM fuse a * b + c into one FMA (one rounding instead
# of two); no other fast-math licence is taken.
def _blend(tile_start, tile_ids, params, boxes, width, height, background, save):
    """Front-to-back compositing, parallel over tiles.

    A tile keeps its state in one flat float32 array of five 16×16 planes:
    transmittance ``T`` (stored negated once the pixel has stopped), R, G, B
    and ``Σ w z``. One buffer and unsigned indices let LLVM vectorise
    ``_blend_lanes`` without aliasing checks or negative-index fix-ups. Each
    row of a Gaussian's box is composited 8 or 16 pixels at a time; a row
    whose pixels have all stopped is skipped, and the tile ends when all its
    pixels have.

    With ``save``, it also keeps what the backward pass needs, outside the
    vectorised lanes so that the plain forward pays only a test per row: per
    pixel the final transmittance, the colour's clip mask and the Gaussian that
    stopped it (found, when ``_blend_lanes`` reports stops, as the pixels of the
    row whose ``T`` turned negative), and per tile row the last Gaussian that
    visited it while some of its pixels were live. Gaussian ``k`` of a tile's
    list was added to a pixel exactly when it is before the pixel's stop and
    passes the tests of ``_blend_lanes``, which the backward pass repeats.

    Parameters
    ----------
    tile_start : (n_tiles + 1,) int64; tile_ids : (P,) int32
        From ``_bin``.
    params : (M, 10) float32; boxes : (M, 4) int32
        The visible Gaussians' rows, front to back (``_gather``).
    width, height : int
    background : (3,) float32
    save : bool
        A runtime test rather than a pruned branch, so that the plain and the
        saving forward share one compiled kernel (each costs seconds to compile;
        the test costs nothing measurable, ``benchmarks/bench_rasterizer.py``).

    Returns
    -------
    image : (H, W, 3) float32; alpha : (H, W) float32; depth : (H, W) float32
    t_final : (H, W) float32
        Final transmittance ``T_N``.
    stop : (H, W) int32
        Position in ``tile_ids`` of the Gaussian that stopped the pixel (-1 if none).
    row_last : (n_tiles, TILE) int32
        Last position in ``tile_ids`` whose Gaussian visited the tile row while
        it had live pixels (-1 if none).
    unclipped : (H, W, 3) bool
        The colour before clipping lies in [0, 1].

    The last four are empty (0 × 0) unless ``save``.
    """
    ntx = (width + TILE - 1) // TILE
    ntiles = ntx * ((height + TILE - 1) // TILE)
    image = np.empty((height, width, 3), np.float32)
    alpha_out = np.empty((height, width), np.float32)
    depth_out = np.empty((height, width), np.float32)
    sh, sw, st = (height, width, ntiles) if save else (0, 0, 0)
    t_final = np.empty((sh, sw), np.float32)
    stop_out = np.empty((sh, sw), np.int32)
    row_last = np.full((st, TILE), -1, np.int32)
    unclipped = np.empty((sh, sw, 3), np.bool_)
    parallel_for(_blend_tiles, ntiles, ntx, tile_start, tile_ids, params, boxes, width, height, background, save,
              image, alpha_out, depth_out, t_final, stop_out, row_last, unclipped)
    return image, alpha_out, depth_out, t_final, stop_out, row_last, unclipped
