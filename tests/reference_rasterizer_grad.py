"""Slow, obviously-correct twin of :mod:`marionette.render.backward`, in plain NumPy float64.

``render64`` is :func:`reference_rasterizer.render_reference` re-written on
float64 parameter arrays (a dict with ``means (N, 3)``, ``quats (N, 4)``,
``log_scales (N, 3)``, ``opacity_logits (N,)``, ``sh (N, C, 3)``), so that
central finite differences can be taken in float64 (``Gaussians`` stores
float32). Same rules: near plane 0.2, ``Σ' = J W Σ Wᵀ Jᵀ + 0.3 I`` with the
1.3× clamp in ``J``, the square 3σ box, depth order by float32 depth,
``α = min(0.99, o e^power)``, skip ``α < 1/255``, stop at ``T (1 - α) < 1e-4``,
colours ``max(SH + 0.5, 0)``, the image clipped to [0, 1]. With ``tape=True``
it also records, per Gaussian in depth order, what the backward needs.

``render_grad_reference`` derives the gradient by hand, in a form different
from the fast path wherever that is natural:

- compositing **front to back**, with the colour behind each Gaussian taken
  as ``S_i = C_raw - Σ_{j<=i} c_j α_j T_j`` (the fast path walks back to front
  and divides transmittances): ``∂C/∂α_i = c_i T_i - S_i / (1 - α_i)``,
  ``∂A/∂α_i = T_N / (1 - α_i)``;
- the conic and covariance chain as matrices: ``∂L/∂Σ' = -Q (∂L/∂Q) Q``,
  ``∂L/∂Σ = Tᵀ (∂L/∂Σ') T``, ``∂L/∂T = 2 (∂L/∂Σ') T Σ``;
- ``∂J/∂t`` written out as three 2×3 matrices; ``∂R/∂q`` by complex-step
  differentiation of the (polynomial) rotation formula, exact to rounding;
- the SH basis' direction derivative by central differences of
  :func:`marionette.render.sh._basis` (a cubic: error ~1e-10).

The pose gradient (twist ``[ω, v]`` of a group about a pivot ``p``:
``μ' = exp(ω^)(μ - p) + p + v``, ``q' = q_ω ⊗ q``) is
``Σ_i [(μ_i - p) × ∂L/∂μ_i + 2 vex(Σ_i ∂L/∂Σ_i), ∂L/∂μ_i]``; :func:`apply_pose`
applies the motion itself, for finite differences.
"""

from __future__ import annotations

import numpy as np

from marionette.camera import Camera
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion, quaternion_multiply
from marionette.render.sh import _basis

from reference_rasterizer import splat_footprint

NEAR = 0.2
LOW_PASS = 0.3
KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def params_of(gaussians: Gaussians) -> dict[str, np.ndarray]:
    """Gaussians → dict of float64 copies of their arrays."""
    return {k: getattr(gaussians, k).astype(np.float64) for k in KEYS}


def gaussians_of(params: dict[str, np.ndarray]) -> Gaussians:
    """dict of arrays → Gaussians (float32)."""
    return Gaussians(*(params[k] for k in KEYS))


def _rotation(q: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) ``w, x, y, z`` (unit, real or complex) → (N, 3, 3), the polynomial formula."""
    w, x, y, z = q.T
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=1).reshape(-1, 3, 3)


def _unit_quats(quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """quats (N, 4) → unit quats (N, 4) (zero stays zero: the identity rotation) and norms (N,)."""
    norm = np.linalg.norm(quats, axis=1)
    return np.where(norm[:, None] > 0, quats / np.where(norm > 0, norm, 1.0)[:, None], 0.0), norm


def project64(params: dict[str, np.ndarray], camera: Camera) -> dict[str, np.ndarray]:
    """Every Gaussian in screen space (float64), plus ``order``: the kept ones, front to back."""
    p = params
    n = len(p["means"])
    w, h = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    view = camera.world_to_camera
    wr = view[:3, :3]
    t = p["means"] @ wr.T + view[:3, 3]
    z = t[:, 2]
    zs = np.where(z > NEAR, z, 1.0)
    lim_x = (-(cx + 0.5) / fx - 0.15 * w / fx, (w - 0.5 - cx) / fx + 0.15 * w / fx)
    lim_y = (-(cy + 0.5) / fy - 0.15 * h / fy, (h - 0.5 - cy) / fy + 0.15 * h / fy)
    xz_raw, yz_raw = t[:, 0] / zs, t[:, 1] / zs
    xz, yz = np.clip(xz_raw, *lim_x), np.clip(yz_raw, *lim_y)
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = fx / zs
    jac[:, 0, 2] = -fx * xz / zs
    jac[:, 1, 1] = fy / zs
    jac[:, 1, 2] = -fy * yz / zs
    tw = jac @ wr
    unit_q, qnorm = _unit_quats(p["quats"])
    rot = _rotation(unit_q)
    var = np.exp(2.0 * p["log_scales"])
    cov3d = (rot * var[:, None, :]) @ np.swapaxes(rot, 1, 2)
    cov2d = tw @ cov3d @ np.swapaxes(tw, 1, 2) + LOW_PASS * np.eye(2)
    det = np.linalg.det(cov2d)
    mid = 0.5 * (cov2d[:, 0, 0] + cov2d[:, 1, 1])
    lam = mid + np.sqrt(np.maximum(0.1, mid * mid - det))
    keep = (z > NEAR) & (det > 0)
    three_sigma = 3.0 * np.sqrt(np.where(keep, lam, 0.0))
    radius = np.ceil(three_sigma).astype(np.int64)
    mean2d = np.stack([fx * xz_raw + cx, fy * yz_raw + cy], axis=1)
    keep &= (mean2d[:, 0] + radius >= 0) & (mean2d[:, 0] - radius <= w - 1)
    keep &= (mean2d[:, 1] + radius >= 0) & (mean2d[:, 1] - radius <= h - 1)
    index = np.flatnonzero(keep)
    order = index[np.argsort(z[index].astype(np.float32), kind="stable")]
    d = p["means"] - camera.center
    dnorm = np.linalg.norm(d, axis=1)
    unit_d = d / dnorm[:, None]
    basis = _basis(unit_d, p["sh"].shape[1])
    sh_value = np.einsum("nc,nck->nk", basis, p["sh"]) + 0.5
    return {
        "order": order, "t": t, "z": z, "xz_raw": xz_raw, "yz_raw": yz_raw, "xz": xz, "yz": yz,
        "lim_x": lim_x, "lim_y": lim_y, "jac": jac, "tw": tw, "unit_q": unit_q, "qnorm": qnorm,
        "rot": rot, "var": var, "cov3d": cov3d, "cov2d": cov2d, "conic": np.linalg.inv(cov2d),
        "three_sigma": three_sigma, "radius": radius, "mean2d": mean2d,
        "opacity": 1.0 / (1.0 + np.exp(-p["opacity_logits"])), "unit_d": unit_d, "dnorm": dnorm,
        "basis": basis, "sh_value": sh_value, "rgb": np.maximum(sh_value, 0.0),
    }


def render64(params: dict[str, np.ndarray], camera: Camera, background=(1.0, 1.0, 1.0),
             tape: bool = False):
    """Float64 render → ``image (H, W, 3)``, ``alpha (H, W)`` (and, with ``tape``, the record)."""
    w, h = camera.width, camera.height
    proj = project64(params, camera)
    bg = np.asarray(background, np.float64)
    trans = np.ones((h, w))
    color = np.zeros((h, w, 3))
    done = np.zeros((h, w), bool)
    steps = []
    for i in proj["order"]:
        footprint = splat_footprint(proj["mean2d"][i], proj["radius"][i], proj["conic"][i], w, h)
        if footprint is None:
            continue
        box, dx, dy, power = footprint
        e = np.exp(power)
        oe = proj["opacity"][i] * e
        alpha = np.minimum(0.99, oe)
        alive = ~done[box]
        use = alive & (power <= 0) & (alpha >= 1.0 / 255.0)
        test_t = trans[box] * (1.0 - alpha)
        finish = use & (test_t < 1e-4)
        done[box] |= finish
        add = use & ~finish
        if tape:
            steps.append({"i": i, "box": box, "dx": dx, "dy": dy, "e": e, "oe": oe, "alpha": alpha,
                          "add": add, "t_before": trans[box].copy(), "alive": alive, "test_t": test_t})
        color[box] += np.where(add, alpha * trans[box], 0.0)[..., None] * proj["rgb"][i]
        trans[box] = np.where(add, test_t, trans[box])
    raw = color + trans[..., None] * bg
    image = np.clip(raw, 0.0, 1.0)
    if tape:
        return image, 1.0 - trans, {"proj": proj, "steps": steps, "raw": raw, "trans": trans}
    return image, 1.0 - trans


def apply_pose(params: dict[str, np.ndarray], mask: np.ndarray, xi: np.ndarray,
               pivot=(0.0, 0.0, 0.0)) -> dict[str, np.ndarray]:
    """Move the Gaussians of ``mask`` by the twist ``xi = [ω, v]`` about ``pivot``:
    ``μ' = exp(ω^)(μ - p) + p + v``, ``q' = q_ω ⊗ q`` (SH unchanged)."""
    rot = axis_angle_to_matrix(np.asarray(xi[:3], np.float64))
    pivot = np.asarray(pivot, np.float64)
    out = {k: v.copy() for k, v in params.items()}
    out["means"][mask] = (params["means"][mask] - pivot) @ rot.T + pivot + xi[3:]
    out["quats"][mask] = quaternion_multiply(matrix_to_quaternion(rot), params["quats"][mask])
    return out


def render_grad_reference(params: dict[str, np.ndarray], camera: Camera, background, grad_image: np.ndarray,
                          grad_alpha: np.ndarray | None = None, groups=None, pivot=None) -> dict[str, np.ndarray]:
    """Gradients of ``L`` with ``∂L/∂image = grad_image (H, W, 3)``, ``∂L/∂alpha = grad_alpha (H, W)``.

    Returns a dict with the keys of ``params`` (same shapes, float64) and, if
    ``groups`` (a list of P boolean masks (N,)) is given, ``pose (P, 6)``.
    """
    p = params
    n, nc = len(p["means"]), p["sh"].shape[1]
    h, w = camera.height, camera.width
    assert grad_image.shape == (h, w, 3), grad_image.shape
    g_a = np.zeros((h, w)) if grad_alpha is None else np.asarray(grad_alpha, np.float64)
    assert g_a.shape == (h, w), g_a.shape
    _, _, rec = render64(p, camera, background, tape=True)
    proj, raw, t_final = rec["proj"], rec["raw"], rec["trans"]
    g_c = np.where((raw >= 0) & (raw <= 1), grad_image, 0.0)  # clipping passes no gradient
    fx, fy = camera.fx, camera.fy

    # 1. Compositing, front to back: ∂L/∂(u, v), ∂L/∂Q (conic), ∂L/∂opacity, ∂L/∂rgb.
    v_uv, v_q = np.zeros((n, 2)), np.zeros((n, 2, 2))
    v_op, v_rgb = np.zeros(n), np.zeros((n, 3))
    front = np.zeros((h, w, 3))  # Σ_{j<=i} c_j α_j T_j
    for s in rec["steps"]:
        i, box, add = s["i"], s["box"], s["add"]
        c = proj["rgb"][i]
        wgt = np.where(add, s["alpha"] * s["t_before"], 0.0)
        front[box] += wgt[..., None] * c
        behind = raw[box] - front[box]
        ra = 1.0 / (1.0 - s["alpha"])
        d_alpha = (np.sum(g_c[box] * (c * s["t_before"][..., None] - behind * ra[..., None]), axis=-1)
                   + g_a[box] * t_final[box] * ra)
        d_alpha = np.where(add & (s["oe"] <= 0.99), d_alpha, 0.0)  # the 0.99 clamp
        v_rgb[i] += np.sum(wgt[..., None] * g_c[box], axis=(0, 1))
        v_op[i] += np.sum(d_alpha * s["e"])
        v_power = d_alpha * s["oe"]
        d = np.stack([s["dx"], s["dy"]], axis=-1)  # pixel - mean, (h', w', 2)
        con = proj["conic"][i]
        v_uv[i] += np.sum(v_power[..., None] * (d @ con), axis=(0, 1))  # ∂power/∂mean = Q d
        v_q[i] += np.einsum("yx,yxa,yxb->ab", v_power, d, d) * -0.5   # ∂power/∂Q = -½ d dᵀ

    # 2. Projection, as matrices.
    conic, tw, cov3d = proj["conic"], proj["tw"], proj["cov3d"]
    v_cov2d = -conic @ v_q @ conic
    v_cov3d = np.swapaxes(tw, 1, 2) @ v_cov2d @ tw
    v_tw = 2.0 * v_cov2d @ tw @ cov3d
    wr = camera.world_to_camera[:3, :3]
    v_jac = v_tw @ wr.T
    t, z = proj["t"], proj["z"]
    zs = np.where(z > NEAR, z, 1.0)
    in_x = (proj["xz_raw"] >= proj["lim_x"][0]) & (proj["xz_raw"] <= proj["lim_x"][1])
    in_y = (proj["yz_raw"] >= proj["lim_y"][0]) & (proj["yz_raw"] <= proj["lim_y"][1])
    dj = np.zeros((n, 3, 2, 3))  # ∂J/∂t_k
    dj[:, 0, 0, 2] = -fx * in_x / zs**2
    dj[:, 1, 1, 2] = -fy * in_y / zs**2
    dj[:, 2, 0, 0] = -fx / zs**2
    dj[:, 2, 1, 1] = -fy / zs**2
    dj[:, 2, 0, 2] = fx * proj["xz"] / zs**2 + fx * in_x * t[:, 0] / zs**3
    dj[:, 2, 1, 2] = fy * proj["yz"] / zs**2 + fy * in_y * t[:, 1] / zs**3
    v_t = np.einsum("nab,nkab->nk", v_jac, dj)
    duv = np.zeros((n, 2, 3))  # ∂(u, v)/∂t
    duv[:, 0, 0], duv[:, 0, 2] = fx / zs, -fx * t[:, 0] / zs**2
    duv[:, 1, 1], duv[:, 1, 2] = fy / zs, -fy * t[:, 1] / zs**2
    v_t += np.einsum("na,nak->nk", v_uv, duv)
    v_means = v_t @ wr

    # Colours: max(B(u) · sh + 0.5, 0) with u = (μ - c) / |μ - c|.
    v_rgb = np.where(proj["sh_value"] > 0, v_rgb, 0.0)
    v_sh = proj["basis"][:, :, None] * v_rgb[:, None, :]
    hstep = 1e-6
    d_basis = np.stack([(_basis(proj["unit_d"] + hstep * e, nc) - _basis(proj["unit_d"] - hstep * e, nc))
                        / (2 * hstep) for e in np.eye(3)], axis=-1)  # (N, C, 3)
    v_unit = np.einsum("nk,nck,ncj->nj", v_rgb, p["sh"], d_basis)
    u = proj["unit_d"]
    v_means += (v_unit - u * np.sum(u * v_unit, axis=1, keepdims=True)) / proj["dnorm"][:, None]

    # Σ = R diag(var) Rᵀ.
    rot, var = proj["rot"], proj["var"]
    v_log_scales = 2.0 * var * np.einsum("nij,nik,nkj->nj", rot, v_cov3d, rot)
    v_rot = 2.0 * v_cov3d @ rot * var[:, None, :]
    uq = proj["unit_q"]
    v_uq = np.stack([np.sum(v_rot * _rotation(uq + 1e-30j * e).imag / 1e-30, axis=(1, 2)) for e in np.eye(4)],
                    axis=1)
    qn = np.where(proj["qnorm"] > 0, proj["qnorm"], np.inf)[:, None]
    v_quats = (v_uq - uq * np.sum(uq * v_uq, axis=1, keepdims=True)) / qn
    o = proj["opacity"]
    grads = {"means": v_means, "quats": v_quats, "log_scales": v_log_scales,
             "opacity_logits": v_op * o * (1 - o), "sh": v_sh}
    # Only Gaussians that were kept have gradients (the others have zero 2D gradients anyway).
    kept = np.zeros(n, bool)
    kept[proj["order"]] = True
    for k in grads:
        grads[k] = np.where(kept.reshape((-1,) + (1,) * (grads[k].ndim - 1)), grads[k], 0.0)
    if groups is not None:
        pivots = np.zeros((len(groups), 3)) if pivot is None else np.broadcast_to(pivot, (len(groups), 3))
        a = cov3d @ np.where(kept[:, None, None], v_cov3d, 0.0)
        vex = np.stack([a[:, 1, 2] - a[:, 2, 1], a[:, 2, 0] - a[:, 0, 2], a[:, 0, 1] - a[:, 1, 0]], axis=1)
        pose = np.zeros((len(groups), 6))
        for k, mask in enumerate(groups):
            gm = grads["means"][mask]
            pose[k, :3] = np.sum(np.cross(p["means"][mask] - pivots[k], gm) + 2.0 * vex[mask], axis=0)
            pose[k, 3:] = gm.sum(axis=0)
        grads["pose"] = pose
    return grads
