"""Gradients of the CPU Gaussian rasterizer: the backward pass of :func:`marionette.render.render`.

Follows the backward pass of the reference 3D Gaussian Splatting rasterizer
(Kerbl et al., SIGGRAPH 2023, ``cuda_rasterizer/backward.cu``) and its
organisation in gsplat (Ye et al., "gsplat: An Open-Source Library for Gaussian
Splatting", 2024, ``rasterize_to_pixels`` / ``fully_fused_projection``), on
exactly the forward rules of :mod:`marionette.render.rasterizer` (0.3 px
low-pass, square 3σ box, ``α = min(0.99, o e^power)``, skip ``α < 1/255``,
stop when ``T (1 - α) < 1e-4``, near plane 0.2, the 1.3× clamp of the
Jacobian, colours ``max(SH + 0.5, 0)``, the image clipped to [0, 1]).

1. The forward is :func:`render`'s own (``_forward`` with ``save``, so the
   image is the same to the bit): ``_blend`` also keeps per pixel the final
   transmittance ``T_N``, the tile-list position of the Gaussian that stopped
   the pixel (gsplat's ``render_alphas`` / ``last_ids``, one position later)
   and which channels were not clipped, and per tile row the last Gaussian
   that visited it.
2. ``_blend_backward`` (parallel over tiles): each tile walks its list back to
   front from the last Gaussian that visited its rows, rebuilding ``T_i = T_{i+1} / (1 - α_i)``
   and the colour behind, ``S_i = Σ_{j>i} c_j α_j T_j + T_N bg``:

   - ``∂C/∂c_i = α_i T_i``;
   - ``∂C/∂α_i = c_i T_i - S_i / (1 - α_i)``; ``∂A/∂α_i = T_N / (1 - α_i)``
     for the alpha image ``A = 1 - T_N``;
   - ``∂α/∂o = e``, ``∂α/∂power = α`` (zero where the 0.99 clamp holds);
   - ``power = -½ (a dx² + c dy²) - b dx dy`` with ``d = pixel - (u, v)``.

   Every (Gaussian, tile) pair gets its own row of 9 partial sums (``u, v``,
   conic ``a, b, c``, opacity, ``r, g, b``), stored in the Gaussian's own
   contiguous run of rows (``_pair_start``: one row per tile of its box, in
   tile order); nothing is summed across threads, so the result does not
   depend on the thread count.
3. ``_project_backward`` (parallel over Gaussians): sums each Gaussian's rows
   in float64, in tile order, then goes back through the conic
   ``Σ'^-1``, ``Σ' = T Σ Tᵀ + 0.3 I`` with ``T = J W``, the perspective
   Jacobian (with its clamp), the projection of the mean, ``Σ = R S² Rᵀ``, the
   normalised quaternion, the sigmoid and the SH colours (degree 0 to 3,
   including the dependence of the viewing direction on the mean), and the
   per-Gaussian share of a rigid-pose gradient.

**Rigid pose.** A twist ``ξ = [ω, v]`` acting on a group of Gaussians about a
pivot ``p`` moves them to ``μ' = exp(ω^) (μ - p) + p + v`` and turns them by
``q' = q_ω ⊗ q`` (``Σ' = R Σ Rᵀ``). The turn of SH coefficients beyond degree 0
(:meth:`Gaussians.turned` turns them too) is left out: exact for the degree-0
colours the pose fits use. The gradient is taken at ``ξ = 0``, where every
parameterisation of SE(3) with this tangent (``exp`` of the twist, or rotation
and translation separately) gives the same derivative::

    ∂L/∂v = sum_i ∂L/∂μ_i
    ∂L/∂ω = sum_i [(μ_i - p) × ∂L/∂μ_i + 2 vex(Σ_i G_i)],   G_i = ∂L/∂Σ_i,
    vex(A) = (A₂₃ - A₃₂, A₃₁ - A₁₃, A₁₂ - A₂₁)

(``Σ_i`` the world covariance, ``G_i`` symmetric, 1-based indices.) It is the first-order change of the
loss under a small left-multiplied pose update of the group, which is what a
Gauss-Newton or gradient step on the group's pose needs.

**Exp.** The forward computes ``e^power`` with the polynomial
``_exp_clamped`` (absolute error < 3e-7 on [-5.6, 0]); the backward
recomputes alphas with the same polynomial, so its skip decisions and
``1 - α`` factors are those of the forward, and uses ``∂α/∂power = α``, the
derivative of the true exponential: it differs from the polynomial's own
derivative by less than 1e-5 relative, far below float32 summation noise.

**Clamps.** Where a clamp holds (``o e > 0.99``, a colour channel below 0, the
image outside [0, 1], ``x/z`` or ``y/z`` beyond the Jacobian's limit) the
gradient through it is zero, as for ``torch.clamp``; the reference 3DGS backward
ignores the 0.99 clamp, gsplat does not. The box, the radius and the skip and
stop decisions are piecewise constant and carry no gradient.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..parallel import CHUNK, chunks, parallel_for
from .rasterizer import (
    _B,
    _CA,
    _CB,
    _CC,
    _G,
    _OPACITY,
    _R,
    TILE,
    RenderOutput,
    _check_background,
    _direction_limits,
    _exp_clamped,
    _forward,
    _Frame,
    _rotation,
    _screen_covariance,
    _splat,
    _splat_row,
    _tile_origin,
    _world_covariance,
)
from .sh import SH_C0, SH_C1, SH_C2, SH_C3

__all__ = ["render_with_grad", "RenderWithGrad", "RenderGradients"]

# Columns of the per-(Gaussian, tile) and per-Gaussian 2D gradient tables.
_GU, _GV, _GA, _GB, _GC, _GO, _GR, _GG, _GBL = range(9)
_NGRAD = 9
# Planes of the backward tile state (each TILE × TILE float32).
_NPLANE_BWD = 9


@dataclass(frozen=True)
class RenderGradients:
    """Gradients of a scalar loss with respect to the Gaussians (and a rigid pose).

    Attributes
    ----------
    means : (N, 3) float32
    quats : (N, 4) float32
        With respect to the stored (unnormalised) quaternions ``w, x, y, z``;
        orthogonal to them, since the renderer normalises.
    log_scales : (N, 3) float32
    opacity_logits : (N,) float32
    sh : (N, C, 3) float32
    pose : (6,) or (P, 6) float64, or None
        ``[∂L/∂ω, ∂L/∂v]`` of each group's twist (see the module docstring);
        None when no group was given.
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    pose: np.ndarray | None = None


@dataclass(frozen=True)
class _Saved:
    """What the backward pass needs from the forward."""

    gaussians: Gaussians
    camera: Camera
    background: np.ndarray  # (3,) float32
    frame: _Frame           # the forward's tables, with its per-pixel state (save=True)
    pair_start: np.ndarray  # (N + 1,) int64, see _pair_start


class RenderWithGrad:
    """A rendered view that can return gradients: :attr:`output` and :meth:`backward`.

    Made by :func:`render_with_grad`; keeps per pixel only the final
    transmittance, the stopping Gaussian's index and the clip mask, plus the
    forward's sorted tables (a few tens of bytes per Gaussian).
    """

    def __init__(self, output: RenderOutput, saved: _Saved) -> None:
        self.output = output
        self._saved = saved

    def backward(self, grad_image: np.ndarray, grad_alpha: np.ndarray | None = None, *,
                 groups: np.ndarray | Sequence[np.ndarray] | None = None,
                 pivot: np.ndarray | None = None) -> RenderGradients:
        """Gradients of a loss ``L`` given its gradients with respect to the rendered images.

        Parameters
        ----------
        grad_image : (H, W, 3) array
            ``∂L/∂image``. Where the image was clipped to 0 or 1 the gradient
            does not pass.
        grad_alpha : (H, W) array, optional
            ``∂L/∂alpha`` (e.g. for a mask loss). The depth image has no gradient.
        groups : (N,) bool mask or (K,) index array, or a sequence of P of them, optional
            Gaussians moved together by a rigid pose: the result's ``pose`` is the
            gradient of their twist, (6,) for one group, (P, 6) for a sequence.
        pivot : (3,) or (P, 3) array, optional
            Centre of each group's rotation (world frame); the origin by default.

        Returns
        -------
        RenderGradients
        """
        s = self._saved
        h, w = s.camera.height, s.camera.width
        g_img = _check_grad(grad_image, (h, w, 3), "grad_image")
        g_a = np.zeros((h, w), np.float32) if grad_alpha is None else _check_grad(grad_alpha, (h, w), "grad_alpha")
        n = len(s.gaussians)
        masks = _group_masks(groups, n)
        pivots = None
        if masks is not None:
            pivots = np.zeros((len(masks), 3))
            if pivot is not None:
                pv = np.asarray(pivot, dtype=np.float64)
                if pv.shape not in ((3,), (len(masks), 3)) or not np.all(np.isfinite(pv)):
                    raise InputError(f"backward: pivot must be finite with shape (3,) or ({len(masks)}, 3), "
                                     f"got {pv.shape}")
                pivots[:] = pv
        gs = s.gaussians
        nc = gs.sh.shape[1]
        grads = RenderGradients(np.empty((n, 3), np.float32), np.empty((n, 4), np.float32),
                                np.empty((n, 3), np.float32), np.empty(n, np.float32), np.empty((n, nc, 3), np.float32))
        f = s.frame
        g_img = np.where(f.unclipped, g_img, np.float32(0.0))

        pair = _scratch("pair", (len(f.tile_ids), _NGRAD), np.float32)
        _zero_rows(pair)
        _blend_backward(f.tile_start, f.tile_ids, f.params, f.boxes, w, h, s.background,
                        f.t_final, f.stop, f.row_last, g_img, g_a, f.order, s.pair_start, pair)
        cam = s.camera
        contrib = _scratch("contrib", (n if masks is not None else 0, 6), np.float64)
        _project_backward(gs.means, gs.quats, f.variances, f.opacities, gs.sh, cam.world_to_camera, cam.K,
                          cam.center, w, h, pair, s.pair_start, masks is not None, grads.means, grads.quats,
                          grads.log_scales, grads.opacity_logits, grads.sh, contrib)
        pose = None
        if masks is not None:
            pose = np.empty((len(masks), 6))
            for k, m in enumerate(masks):
                part = _masked_sum(contrib, m)
                pose[k, :3] = part[:3] - np.cross(pivots[k], part[3:])
                pose[k, 3:] = part[3:]
            if not isinstance(groups, (list, tuple)):
                pose = pose[0]
        return RenderGradients(grads.means, grads.quats, grads.log_scales, grads.opacity_logits, grads.sh, pose)


def render_with_grad(gaussians: Gaussians, camera: Camera,
                     background: tuple[float, float, float] = (1.0, 1.0, 1.0)) -> RenderWithGrad:
    """Render like :func:`marionette.render.render`, keeping what the backward pass needs.

    Parameters
    ----------
    gaussians : Gaussians
        N Gaussians (any SH degree 0 to 3).
    camera : Camera
        OpenCV pinhole camera; the image is ``camera.height × camera.width``.
    background : three floats in [0, 1]
        RGB behind the splats (a constant: it gets no gradient).

    Returns
    -------
    RenderWithGrad
        ``.output`` is the :class:`RenderOutput` (bit-identical to
        :func:`render`); ``.backward(grad_image (H, W, 3), grad_alpha (H, W) =
        None, groups=..., pivot=...)`` returns :class:`RenderGradients`.

    Examples
    --------
    >>> view = render_with_grad(gaussians, camera)            # doctest: +SKIP
    >>> residual = view.output.image - target                 # doctest: +SKIP
    >>> grads = view.backward(2 * residual, groups=part_mask)  # L = Σ residual², grads.pose (6,)
    """
    if not isinstance(gaussians, Gaussians):
        raise InputError(f"render_with_grad: gaussians must be a Gaussians, got {type(gaussians).__name__}")
    if not isinstance(camera, Camera):
        raise InputError(f"render_with_grad: camera must be a Camera, got {type(camera).__name__}")
    bg = _check_background(background)
    frame = _forward(gaussians, camera, bg, save=True)
    saved = _Saved(gaussians, camera, bg, frame, _pair_start(frame.boxes, frame.order, len(gaussians)))
    return RenderWithGrad(RenderOutput(frame.image, frame.alpha, frame.depth), saved)


@numba.njit(cache=True)
def _pair_start(boxes, order, n):
    """boxes (M, 4) int32 in depth order, order (M,) int32, n → pair_start (N + 1,) int64.

    Gaussian ``i`` owns slots ``pair_start[i] .. pair_start[i + 1] - 1`` of the
    backward's pair table, one per tile of its box, row-major (the tiles
    ``_bin`` gave it); culled Gaussians own none. Slots follow the input order
    so that ``_project_backward`` reads them as a stream.
    """
    start = np.zeros(n + 1, np.int64)
    for r in range(order.shape[0]):
        start[order[r] + 1] = (np.int64(boxes[r, 1] // TILE - boxes[r, 0] // TILE + 1)
                               * np.int64(boxes[r, 3] // TILE - boxes[r, 2] // TILE + 1))
    for i in range(n):
        start[i + 1] += start[i]
    return start


@numba.njit(nogil=True, cache=True)
def _zero_chunks(first, step, nchunks, table):
    """Chunks ``first, first + step, ...`` of ``CHUNK`` rows of table (P, K) set to zeros (one thread's share)."""
    for chunk in range(first, nchunks, step):
        for r in range(chunk * CHUNK, min(table.shape[0], (chunk + 1) * CHUNK)):
            for k in range(table.shape[1]):
                table[r, k] = 0


def _zero_rows(table):
    """Set table (P, K) to zeros, in parallel."""
    parallel_for(_zero_chunks, chunks(table.shape[0]), table)


@numba.njit(cache=True)
def _masked_sum(rows, mask):
    """Sum of rows (N, 6) float64 where mask (N,) bool holds → (6,), in index order."""
    total = np.zeros(6)
    for i in range(rows.shape[0]):
        if mask[i]:
            for k in range(6):
                total[k] += rows[i, k]
    return total


# Scratch tables of the backward pass, kept per thread and reused from call to call: the pair
# table of a large scene is tens of megabytes, and fresh pages cost more than the kernel that
# fills them. Per thread, so that concurrent fits (the web app's jobs) never share one.
_scratch_tables = threading.local()


def _scratch(name: str, shape: tuple[int, int], dtype: type) -> np.ndarray:
    """A C-contiguous array of ``shape`` and ``dtype``, its contents undefined: a view of this
    thread's buffer ``name``, which grows (to 1.25× the request) when too small."""
    size = shape[0] * shape[1]
    buffer = getattr(_scratch_tables, name, None)
    if buffer is None or buffer.size < size or buffer.dtype != dtype:
        buffer = np.empty(int(size * 1.25) + 1, dtype)
        setattr(_scratch_tables, name, buffer)
    return buffer[:size].reshape(shape)


def _check_grad(value: object, shape: tuple[int, ...], name: str) -> np.ndarray:
    """An upstream gradient → C-contiguous float32 of ``shape``, or :class:`InputError`."""
    try:
        arr = np.asarray(value, dtype=np.float32)
    except (TypeError, ValueError):
        raise InputError(f"backward: {name} must be a numeric array of shape {shape}") from None
    if arr.shape != shape:
        raise InputError(f"backward: {name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"backward: {name} contains NaN or infinite values")
    return np.ascontiguousarray(arr)


def _group_masks(groups: object, n: int) -> list[np.ndarray] | None:
    """``groups`` (a mask (N,), an index array, or a sequence of them) → boolean masks (N,)."""
    if groups is None:
        return None
    items = list(groups) if isinstance(groups, (list, tuple)) else [groups]
    if not items:
        raise InputError("backward: groups is an empty sequence")
    masks = []
    for k, item in enumerate(items):
        arr = np.asarray(item)
        mask = np.zeros(n, bool)
        if arr.dtype == bool:
            if arr.shape != (n,):
                raise InputError(f"backward: boolean group {k} must have shape ({n},), got {arr.shape}")
            mask = arr.copy()
        elif arr.ndim == 1 and (arr.size == 0 or np.issubdtype(arr.dtype, np.integer)):
            if arr.size and (arr.min() < -n or arr.max() >= n):
                raise InputError(f"backward: group {k} has indices outside 0..{n - 1}")
            mask[arr.astype(np.int64)] = True
        else:
            raise InputError(f"backward: group {k} must be a boolean mask ({n},) or a 1-D integer index array, "
                             f"got dtype {arr.dtype} shape {arr.shape}")
        masks.append(mask)
    return masks


# --------------------------------------------------------------------------- rasterize backward

@numba.njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _backward_lanes(state, accs, base, j0, nlanes, du, a2, b1, c0, xlo, xhi, opacity, red, green, blue,
                    kf, ca, cb, cc, dy):
    """Undo one Gaussian on lanes ``j0 .. j0 + nlanes - 1`` of one tile row, back to front.

    Branch-free, so that it vectorises. ``state`` holds the tile's planes
    (each TILE × TILE float32): 0 ``T`` (transmittance after this Gaussian),
    1-3 ``S`` (colour behind it, background included), 4-6 ``∂L/∂C``, 7
    ``∂L/∂A · T_N``, 8 the position of the Gaussian that stopped the pixel
    (the list's length if none). All planes are addressed
    as ``base + lane + constant``, so LLVM proves them disjoint. ``accs``
    (9 · TILE,) float32, a separate array (one runtime alias check), sums
    this Gaussian's 9 gradients (``_GU`` ...) per lane over the rows.
    The alpha is recomputed exactly as ``_blend_lanes`` computes it, so the
    pixels used are the forward's.
    """
    f32 = np.float32
    zero, one, half = f32(0.0), f32(1.0), f32(0.5)
    min_alpha, max_alpha = f32(1.0 / 255.0), f32(0.99)
    pl = np.uint64(TILE * TILE)
    p1, p2, p3, p4, p5, p6, p7, p8 = (pl, np.uint64(2) * pl, np.uint64(3) * pl, np.uint64(4) * pl,
                                      np.uint64(5) * pl, np.uint64(6) * pl, np.uint64(7) * pl, np.uint64(8) * pl)
    for jj in range(nlanes):
        j = j0 + jj
        lane = f32(j)
        dx = lane + du
        power = (a2 * dx + b1) * dx + c0
        e = _exp_clamped(power)
        oe = opacity * e
        alpha = min(max_alpha, oe)
        i = base + np.uint64(j)
        use = ((lane >= xlo) & (lane <= xhi) & (kf < state[i + p8]) & (power <= zero)
               & (alpha >= min_alpha))
        ra = one / (one - alpha)
        t_after = state[i]
        t_i = t_after * ra
        w = alpha * t_i
        s_r, s_g, s_b = state[i + p1], state[i + p2], state[i + p3]
        g_r, g_g, g_b = state[i + p4], state[i + p5], state[i + p6]
        v_alpha = ((g_r * (red * t_i - s_r * ra) + g_g * (green * t_i - s_g * ra)
                    + g_b * (blue * t_i - s_b * ra)) + state[i + p7] * ra)
        v_oe = v_alpha if (use & (oe <= max_alpha)) else zero
        v_power = v_oe * oe
        # d power / d(u, v) = (a dx + b dy, b dx + c dy) with dx = x - u.
        accs[0 + j] += v_power * (ca * dx + cb * dy)
        accs[16 + j] += v_power * (cb * dx + cc * dy)
        accs[32 + j] += v_power * (-half * dx * dx)
        accs[48 + j] += v_power * (-dx * dy)
        accs[64 + j] += v_power * (-half * dy * dy)
        accs[80 + j] += v_oe * e
        wu = w if use else zero
        accs[96 + j] += wu * g_r
        accs[112 + j] += wu * g_g
        accs[128 + j] += wu * g_b
        state[i] = t_i if use else t_after
        state[i + p1] = s_r + wu * red
        state[i + p2] = s_g + wu * green
        state[i + p3] = s_b + wu * blue


def _blend_backward(tile_start, tile_ids, params, boxes, width, height, background,
                    t_final, stop, row_last, grad_rgb, grad_alpha, order, pair_start, pair):
    """Gradients of the loss with respect to every (Gaussian, tile) pair's 2D parameters.

    Parameters
    ----------
    tile_start (n_tiles + 1,) int64, tile_ids (P,) int32, params (M, 10) float32, boxes (M, 4) int32
        As for ``_blend``.
    width, height : int
    background : (3,) float32
    t_final (H, W) float32, stop (H, W) int32, row_last (n_tiles, TILE) int32
        From ``_blend`` with ``save``.
    grad_rgb (H, W, 3) float32, grad_alpha (H, W) float32
        ``∂L/∂C`` (zero where the image was clipped) and ``∂L/∂A``.
    order (M,) int32, pair_start (N + 1,) int64
        Row → Gaussian, and each Gaussian's slots (``_pair_start``).
    pair : (P, 9) float32, zeros
        Filled here: the share of one tile's pixels in the gradients
        of one Gaussian (``u, v``, conic ``a, b, c``, opacity, ``r, g, b``), in
        the Gaussian's slot for that tile; each Gaussian's rows are contiguous and
        in tile order. Rows that stay zero (Gaussians behind stopped pixels, or
        adding to none) are not written: NumPy's zeros are pages the OS zeroes
        on first touch, far cheaper than scattered stores.
    """
    ntx = (width + TILE - 1) // TILE
    parallel_for(_blend_backward_tiles, ntx * ((height + TILE - 1) // TILE), ntx, tile_start, tile_ids, params, boxes,
                 width, height, background, t_final, stop, row_last, grad_rgb, grad_alpha, order, pair_start, pair)


@numba.njit(nogil=True, cache=True, error_model="numpy", fastmath={"contract"})
def _blend_backward_tiles(first, step, ntiles, ntx, tile_start, tile_ids, params, boxes, width, height, background,
                          t_final, stop, row_last, grad_rgb, grad_alpha, order, pair_start, pair):
    """Tiles ``first, first + step, ...`` of ``_blend_backward`` (one thread's share), each into its pairs'
    rows of ``pair``."""
    f32 = np.float32
    plane = TILE * TILE
    for t in range(first, ntiles, step):
        xs, ys, tw, th = _tile_origin(t, ntx, width, height)
        start, end = tile_start[t], tile_start[t + 1]
        state = np.zeros(_NPLANE_BWD * plane, np.float32)
        accs = np.zeros(_NGRAD * TILE, np.float32)
        for ly in range(th):
            for lx in range(tw):
                y, x = ys + ly, xs + lx
                p = ly * TILE + lx
                tn = t_final[y, x]
                state[p] = tn
                for ch in range(3):
                    state[(1 + ch) * plane + p] = tn * background[ch]
                    state[(4 + ch) * plane + p] = grad_rgb[y, x, ch]
                state[7 * plane + p] = grad_alpha[y, x] * tn
                state[8 * plane + p] = f32((stop[y, x] if stop[y, x] >= 0 else end) - start)
        kmax = -1
        for ly in range(th):
            kmax = max(kmax, row_last[t, ly] - start if row_last[t, ly] >= 0 else -1)
        ty, tx = t // ntx, t % ntx
        for kk in range(kmax, -1, -1):
            k = start + kk
            g = tile_ids[k]
            bx0, bx1, by0, by1, du, xlo, xhi, a2 = _splat(params, boxes, g, xs, ys, tw, th)
            ca, cb, cc = params[g, _CA], params[g, _CB], params[g, _CC]
            opacity = params[g, _OPACITY]
            red, green, blue = params[g, _R], params[g, _G], params[g, _B]
            kf = f32(kk)
            ran = False
            for ly in range(by0, by1 + 1):
                if row_last[t, ly] < k:
                    continue
                ran = True
                dy, b1, c0 = _splat_row(params, g, ys, ly)
                base = np.uint64(ly * TILE)
                h0 = bx0 - bx0 % 8
                if bx1 < h0 + 8:
                    _backward_lanes(state, accs, base, h0, 8, du, a2, b1, c0, xlo, xhi, opacity,
                                    red, green, blue, kf, ca, cb, cc, dy)
                else:
                    _backward_lanes(state, accs, base, 0, TILE, du, a2, b1, c0, xlo, xhi, opacity,
                                    red, green, blue, kf, ca, cb, cc, dy)
            if not ran:
                continue
            # The 16 lanes summed by a fixed pairwise tree (lanes not run hold zeros).
            _lane_tree(accs)
            nonzero = False
            for q in range(_NGRAD):
                nonzero |= accs[q * TILE] != f32(0.0)
            if nonzero:  # a scattered write: only where the pair row is not all zeros already
                slot = _slot(pair_start, order, boxes, g, ty, tx)
                for q in range(_NGRAD):
                    pair[slot, q] = accs[q * TILE]
                # A channel the forward clamped to 0 (SH + 0.5 <= 0) passes no gradient to its SH.
                if red <= f32(0.0):
                    pair[slot, _GR] = f32(0.0)
                if green <= f32(0.0):
                    pair[slot, _GG] = f32(0.0)
                if blue <= f32(0.0):
                    pair[slot, _GBL] = f32(0.0)
            for q in range(_NGRAD):
                accs[q * TILE] = f32(0.0)


@numba.njit(cache=True, inline="always")
def _lane_tree(accs):
    """Sum each run of TILE = 16 lanes of accs (9 · 16,) float32 into its first lane, by the fixed
    tree 16 → 8 → 4 → 2 → 1 (constant trip counts, so each level vectorises), and zero the others."""
    for q in range(_NGRAD):
        o = q * TILE
        for j in range(8):
            accs[o + j] += accs[o + 8 + j]
            accs[o + 8 + j] = np.float32(0.0)
        for j in range(4):
            accs[o + j] += accs[o + 4 + j]
            accs[o + 4 + j] = np.float32(0.0)
        for j in range(2):
            accs[o + j] += accs[o + 2 + j]
            accs[o + 2 + j] = np.float32(0.0)
        accs[o] += accs[o + 1]
        accs[o + 1] = np.float32(0.0)


@numba.njit(cache=True, inline="always")
def _slot(pair_start, order, boxes, g, ty, tx):
    """Slot of row ``g``'s entry for tile ``(ty, tx)`` in the pair table (see ``_pair_start``)."""
    tx0 = boxes[g, 0] // TILE
    return pair_start[order[g]] + (ty - boxes[g, 2] // TILE) * (boxes[g, 1] // TILE - tx0 + 1) + (tx - tx0)


# --------------------------------------------------------------------------- projection backward

@numba.njit(cache=True, inline="always")
def _sh_term(sh, v_sh, i, m, basis, gx, gy, gz, v0, v1, v2, acc):
    """One SH coefficient ``m``: writes ``v_sh[i, m]`` and adds its direction gradient to ``acc``."""
    v_sh[i, m, 0] = v0 * basis
    v_sh[i, m, 1] = v1 * basis
    v_sh[i, m, 2] = v2 * basis
    s = v0 * sh[i, m, 0] + v1 * sh[i, m, 1] + v2 * sh[i, m, 2]
    return acc[0] + s * gx, acc[1] + s * gy, acc[2] + s * gz


@numba.njit(cache=True)
def _sh_backward_one(sh, i, x, y, z, v0, v1, v2, v_sh):
    """Gradients of the SH colour of Gaussian ``i`` at unit direction ``(x, y, z)``.

    ``v0, v1, v2`` are ``∂L/∂colour`` already zeroed where the ``max(·, 0)``
    clamp holds. Writes ``v_sh[i]`` (C, 3) and returns ``∂L/∂(x, y, z)``,
    the direction's components taken as independent. The basis is that of
    :func:`marionette.render.sh._sh_channel`; each line gives a basis function
    and its partial derivatives.
    """
    c = sh.shape[1]
    xx, yy, zz = x * x, y * y, z * z
    acc = (0.0, 0.0, 0.0)
    acc = _sh_term(sh, v_sh, i, 0, SH_C0, 0.0, 0.0, 0.0, v0, v1, v2, acc)
    if c > 1:
        acc = _sh_term(sh, v_sh, i, 1, -SH_C1 * y, 0.0, -SH_C1, 0.0, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 2, SH_C1 * z, 0.0, 0.0, SH_C1, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 3, -SH_C1 * x, -SH_C1, 0.0, 0.0, v0, v1, v2, acc)
    if c > 4:
        k = SH_C2
        acc = _sh_term(sh, v_sh, i, 4, k[0] * x * y, k[0] * y, k[0] * x, 0.0, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 5, k[1] * y * z, 0.0, k[1] * z, k[1] * y, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 6, k[2] * (2 * zz - xx - yy), -2 * k[2] * x, -2 * k[2] * y, 4 * k[2] * z,
                       v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 7, k[3] * x * z, k[3] * z, 0.0, k[3] * x, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 8, k[4] * (xx - yy), 2 * k[4] * x, -2 * k[4] * y, 0.0, v0, v1, v2, acc)
    if c > 9:
        k = SH_C3
        acc = _sh_term(sh, v_sh, i, 9, k[0] * y * (3 * xx - yy), 6 * k[0] * x * y, k[0] * (3 * xx - 3 * yy), 0.0,
                       v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 10, k[1] * x * y * z, k[1] * y * z, k[1] * x * z, k[1] * x * y,
                       v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 11, k[2] * y * (4 * zz - xx - yy), -2 * k[2] * x * y,
                       k[2] * (4 * zz - xx - 3 * yy), 8 * k[2] * y * z, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 12, k[3] * z * (2 * zz - 3 * xx - 3 * yy), -6 * k[3] * x * z,
                       -6 * k[3] * y * z, k[3] * (6 * zz - 3 * xx - 3 * yy), v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 13, k[4] * x * (4 * zz - xx - yy), k[4] * (4 * zz - 3 * xx - yy),
                       -2 * k[4] * x * y, 8 * k[4] * x * z, v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 14, k[5] * z * (xx - yy), 2 * k[5] * x * z, -2 * k[5] * y * z,
                       k[5] * (xx - yy), v0, v1, v2, acc)
        acc = _sh_term(sh, v_sh, i, 15, k[6] * x * (xx - 3 * yy), k[6] * (3 * xx - 3 * yy), -6 * k[6] * x * y,
                       0.0, v0, v1, v2, acc)
    return acc


@numba.njit(cache=True, error_model="numpy")
def _project_range(lo, hi, means, quats, variances, opacities, sh, view, K, campos, width, height,
                   pair, pair_start, want_pose, v_means, v_quats, v_log_scales, v_logits, v_sh, contrib):
    """``_project_backward`` for Gaussians ``lo .. hi - 1``, written into its outputs."""
    nc = sh.shape[1]
    fx, fy = K[0, 0], K[1, 1]
    lims = _direction_limits(K, width, height)
    lim_x0, lim_x1, lim_y0, lim_y1 = lims
    w00, w01, w02 = view[0, 0], view[0, 1], view[0, 2]
    w10, w11, w12 = view[1, 0], view[1, 1], view[1, 2]
    w20, w21, w22 = view[2, 0], view[2, 1], view[2, 2]
    f32 = np.float32
    for i in range(lo, hi):
        if pair_start[i] == pair_start[i + 1]:
            for k in range(3):
                v_means[i, k] = v_log_scales[i, k] = f32(0.0)
            for k in range(4):
                v_quats[i, k] = f32(0.0)
            v_logits[i] = f32(0.0)
            for m in range(nc):
                for k in range(3):
                    v_sh[i, m, k] = f32(0.0)
            if want_pose:
                for k in range(6):
                    contrib[i, k] = 0.0
            continue
        g_u = g_v = g_ca = g_cb = g_cc = g_o = g_r = g_g = g_b = 0.0
        for slot in range(pair_start[i], pair_start[i + 1]):
            g_u += pair[slot, _GU]
            g_v += pair[slot, _GV]
            g_ca += pair[slot, _GA]
            g_cb += pair[slot, _GB]
            g_cc += pair[slot, _GC]
            g_o += pair[slot, _GO]
            g_r += pair[slot, _GR]
            g_g += pair[slot, _GG]
            g_b += pair[slot, _GBL]
        mx, my, mz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
        tx = w00 * mx + w01 * my + w02 * mz + view[0, 3]
        ty = w10 * mx + w11 * my + w12 * mz + view[1, 3]
        tz = w20 * mx + w21 * my + w22 * mz + view[2, 3]
        itz = 1.0 / tz
        # Σ = R diag(var) Rᵀ from the normalised quaternion, and T = J W: rows p, q.
        (qw, qx, qy, qz), qinv, rows = _rotation(quats, i)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rows
        va, vb_, vc = np.float64(variances[i, 0]), np.float64(variances[i, 1]), np.float64(variances[i, 2])
        sigma = _world_covariance(rows, variances, i)
        s00, s01, s02, s11, s12, s22 = sigma
        xz, yz = tx * itz, ty * itz
        (cxz, cyz), p, q, sp, sq, a, b, c_ = _screen_covariance(view, fx, fy, lims, xz, yz, itz, sigma)
        p0, p1, p2 = p
        q0, q1, q2 = q
        sp0, sp1, sp2 = sp
        sq0, sq1, sq2 = sq
        det = a * c_ - b * b
        id2 = 1.0 / (det * det)
        # Conic (c, -b, a) / det → Σ' entries a, b, c.
        v_a = (-c_ * c_ * g_ca + b * c_ * g_cb - b * b * g_cc) * id2
        v_b = (2 * b * c_ * g_ca - (a * c_ + b * b) * g_cb + 2 * a * b * g_cc) * id2
        v_c = (-b * b * g_ca + a * b * g_cb - a * a * g_cc) * id2
        # ∂L/∂Σ (symmetric) = v_a p pᵀ + v_b (q pᵀ + p qᵀ) / 2 + v_c q qᵀ.
        hb = 0.5 * v_b
        g00 = v_a * p0 * p0 + 2 * hb * q0 * p0 + v_c * q0 * q0
        g11 = v_a * p1 * p1 + 2 * hb * q1 * p1 + v_c * q1 * q1
        g22 = v_a * p2 * p2 + 2 * hb * q2 * p2 + v_c * q2 * q2
        g01 = v_a * p0 * p1 + hb * (q0 * p1 + p0 * q1) + v_c * q0 * q1
        g02 = v_a * p0 * p2 + hb * (q0 * p2 + p0 * q2) + v_c * q0 * q2
        g12 = v_a * p1 * p2 + hb * (q1 * p2 + p1 * q2) + v_c * q1 * q2
        # ∂L/∂p = 2 v_a Σ p + v_b Σ q; ∂L/∂q = 2 v_c Σ q + v_b Σ p;
        # p = j00 W₀ + j02 W₂, q = j11 W₁ + j12 W₂.
        vp0, vp1, vp2 = 2 * v_a * sp0 + v_b * sq0, 2 * v_a * sp1 + v_b * sq1, 2 * v_a * sp2 + v_b * sq2
        vq0, vq1, vq2 = 2 * v_c * sq0 + v_b * sp0, 2 * v_c * sq1 + v_b * sp1, 2 * v_c * sq2 + v_b * sp2
        v_j00 = vp0 * w00 + vp1 * w01 + vp2 * w02
        v_j02 = vp0 * w20 + vp1 * w21 + vp2 * w22
        v_j11 = vq0 * w10 + vq1 * w11 + vq2 * w12
        v_j12 = vq0 * w20 + vq1 * w21 + vq2 * w22
        # Mean in 2D: u = fx x/z + cx, v = fy y/z + cy (not clamped).
        iz2 = itz * itz
        v_tx = g_u * fx * itz
        v_ty = g_v * fy * itz
        v_tz = -(g_u * fx * tx + g_v * fy * ty) * iz2
        # j00 = fx/z, j11 = fy/z; j02 = -fx clamp(x/z)/z: direct z dependence, then the clamp.
        v_tz += (-(v_j00 * fx + v_j11 * fy) + v_j02 * fx * cxz + v_j12 * fy * cyz) * iz2
        v_cxz, v_cyz = -v_j02 * fx * itz, -v_j12 * fy * itz
        if lim_x0 <= xz <= lim_x1:
            v_tx += v_cxz * itz
            v_tz -= v_cxz * tx * iz2
        if lim_y0 <= yz <= lim_y1:
            v_ty += v_cyz * itz
            v_tz -= v_cyz * ty * iz2
        vmx = w00 * v_tx + w10 * v_ty + w20 * v_tz
        vmy = w01 * v_tx + w11 * v_ty + w21 * v_tz
        vmz = w02 * v_tx + w12 * v_ty + w22 * v_tz
        # Colours: max(SH(dir) + 0.5, 0), dir = (μ - campos) / |μ - campos|.
        dxw, dyw, dzw = mx - campos[0], my - campos[1], mz - campos[2]
        inv = 1.0 / math.sqrt(max(dxw * dxw + dyw * dyw + dzw * dzw, 1e-300))
        ux, uy, uz = dxw * inv, dyw * inv, dzw * inv
        # The colour gradients are zero already where the forward clamped (``_blend_backward``).
        gux, guy, guz = _sh_backward_one(sh, i, ux, uy, uz, g_r, g_g, g_b, v_sh)
        # Through the normalisation: (I - u uᵀ) g / |d|.
        dot = ux * gux + uy * guy + uz * guz
        vmx += (gux - ux * dot) * inv
        vmy += (guy - uy * dot) * inv
        vmz += (guz - uz * dot) * inv
        v_means[i, 0], v_means[i, 1], v_means[i, 2] = vmx, vmy, vmz
        o = np.float64(opacities[i])
        v_logits[i] = g_o * o * (1.0 - o)
        # Σ = M Mᵀ, M = R diag(s): ∂L/∂var_k = (Rᵀ G R)_kk and ∂L/∂R = 2 G R diag(var); var = exp(2 log_s).
        e00 = g00 * r00 + g01 * r10 + g02 * r20  # E = G R
        e01 = g00 * r01 + g01 * r11 + g02 * r21
        e02 = g00 * r02 + g01 * r12 + g02 * r22
        e10 = g01 * r00 + g11 * r10 + g12 * r20
        e11 = g01 * r01 + g11 * r11 + g12 * r21
        e12 = g01 * r02 + g11 * r12 + g12 * r22
        e20 = g02 * r00 + g12 * r10 + g22 * r20
        e21 = g02 * r01 + g12 * r11 + g22 * r21
        e22 = g02 * r02 + g12 * r12 + g22 * r22
        v_log_scales[i, 0] = 2.0 * va * (r00 * e00 + r10 * e10 + r20 * e20)
        v_log_scales[i, 1] = 2.0 * vb_ * (r01 * e01 + r11 * e11 + r21 * e21)
        v_log_scales[i, 2] = 2.0 * vc * (r02 * e02 + r12 * e12 + r22 * e22)
        m00, m01, m02 = 2 * va * e00, 2 * vb_ * e01, 2 * vc * e02  # ∂L/∂R
        m10, m11, m12 = 2 * va * e10, 2 * vb_ * e11, 2 * vc * e12
        m20, m21, m22 = 2 * va * e20, 2 * vb_ * e21, 2 * vc * e22
        # R(w, x, y, z) of the normalised quaternion, then (I - q̂ q̂ᵀ) g / |q|.
        vw = 2 * (-qz * m01 + qy * m02 + qz * m10 - qx * m12 - qy * m20 + qx * m21)
        vx = 2 * (qy * m01 + qz * m02 + qy * m10 - 2 * qx * m11 - qw * m12 + qz * m20 + qw * m21 - 2 * qx * m22)
        vy = 2 * (-2 * qy * m00 + qx * m01 + qw * m02 + qx * m10 + qz * m12 - qw * m20 + qz * m21 - 2 * qy * m22)
        vz = 2 * (-2 * qz * m00 - qw * m01 + qx * m02 + qw * m10 - 2 * qz * m11 + qy * m12 + qx * m20 + qy * m21)
        dq = qw * vw + qx * vx + qy * vy + qz * vz
        v_quats[i, 0] = (vw - qw * dq) * qinv
        v_quats[i, 1] = (vx - qx * dq) * qinv
        v_quats[i, 2] = (vy - qy * dq) * qinv
        v_quats[i, 3] = (vz - qz * dq) * qinv
        if want_pose:
            # A = Σ G; the rotation's share is 2 vex(A).
            a01 = s00 * g01 + s01 * g11 + s02 * g12
            a10 = s01 * g00 + s11 * g01 + s12 * g02
            a02 = s00 * g02 + s01 * g12 + s02 * g22
            a20 = s02 * g00 + s12 * g01 + s22 * g02
            a12 = s01 * g02 + s11 * g12 + s12 * g22
            a21 = s02 * g01 + s12 * g11 + s22 * g12
            contrib[i, 0] = my * vmz - mz * vmy + 2 * (a12 - a21)
            contrib[i, 1] = mz * vmx - mx * vmz + 2 * (a20 - a02)
            contrib[i, 2] = mx * vmy - my * vmx + 2 * (a01 - a10)
            contrib[i, 3], contrib[i, 4], contrib[i, 5] = vmx, vmy, vmz


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _project_chunks(first, step, nchunks, means, quats, variances, opacities, sh, view, K, campos, width, height,
                    pair, pair_start, want_pose, v_means, v_quats, v_log_scales, v_logits, v_sh, contrib):
    """Chunks ``first, first + step, ...`` of ``CHUNK`` Gaussians of ``_project_backward`` (one thread's share)."""
    n = means.shape[0]
    for chunk in range(first, nchunks, step):
        _project_range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK), means, quats, variances, opacities, sh,
                       view, K, campos, width, height, pair, pair_start, want_pose,
                       v_means, v_quats, v_log_scales, v_logits, v_sh, contrib)


def _project_backward(means, quats, variances, opacities, sh, view, K, campos, width, height,
                      pair, pair_start, want_pose, v_means, v_quats, v_log_scales, v_logits, v_sh, contrib):
    """From the 2D gradients to the Gaussians' parameters, in float64.

    Recomputes ``_preprocess``'s quantities for each visible Gaussian and runs
    them backwards (see the module docstring). Scalars only: no allocation per
    Gaussian.

    Parameters
    ----------
    means (N, 3), quats (N, 4), variances (N, 3), opacities (N,), sh (N, C, 3) : float32
    view (4, 4), K (3, 3), campos (3,) : float64
    width, height : int
    pair (P, 9) float32, pair_start (N + 1,) int64
        From ``_blend_backward``: Gaussian ``i``'s rows, summed here in float64
        and in tile order, give ``∂L/∂`` ``u, v``, conic ``a, b, c``, opacity,
        ``r, g, b``. Culled Gaussians have none and get zeros.
    want_pose : bool
    v_means (N, 3), v_quats (N, 4), v_log_scales (N, 3), v_logits (N,), v_sh (N, C, 3) : float32
        Outputs, every element written.
    contrib : (N, 6) float64, written with ``want_pose`` (else unused)
        ``[μ × ∂L/∂μ + 2 vex(Σ ∂L/∂Σ), ∂L/∂μ]``: each Gaussian's share of a pose gradient
        (zeros for culled Gaussians).
    """
    parallel_for(_project_chunks, chunks(means.shape[0]), means, quats, variances, opacities,
                 sh, view, K, campos, width, height, pair, pair_start, want_pose, v_means, v_quats, v_log_scales,
                 v_logits, v_sh, contrib)
