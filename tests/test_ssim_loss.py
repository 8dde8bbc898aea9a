"""D-SSIM of the reconstruction's loss: value against scikit-image and a loop twin, gradient against finite
differences."""

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from marionette.reconstruct.ssim import C1, C2, dssim_and_grad, ssim_window


def _ssim_map_by_loops(x: np.ndarray, y: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """SSIM per pixel and channel, window sums written out, zero outside the frame (the twin)."""
    h, w, c = x.shape
    r = len(kernel) // 2
    window = np.outer(kernel, kernel)
    pad = ((r, r), (r, r), (0, 0))
    xp, yp = np.pad(x, pad), np.pad(y, pad)
    out = np.empty_like(x)
    for i in range(h):
        for j in range(w):
            for k in range(c):
                px, py = xp[i:i + 2 * r + 1, j:j + 2 * r + 1, k], yp[i:i + 2 * r + 1, j:j + 2 * r + 1, k]
                mx, my = (window * px).sum(), (window * py).sum()
                vx = (window * px * px).sum() - mx ** 2
                vy = (window * py * py).sum() - my ** 2
                cxy = (window * px * py).sum() - mx * my
                out[i, j, k] = (2 * mx * my + C1) * (2 * cxy + C2) / ((mx ** 2 + my ** 2 + C1) * (vx + vy + C2))
    return out


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    target = rng.random((13, 17, 3))
    image = np.clip(target + 0.2 * rng.standard_normal(target.shape), 0, 1)
    return image, target


def test_loss_is_one_minus_the_mean_of_the_loop_twins_ssim(pair):
    image, target = pair
    kernel = ssim_window(5, 1.0)
    loss, _ = dssim_and_grad(image, target, kernel=kernel)
    assert loss == pytest.approx(1 - _ssim_map_by_loops(image, target, kernel).mean(), abs=1e-12)


def test_ssim_matches_scikit_image_away_from_the_border():
    rng = np.random.default_rng(0)
    target = rng.random((40, 48, 3))
    image = np.clip(target + 0.1 * rng.standard_normal(target.shape), 0, 1)
    # scikit-image's Gaussian SSIM (σ 1.5, truncated at 3.5σ: the same 11 taps) pads differently at the border,
    # so compare the maps 5 px in.
    _, ref = structural_similarity(image, target, channel_axis=2, data_range=1.0, gaussian_weights=True,
                                   sigma=1.5, use_sample_covariance=False, full=True)
    ours = _ssim_map_by_loops(image, target, ssim_window())
    np.testing.assert_allclose(ours[5:-5, 5:-5], ref[5:-5, 5:-5], atol=1e-10)


def test_a_perfect_render_has_zero_loss_and_no_gradient(pair):
    _, target = pair
    loss, grad = dssim_and_grad(target, target)
    assert loss == pytest.approx(0.0, abs=1e-12)
    assert np.abs(grad).max() < 1e-10


@pytest.mark.parametrize("size", [5, 11])
def test_gradient_matches_central_differences(pair, size):
    image, target = pair
    kernel = ssim_window(size, 1.5)
    _, grad = dssim_and_grad(image, target, kernel=kernel)
    rng = np.random.default_rng(size)
    eps = 1e-6
    for flat in rng.choice(image.size, 40, replace=False):
        idx = np.unravel_index(flat, image.shape)
        up, down = image.copy(), image.copy()
        up[idx] += eps
        down[idx] -= eps
        numeric = (dssim_and_grad(up, target, kernel=kernel)[0] - dssim_and_grad(down, target, kernel=kernel)[0])
        assert grad[idx] == pytest.approx(numeric / (2 * eps), rel=1e-5, abs=1e-9)


def test_a_step_down_the_gradient_lowers_the_loss(pair):
    image, target = pair
    loss, grad = dssim_and_grad(image, target)
    assert dssim_and_grad(image - 0.5 * grad / np.abs(grad).max() * 1e-2, target)[0] < loss
