"""Gradients of the numba rasterizer (``marionette.render.backward``) against the NumPy twin
(``tests/reference_rasterizer_grad.py``) and central finite differences of its float64 forward.

**Knife edges.** The forward has discrete decisions (skip ``α < 1/255``, the 0.99
clamp, the stop at ``T < 1e-4``, the 3σ box and radius, the colour and image
clamps, the Jacobian clamp, the depth order, the near plane). Where one sits
within rounding of its threshold, the float32 fast path and the float64 twin may
decide differently, and a finite difference across it measures a jump, not a
derivative. ``smooth_scene`` therefore draws seeded scenes and keeps the first
whose every decision clears its threshold by a stated margin (``MARGINS``) that
is far larger than both the fast path's error there (float32 and the polynomial
exp: ``255 α`` is off by < 1e-4) and the change a finite-difference step causes
(steps of 1e-6 move any ``α`` by < 1e-5 relative). The checks are deterministic
and the scene is rejected, not the test, when a draw lands near a threshold, so
nothing depends on floating-point luck; the tests assert that the scenes still
exercise the clamps (opaque centres, stopped pixels, clipped pixels, clamped
colours, the clamped Jacobian).
"""

from __future__ import annotations

import functools

import numba
import numpy as np
import pytest
from reference_rasterizer import render_reference
from reference_rasterizer_grad import (
    KEYS, apply_pose, gaussians_of, project64, render64, render_grad_reference,
)

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.gaussians import rgb_to_sh
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.render import render
from marionette.render.backward import RenderGradients, render_with_grad

#: Smallest allowed distance of each discrete decision from its threshold (see the module docstring).
MARGINS = {
    "alpha_cut": 5e-4,    # |255 α - 1| for every live pixel in a box (fast path error < 1e-4)
    "alpha_clamp": 1e-4,  # |o e / 0.99 - 1|
    "stop": 1e-3,         # |T (1 - α) / 1e-4 - 1|
    "box": 1e-3,          # distance of u ± r, v ± r and 3 sqrt(λ_max) to the nearest integer (px)
    "colour": 1e-3,       # |SH + 0.5| of visible Gaussians
    "clip": 1e-4,         # distance of each unclipped colour to 0 and 1
    "jacobian": 1e-4,     # |x/z - limit| and |y/z - limit|
    "depth": 1e-4,        # gap between consecutive depths; distance of z to the near plane
}


def knife_edges(params: dict, camera: Camera, background) -> dict[str, float]:
    """The smallest distance of each kind of discrete decision to its threshold (keys of ``MARGINS``)."""
    _, _, rec = render64(params, camera, background, tape=True)
    proj = rec["proj"]
    out = {k: np.inf for k in MARGINS}
    for s in rec["steps"]:
        live = s["alive"]  # every pixel of the box not yet stopped
        a = np.minimum(0.99, s["oe"])[live]
        if a.size:
            out["alpha_cut"] = min(out["alpha_cut"], np.abs(255.0 * a - 1.0).min())
            out["alpha_clamp"] = min(out["alpha_clamp"], np.abs(s["oe"][live] / 0.99 - 1.0).min())
        used = s["alive"] & (np.minimum(0.99, s["oe"]) >= 1 / 255)
        if used.any():
            out["stop"] = min(out["stop"], np.abs(s["test_t"][used] / 1e-4 - 1.0).min())
    order = proj["order"]
    edges = np.concatenate([proj["mean2d"][order] - proj["radius"][order, None],
                            proj["mean2d"][order] + proj["radius"][order, None]], axis=1).ravel()
    edges = np.concatenate([edges, proj["three_sigma"][order]])
    out["box"] = np.abs(edges - np.round(edges)).min() if edges.size else np.inf
    out["colour"] = np.abs(proj["sh_value"][order]).min() if order.size else np.inf
    raw = rec["raw"]
    out["clip"] = np.minimum(np.abs(raw), np.abs(raw - 1.0)).min()
    lims = np.concatenate([proj["xz_raw"][order, None] - np.array(proj["lim_x"]),
                           proj["yz_raw"][order, None] - np.array(proj["lim_y"])], axis=1)
    out["jacobian"] = np.abs(lims).min() if order.size else np.inf
    z32 = np.sort(proj["z"].astype(np.float32)[order]).astype(np.float64)
    gaps = np.diff(z32) if z32.size > 1 else np.array([np.inf])
    out["depth"] = min(gaps.min(), np.abs(proj["z"] - 0.2).min())
    return out


def _draw(rng: np.random.Generator, n: int, w: int, h: int, degree: int):
    k = np.array([[1.1 * w, 0.0, w / 2 - 0.3], [0.0, 1.15 * w, h / 2 + 0.4], [0.0, 0.0, 1.0]])
    camera_to_world = make_transform(axis_angle_to_matrix(rng.normal(0.0, 0.1, 3)), [0.1, -0.1, -3.0])
    camera = Camera(k, np.linalg.inv(camera_to_world), w, h)
    means = rng.normal(size=(n, 3)) * [0.7, 0.5, 0.5]
    log_scales = np.log(rng.uniform(0.04, 0.25, (n, 3)))
    c = (degree + 1) ** 2
    sh = rng.normal(0.0, 0.15, (n, c, 3))
    sh[:, 0] = rgb_to_sh(rng.uniform(-0.1, 1.2, (n, 3)))  # some colours clamp at 0, some clip at 1
    logits = rng.normal(1.0, 2.0, n)
    # A stack of near-opaque layers on one line of sight, o in [0.96, 0.98]: pixels behind three
    # of them stop (T < 1e-4) with room to spare. (Two layers clamped at 0.99 would give exactly
    # T = 1e-4, a knife edge of the reference rules that ``smooth_scene`` rejects.)
    stack = max(3, n // 5)
    means[:stack, :2] = rng.normal(0.0, 0.05, (stack, 2))
    means[:stack, 2] = np.linspace(-0.6, 0.6, stack) + rng.uniform(-0.02, 0.02, stack)
    log_scales[:stack, :2] = np.log(rng.uniform(0.15, 0.25, (stack, 2)))
    logits[:stack] = rng.uniform(3.2, 3.9, stack)
    clamped = max(1, n // 8)  # opaque: o e > 0.99 near their centres
    logits[stack:stack + clamped] = rng.uniform(5.0, 7.0, clamped)
    params = {"means": means, "quats": rng.normal(size=(n, 4)), "log_scales": log_scales,
              "opacity_logits": logits, "sh": sh}
    # Float32 values, as Gaussians stores them, so the fast path and the twin see the same scene.
    params = {key: v.astype(np.float32).astype(np.float64) for key, v in params.items()}
    return params, camera, rng.uniform(0.2, 0.8, 3)


def smooth_scene(seed: int, n: int = 40, w: int = 64, h: int = 48, degree: int = 3):
    """The first seeded draw whose every discrete decision clears ``MARGINS``: params, camera, background."""
    params, camera, background = _smooth_scene(seed, n, w, h, degree)
    return {k: v.copy() for k, v in params.items()}, camera, background


@functools.lru_cache(maxsize=None)
def _smooth_scene(seed: int, n: int, w: int, h: int, degree: int):
    for attempt in range(200):
        params, camera, background = _draw(np.random.default_rng([seed, attempt]), n, w, h, degree)
        edges = knife_edges(params, camera, background)
        if all(edges[k] > MARGINS[k] for k in MARGINS):
            return params, camera, background
    raise AssertionError(f"no smooth scene for seed {seed}")


def loss_weights(camera: Camera, seed: int = 0):
    """Random ``∂L/∂image (H, W, 3)`` and ``∂L/∂alpha (H, W)``: ``L = Σ gi · image + Σ ga · alpha``."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(camera.height, camera.width, 3)), rng.normal(size=(camera.height, camera.width))


def linear_loss(params, camera, background, gi, ga) -> float:
    image, alpha = render64(params, camera, background)
    return float(np.sum(image * gi) + np.sum(alpha * ga))


def normwise_error(fast: np.ndarray, ref: np.ndarray) -> float:
    """max |fast - ref| / max |ref|: robust where gradients cancel to near zero."""
    return float(np.abs(np.asarray(fast, np.float64) - ref).max() / max(np.abs(ref).max(), 1e-300))


def features(params, camera, background) -> dict[str, bool]:
    """Which clamps a scene exercises."""
    _, _, rec = render64(params, camera, background, tape=True)
    proj, order = rec["proj"], rec["proj"]["order"]
    steps = rec["steps"]
    return {
        "alpha_clamp": any(((s["oe"] > 0.99) & s["add"]).any() for s in steps),
        "stop": any((s["alive"] & (np.minimum(0.99, s["oe"]) >= 1 / 255) & (s["test_t"] < 1e-4)).any()
                    for s in steps),
        "clip": bool(((rec["raw"] > 1) | (rec["raw"] < 0)).any()),
        "colour_clamp": bool((proj["sh_value"][order] < 0).any()),
        "jacobian_clamp": bool(((proj["xz"] != proj["xz_raw"]) | (proj["yz"] != proj["yz_raw"]))[order].any()),
    }


# --------------------------------------------------------------------------- forward

@pytest.mark.parametrize("seed", range(3))
def test_forward_is_render(seed):
    """The saving forward returns exactly :func:`render`'s images."""
    params, camera, background = smooth_scene(seed)
    gaussians = gaussians_of(params)
    out = render(gaussians, camera, background)
    view = render_with_grad(gaussians, camera, background)
    for name in ("image", "alpha", "depth"):
        np.testing.assert_array_equal(getattr(view.output, name), getattr(out, name))


def test_twin_forward_is_reference():
    """The twin's float64 forward is ``render_reference``; the reference rounds colours and opacities
    to float32 (``eval_sh``, ``Gaussians.opacities``), hence 1e-6 rather than float64 rounding."""
    params, camera, background = smooth_scene(0)
    image, alpha = render64(params, camera, background)
    _image, _alpha, _ = render_reference(gaussians_of(params), camera, background)
    np.testing.assert_allclose(image, _image, atol=1e-6)
    np.testing.assert_allclose(alpha, _alpha, atol=1e-6)


# --------------------------------------------------------------------------- the twin against finite differences

def test_twin_matches_finite_differences():
    """Every coordinate of the twin's gradient (and a pose) against central differences in float64.

    Step 1e-6: truncation error ~h² f''' < 1e-10 and rounding ~1e-16 L / h < 1e-8, so
    the two agree to ~1e-7 of the largest gradient; 1e-6 leaves room.
    """
    params, camera, background = smooth_scene(11, n=7, w=24, h=20)
    gi, ga = loss_weights(camera, 1)
    mask = np.arange(7) % 2 == 0
    _grads = render_grad_reference(params, camera, background, gi, ga, groups=[mask], pivot=[0.1, -0.2, 0.3])
    step = 1e-6
    for key in KEYS:
        fd = np.zeros_like(params[key])
        for idx in np.ndindex(params[key].shape):
            p = {k: v.copy() for k, v in params.items()}
            p[key][idx] += step
            plus = linear_loss(p, camera, background, gi, ga)
            p[key][idx] -= 2 * step
            fd[idx] = (plus - linear_loss(p, camera, background, gi, ga)) / (2 * step)
        assert np.abs(fd).max() > 0, key
        assert normwise_error(_grads[key], fd) < 1e-6, key
    fd_pose = np.zeros(6)
    for j in range(6):
        xi = np.zeros(6)
        xi[j] = step
        fd_pose[j] = (linear_loss(apply_pose(params, mask, xi, [0.1, -0.2, 0.3]), camera, background, gi, ga)
                      - linear_loss(apply_pose(params, mask, -xi, [0.1, -0.2, 0.3]), camera, background, gi, ga)
                      ) / (2 * step)
    assert normwise_error(_grads["pose"][0], fd_pose) < 1e-6


# --------------------------------------------------------------------------- fast path against the twin and FD

@pytest.mark.parametrize("seed, degree", [(0, 3), (1, 0), (2, 1), (3, 2)])
def test_matches_twin(seed, degree):
    """All gradients, every element, against the twin on 40 Gaussians at 64×48.

    Tolerance: the fast path composites in float32 (relative error ~1e-6 per
    pixel term, ~1e-5 after summing hundreds of them with cancellation) and uses
    the polynomial exp (< 3e-7 absolute); 1e-4 of the largest gradient in each
    group is ~100× the errors seen (< 1e-6; entries above 1% of the largest agree
    to < 3e-5 relative). A wrong sign, a missing term or a half-pixel shift costs
    far more than that.
    """
    params, camera, background = smooth_scene(seed, degree=degree)
    gi, ga = loss_weights(camera, seed)
    mask = np.arange(40) < 15
    grads = render_with_grad(gaussians_of(params), camera, background).backward(gi, ga, groups=mask)
    _grads = render_grad_reference(params, camera, background, gi, ga, groups=[mask])
    assert isinstance(grads, RenderGradients)
    for key in KEYS:
        assert getattr(grads, key).shape == params[key].shape and getattr(grads, key).dtype == np.float32
        assert normwise_error(getattr(grads, key), _grads[key]) < 1e-4, key
    assert grads.pose.shape == (6,)
    assert normwise_error(grads.pose, _grads["pose"][0]) < 1e-4


def test_scenes_exercise_the_clamps():
    """The smooth scenes still contain every clamp, so their gradients are tested too."""
    seen = {}
    for seed in range(4):
        for name, value in features(*smooth_scene(seed, degree=seed)).items():
            seen[name] = seen.get(name, False) or value
    tiny = features(*smooth_scene(11, n=7, w=24, h=20))
    assert all(seen.values()), seen
    assert sum(tiny.values()) >= 2, tiny


def test_matches_finite_differences():
    """Directional derivatives of the fast gradient, per parameter group, against central
    differences of the float64 forward (3 random directions each). Same 1e-4 budget as
    against the twin: the directional sums average the float32 errors."""
    params, camera, background = smooth_scene(5)
    gi, ga = loss_weights(camera, 5)
    grads = render_with_grad(gaussians_of(params), camera, background).backward(gi, ga)
    rng = np.random.default_rng(5)
    step = 1e-6
    for key in KEYS:
        for _ in range(3):
            direction = rng.normal(size=params[key].shape)
            plus = {k: v + step * direction if k == key else v for k, v in params.items()}
            minus = {k: v - step * direction if k == key else v for k, v in params.items()}
            fd = (linear_loss(plus, camera, background, gi, ga)
                  - linear_loss(minus, camera, background, gi, ga)) / (2 * step)
            analytic = float(np.sum(getattr(grads, key).astype(np.float64) * direction))
            scale = float(np.sqrt(np.sum(getattr(grads, key).astype(np.float64) ** 2 * direction ** 2)))
            assert abs(analytic - fd) <= 1e-4 * max(abs(fd), scale), (key, analytic, fd)


def test_pose_gradient():
    """The SE(3) gradient of two groups (a mask and an index array) about pivots against central
    differences of moving them in the float64 forward; 1e-4 as above."""
    params, camera, background = smooth_scene(7)
    gi, ga = loss_weights(camera, 7)
    mask = np.zeros(40, bool)
    mask[::3] = True
    index = np.arange(20, 40)
    pivots = np.array([[0.2, 0.0, 0.1], [-0.3, 0.1, 0.0]])
    grads = render_with_grad(gaussians_of(params), camera, background).backward(
        gi, ga, groups=[mask, index], pivot=pivots)
    assert grads.pose.shape == (2, 6)
    step = 1e-6
    for k, group in enumerate([mask, np.isin(np.arange(40), index)]):
        fd = np.zeros(6)
        for j in range(6):
            xi = np.zeros(6)
            xi[j] = step
            fd[j] = (linear_loss(apply_pose(params, group, xi, pivots[k]), camera, background, gi, ga)
                     - linear_loss(apply_pose(params, group, -xi, pivots[k]), camera, background, gi, ga)
                     ) / (2 * step)
        assert normwise_error(grads.pose[k], fd) < 1e-4, (k, grads.pose[k], fd)
    # The whole scene's pose gradient is the sum of its parts' (same pivot).
    whole = render_with_grad(gaussians_of(params), camera, background).backward(
        gi, ga, groups=[mask, ~mask, np.ones(40, bool)])
    np.testing.assert_allclose(whole.pose[0] + whole.pose[1], whole.pose[2], rtol=1e-9, atol=1e-9)


# --------------------------------------------------------------------------- properties

def test_deterministic_across_threads():
    """Per-(Gaussian, tile) partial sums are reduced in a fixed order: 1 or 2 threads, same bits."""
    params, camera, background = smooth_scene(2)
    gi, ga = loss_weights(camera, 2)
    gaussians = gaussians_of(params)
    threads = numba.get_num_threads()
    try:
        results = []
        for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS), threads}):
            numba.set_num_threads(t)
            results.append(render_with_grad(gaussians, camera, background).backward(gi, ga, groups=np.arange(9)))
    finally:
        numba.set_num_threads(threads)
    for other in results[1:]:
        for key in KEYS + ("pose",):
            np.testing.assert_array_equal(getattr(other, key), getattr(results[0], key))


def test_reused_scratch_tables_give_the_same_bits():
    """A larger pass in between, which leaves other numbers in the backward's reused scratch
    tables, changes nothing: not the gradients, nor the pose shares of culled Gaussians."""
    params, camera, background = smooth_scene(3)
    params = {k: v.copy() for k, v in params.items()}
    params["means"][:2] = [0.0, 0.0, -5.0]  # culled
    gi, ga = loss_weights(camera, 3)
    gaussians = gaussians_of(params)
    groups = [np.arange(40) % 2 == 0, np.ones(40, bool)]
    first = render_with_grad(gaussians, camera, background).backward(gi, ga, groups=groups)
    big_params, big_camera, big_background = _draw(np.random.default_rng(4), 400, 96, 80, 3)
    big_gi, big_ga = loss_weights(big_camera, 4)
    render_with_grad(gaussians_of(big_params), big_camera, big_background).backward(
        big_gi, big_ga, groups=np.ones(400, bool))
    again = render_with_grad(gaussians, camera, background).backward(gi, ga, groups=groups)
    for key in KEYS + ("pose",):
        np.testing.assert_array_equal(getattr(again, key), getattr(first, key))


def test_clipped_pixels_and_culled_gaussians_get_nothing():
    """A gradient only on clipped pixels moves nothing; Gaussians behind the camera get zeros."""
    params, camera, background = smooth_scene(0)
    params = {k: v.copy() for k, v in params.items()}
    params["means"][:3] = [0.0, 0.0, -5.0]  # behind the camera (at z ≈ -3 in the world)
    view = render_with_grad(gaussians_of(params), camera, background)
    _, _, rec = render64(params, camera, background, tape=True)
    clipped = (rec["raw"] > 1) | (rec["raw"] < 0)
    assert clipped.any()
    grads = view.backward(np.where(clipped, 1.0, 0.0))
    for key in KEYS:
        assert not np.any(getattr(grads, key)), key
    assert 0 not in project64(params, camera)["order"]
    grads = view.backward(loss_weights(camera)[0])
    for key in KEYS:
        assert not np.any(getattr(grads, key)[:3]), key
        assert np.any(getattr(grads, key)[3:]), key


def test_zero_upstream_gradient_gives_zero():
    params, camera, background = smooth_scene(1)
    grads = render_with_grad(gaussians_of(params), camera, background).backward(
        np.zeros((camera.height, camera.width, 3)), groups=np.ones(40, bool))
    for key in KEYS + ("pose",):
        assert not np.any(getattr(grads, key)), key


def test_bad_inputs_raise():
    params, camera, background = smooth_scene(0, n=5, w=16, h=16)
    gaussians = gaussians_of(params)
    with pytest.raises(InputError, match="gaussians"):
        render_with_grad(params, camera)
    with pytest.raises(InputError, match="camera"):
        render_with_grad(gaussians, "camera")
    with pytest.raises(InputError, match="background"):
        render_with_grad(gaussians, camera, (1.0, 2.0, 0.0))
    view = render_with_grad(gaussians, camera, background)
    with pytest.raises(InputError, match=r"grad_image must have shape \(16, 16, 3\)"):
        view.backward(np.zeros((16, 16)))
    with pytest.raises(InputError, match="grad_alpha"):
        view.backward(np.zeros((16, 16, 3)), np.zeros((16, 15)))
    with pytest.raises(InputError, match="NaN"):
        view.backward(np.full((16, 16, 3), np.nan))
    with pytest.raises(InputError, match="group 0"):
        view.backward(np.zeros((16, 16, 3)), groups=np.ones(4, bool))
    with pytest.raises(InputError, match="outside"):
        view.backward(np.zeros((16, 16, 3)), groups=[np.array([0, 5])])
    with pytest.raises(InputError, match="pivot"):
        view.backward(np.zeros((16, 16, 3)), groups=[np.array([0, 1])], pivot=np.zeros(2))
