"""The numba rasterizer against its NumPy twin (``tests/reference_rasterizer.py``), plus
properties with a known answer."""

from __future__ import annotations

import numpy as np
import pytest
from reference_rasterizer import project, render_reference

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.gaussians import SH_C0, Gaussians
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.render import RenderOutput, eval_sh, render
from marionette.render.rasterizer import _EXP_LO, _exp_clamped
from marionette.render.sh import _basis, _eval_sh_one

W, H = 50, 40  # non-square; 4 × 3 tiles, the last column and row partial


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - b) ** 2))
    return np.inf if mse == 0 else 10 * np.log10(1.0 / mse)


def random_scene(seed: int, n: int = 200) -> tuple[Gaussians, Camera, np.ndarray]:
    """Overlapping anisotropic rotated Gaussians of SH degree ``seed % 4`` around a
    rotated, translated camera with an off-centre principal point and fx != fy."""
    rng = np.random.default_rng(seed)
    c = (seed % 4 + 1) ** 2
    # Spread in z from behind the camera to far ahead, wide in x/y so some are off-screen.
    means = rng.normal(size=(n, 3)) * [1.2, 1.0, 1.8] + [0.0, 0.0, 0.5]
    log_scales = np.log(rng.uniform(0.01, 0.4, (n, 3)))
    sh = rng.normal(0.0, 0.4, (n, c, 3))
    sh[:, 0] += rng.uniform(-1.5, 1.5, (n, 3))
    gaussians = Gaussians(means, rng.normal(size=(n, 4)), log_scales, rng.normal(1.0, 2.0, n), sh)
    k = np.array([[44.0, 0.0, 21.3], [0.0, 49.0, 17.6], [0.0, 0.0, 1.0]])
    camera_to_world = make_transform(axis_angle_to_matrix(rng.normal(0.0, 0.15, 3)), [0.2, -0.1, -3.0])
    camera = Camera(k, np.linalg.inv(camera_to_world), W, H)
    return gaussians, camera, rng.uniform(0.0, 1.0, 3)


@pytest.mark.parametrize("seed", range(8))
def test_matches_reference(seed):
    gaussians, camera, background = random_scene(seed)
    out = render(gaussians, camera, background)
    _image, _alpha, _depth = render_reference(gaussians, camera, background)

    # The scene exercises what it should: near-plane culling, Gaussians off-screen,
    # the x/z clamp of the Jacobian, and pixels stopped by the transmittance limit.
    z = camera.world_to_camera_points(gaussians.means.astype(np.float64))[:, 2]
    assert (z <= 0.2).any()
    proj = project(gaussians, camera)
    u = proj["mean2d"][:, 0]
    assert ((u < 0) | (u > W - 1)).any()
    assert (np.abs((u - camera.cx) / camera.fx) > 1.3 * W / (2 * camera.fx)).any()
    assert (_alpha > 1 - 2e-4).any()

    # Tolerance: the fast path computes in float32 with a polynomial exp (absolute
    # error < 3e-7), so alphas differ from the float64 reference by ~1e-6 and a
    # discrete decision (α >= 1/255, T < 1e-4, the box edge) can flip on a rare
    # pixel, changing it by at most ~0.011. 50 dB (RMS 3e-3) allows a few such
    # flips in 1920 pixels; any real mistake (half-pixel shift, conic sign,
    # depth order, SH sign) costs far more. (Typically the two agree to ~140 dB.)
    assert psnr(out.image, _image) >= 50.0
    assert psnr(out.alpha, _alpha) >= 50.0
    assert np.mean(np.abs(out.image - _image) > 1e-4) < 0.005  # flips stay rare
    both = (out.alpha > 0.5) & (_alpha > 0.5)
    np.testing.assert_allclose(out.depth[both], _depth[both], rtol=1e-3)


def test_output_types_and_ranges():
    gaussians, camera, background = random_scene(3)
    out = render(gaussians, camera, background)
    assert isinstance(out, RenderOutput)
    assert out.image.shape == (H, W, 3) and out.alpha.shape == (H, W) and out.depth.shape == (H, W)
    assert out.image.dtype == out.alpha.dtype == out.depth.dtype == np.float32
    assert out.image.min() >= 0.0 and out.image.max() <= 1.0
    assert out.alpha.min() >= 0.0 and out.alpha.max() <= 1.0
    assert (out.depth[out.alpha == 0] == 0).all()
    assert (out.depth[out.alpha > 0] > 0.2).all()


@pytest.mark.parametrize("n", [0, 5])
def test_empty_scene_is_background(n):
    """No Gaussians, or only ones behind the camera: exactly the background."""
    means = np.zeros((n, 3)) + [0.0, 0.0, -2.0]
    gaussians = Gaussians.from_rgb(means, np.full((n, 3), 0.3), np.full(n, 0.5))
    background = (0.25, 0.5, 0.125)
    out = render(gaussians, Camera.from_fov(W, H), background)
    assert (out.image == np.float32(background)).all()
    assert (out.alpha == 0).all() and (out.depth == 0).all()


@pytest.mark.parametrize("size, pixel", [((33, 25), (16, 12)), ((W, H), (10, 7)), ((W, H), (37, 30))])
def test_single_gaussian_peaks_at_projected_pixel(size, pixel):
    """An opaque Gaussian whose mean projects onto a pixel centre peaks there, with
    alpha 0.99, its colour, and its depth; (16, 12) is the centre of a 33 × 25 image."""
    camera = Camera.from_fov(*size, 60.0)
    z = 4.0
    mean = [(pixel[0] - camera.cx) * z / camera.fx, (pixel[1] - camera.cy) * z / camera.fy, z]
    gaussians = Gaussians.from_rgb(np.array([mean]), np.array([[0.9, 0.2, 0.1]]),
                                   np.array([0.05]), opacities=0.99)
    out = render(gaussians, camera, (0.0, 0.0, 0.0))
    row, col = np.unravel_index(np.argmax(out.alpha), out.alpha.shape)
    assert (col, row) == pixel
    assert out.alpha[row, col] == pytest.approx(0.99, abs=1e-5)
    np.testing.assert_allclose(out.image[row, col], 0.99 * np.array([0.9, 0.2, 0.1]), atol=1e-5)
    # Symmetric about the peak.
    np.testing.assert_allclose(out.alpha[row, col - 1], out.alpha[row, col + 1], rtol=1e-5)
    np.testing.assert_allclose(out.alpha[row - 1, col], out.alpha[row + 1, col], rtol=1e-5)
    np.testing.assert_allclose(out.depth[out.alpha > 0], z, rtol=1e-5)  # float32 Σ w z / Σ w


def test_background_colour_respected():
    gaussians, camera, _ = random_scene(1, n=40)
    a = render(gaussians, camera, (1.0, 1.0, 1.0))
    b = render(gaussians, camera, (0.0, 0.5, 1.0))
    empty = a.alpha == 0
    assert empty.any()
    assert (b.image[empty] == np.float32([0.0, 0.5, 1.0])).all()
    # Elsewhere the image moves by T * Δbackground, T = 1 - alpha (before clipping).
    t = (1 - a.alpha)[..., None]
    inside = (a.image > 0) & (a.image < 1) & (b.image > 0) & (b.image < 1)
    np.testing.assert_allclose((a.image - b.image)[inside],
                               (t * np.float32([1.0, 0.5, 0.0]))[inside], atol=1e-5)
    np.testing.assert_array_equal(a.alpha, b.alpha)


def test_camera_translation_shifts_image():
    """Splats on the plane z = 5 facing the camera: moving the camera by Δx shifts
    the image by -fx Δx / z pixels."""
    rng = np.random.default_rng(7)
    n, z, shift = 60, 5.0, 3
    camera = Camera.from_fov(W, H, 60.0)
    uv = rng.uniform([12, 8], [W - 13, H - 9], (n, 2))  # well inside, away from the borders
    means = np.column_stack([(uv[:, 0] - camera.cx) * z / camera.fx,
                             (uv[:, 1] - camera.cy) * z / camera.fy, np.full(n, z)])
    scales = np.column_stack([rng.uniform(0.05, 0.2, (n, 2)), np.full(n, 1e-3)])
    # Rotated about the optical axis (quaternions w, 0, 0, 1; the renderer normalises).
    quats = np.column_stack([np.cos(rng.uniform(0, np.pi, n)), np.zeros((n, 2)), np.ones(n)])
    gaussians = Gaussians.from_rgb(means, rng.uniform(0, 1, (n, 3)), scales,
                                   rng.uniform(0.3, 0.95, n), quats)
    dx = shift * z / camera.fx
    moved = camera.with_pose(make_transform(np.eye(3), [-dx, 0.0, 0.0]))  # camera centre at +dx
    a, b = render(gaussians, camera), render(gaussians, moved)
    np.testing.assert_allclose(b.image[:, :-shift], a.image[:, shift:], atol=2e-5)
    np.testing.assert_allclose(b.alpha[:, :-shift], a.alpha[:, shift:], atol=2e-5)
    assert np.abs(b.image[:, shift:] - a.image[:, shift:]).max() > 0.1  # it did move


def test_degenerate_gaussians():
    """A zero quaternion acts as the identity (as in the reference); a Gaussian whose
    scale overflows, or whose opacity is below 1/255, is culled rather than poisoning
    the image."""
    gaussians, camera, background = random_scene(2, n=50)
    quats = gaussians.quats.copy()
    quats[:10] = [1.0, 0.0, 0.0, 0.0]
    identity = render(Gaussians(gaussians.means, quats, gaussians.log_scales,
                                gaussians.opacity_logits, gaussians.sh), camera, background)
    quats[:10] = 0.0
    zero = render(Gaussians(gaussians.means, quats, gaussians.log_scales,
                            gaussians.opacity_logits, gaussians.sh), camera, background)
    np.testing.assert_array_equal(zero.image, identity.image)

    base = render(gaussians, camera, background)
    front = np.array([[0.0, 0.0, 1.0]]) @ np.linalg.inv(camera.world_to_camera)[:3, :3].T
    extra = Gaussians(np.repeat(front + camera.center, 2, axis=0), np.tile([1.0, 0, 0, 0], (2, 1)),
                      [[80.0, 0.0, 0.0], [-2.0, -2.0, -2.0]], [5.0, -200.0],
                      np.zeros((2, gaussians.sh.shape[1], 3)))
    out = render(Gaussians.concatenate([gaussians, extra]), camera, background)
    np.testing.assert_array_equal(out.image, base.image)


@pytest.mark.parametrize("background", [(1.0, 1.0), (0.5, 0.5, 1.5), (0.0, np.nan, 0.0), "white",
                                        (-0.1, 0.0, 0.0)])
def test_bad_background_raises(background):
    gaussians, camera, _ = random_scene(0, n=3)
    with pytest.raises(InputError, match="background"):
        render(gaussians, camera, background)


def test_bad_inputs_raise():
    gaussians, camera, _ = random_scene(0, n=3)
    with pytest.raises(InputError, match="camera"):
        render(gaussians, "camera")
    with pytest.raises(InputError, match="gaussians"):
        render(gaussians.means, camera)
    means = gaussians.means.copy()
    means[1, 2] = np.nan
    with pytest.raises(InputError, match="means"):
        render(gaussians.with_means(means), camera)


def test_exp_polynomial():
    """The vectorised exp of ``_blend``, run here as plain NumPy float32."""
    x = np.linspace(_EXP_LO, 0.0, 200_001).astype(np.float32)
    e = _exp_clamped.py_func(x)
    assert e.dtype == np.float32
    assert np.abs(e - np.exp(x.astype(np.float64))).max() < 3e-7
    assert _exp_clamped.py_func(np.float32(-30.0)) == pytest.approx(np.exp(_EXP_LO), abs=3e-7)
    # Below the clamp no opacity reaches the 1/255 cut.
    assert 0.99 * np.exp(_EXP_LO) < 1.0 / 255.0


@pytest.mark.parametrize("c", [1, 4, 9, 16])
def test_eval_sh_numpy_and_numba_agree(c):
    rng = np.random.default_rng(c)
    sh = rng.normal(size=(30, c, 3)).astype(np.float32)
    dirs = rng.normal(size=(30, 3))
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    _rgb = np.array([_eval_sh_one(sh, i, *unit[i]) for i in range(30)])
    np.testing.assert_allclose(eval_sh(sh, dirs), _rgb, atol=1e-6)


def test_eval_sh_values():
    """Degree 0 is the 3DGS DC rule; degree 1 follows the reference signs (-y, z, -x)."""
    sh = np.zeros((2, 4, 3), np.float32)
    sh[:, 0] = [0.4, -0.2, 3.0]
    sh[1, 1:, 0] = [1.0, 2.0, 3.0]
    dirs = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    rgb = eval_sh(sh, dirs)
    np.testing.assert_allclose(rgb[0], [0.5 + SH_C0 * 0.4, 0.5 - SH_C0 * 0.2, 0.5 + SH_C0 * 3.0], rtol=1e-6)
    c1 = 0.4886025119029199
    assert rgb[1, 0] == pytest.approx(0.5 + SH_C0 * 0.4 + c1 * (2.0 * 0.8 - 3.0 * 0.6), rel=1e-6)
    # Clamped at 0 from below only.
    dark = eval_sh(np.full((1, 1, 3), -10.0), np.array([[0.0, 0.0, 1.0]]))
    bright = eval_sh(np.full((1, 1, 3), 10.0), np.array([[0.0, 0.0, 1.0]]))
    assert (dark == 0).all() and (bright > 1).all()


def test_sh_basis_is_orthonormal():
    """∫ Y_i Y_j dΩ = δ_ij over the sphere, which pins every constant and every
    polynomial of degrees 0 to 3 (up to sign; the signs are the reference's)."""
    n = 400_000
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n  # Fibonacci sphere: near-uniform points
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * k
    dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    y = _basis(dirs, 16)
    gram = 4 * np.pi * (y.T @ y) / n
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-3)
