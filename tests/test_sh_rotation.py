"""SH coefficients turn with their Gaussians: checked against eval_sh at turned directions and a render."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.camera import Camera
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_quaternion
from marionette.reconstruct._init import pose_gaussians
from marionette.render import eval_sh, render
from marionette.render.sh import rotate_sh, sh_rotations


def random_rotations(rng: np.random.Generator, count: int) -> np.ndarray:
    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axis_angle_to_matrix(axes * rng.uniform(0.2, 3.0, (count, 1)))


@pytest.mark.parametrize("coefficients", [4, 9, 16])
def test_turned_coefficients_show_the_colour_of_the_turned_back_direction(coefficients):
    """eval_sh(M sh, d) = eval_sh(sh, Rᵀ d) for every band, rotation and direction."""
    rng = np.random.default_rng(coefficients)
    n = 200
    sh = rng.normal(0, 0.3, (n, coefficients, 3)).astype(np.float32)
    sh[:, 0] += 2.0  # keep colours above the clamp at 0, which would hide differences
    rotations = random_rotations(rng, 5)
    labels = rng.integers(0, 5, n)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    back = np.einsum("nji,nj->ni", rotations[labels], dirs)  # Rᵀ d
    turned = rotate_sh(sh, rotations, labels)
    assert turned.dtype == np.float32 and turned.shape == sh.shape
    np.testing.assert_allclose(eval_sh(turned, dirs), eval_sh(sh, back), atol=2e-5)
    np.testing.assert_array_equal(turned[:, 0], sh[:, 0])  # the DC term has no direction


def test_band_matrices_are_orthogonal_and_compose():
    rng = np.random.default_rng(1)
    r1, r2 = random_rotations(rng, 2)
    m1, m2, m21 = sh_rotations(np.stack([r1, r2, r2 @ r1]), 16)
    np.testing.assert_allclose(m1 @ m1.T, np.eye(16), atol=1e-12)
    np.testing.assert_allclose(m2 @ m1, m21, atol=1e-12)
    np.testing.assert_allclose(sh_rotations(np.eye(3)[None], 16)[0], np.eye(16), atol=1e-12)
    # Band 1 is exact: the rotation's own entries, permuted and signed, with no solve in between.
    np.testing.assert_array_equal(np.sort(np.abs(m1[1:4, 1:4]).ravel()), np.sort(np.abs(r1).ravel()))
    band_mask = np.zeros((16, 16), bool)
    for lo, hi in ((0, 1), (1, 4), (4, 9), (9, 16)):
        band_mask[lo:hi, lo:hi] = True
    assert not np.any(m1[~band_mask])


def test_degree_zero_is_returned_as_is():
    sh = np.ones((3, 1, 3), np.float32)
    assert rotate_sh(sh, np.eye(3)[None], np.zeros(3, int)) is sh


def scene(rng: np.random.Generator, n: int = 30) -> Gaussians:
    sh = rng.normal(0, 0.25, (n, 16, 3)).astype(np.float32)
    sh[:, 0] = rng.uniform(-0.5, 0.5, (n, 3))
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    return Gaussians(rng.normal(0, 0.3, (n, 3)).astype(np.float32), quats,
                     np.log(rng.uniform(0.05, 0.15, (n, 3))).astype(np.float32),
                     np.full(n, 1.0, np.float32), sh)


def test_a_turned_scene_renders_as_the_scene_seen_from_the_turned_back_camera():
    """Means, orientations and view-dependent colours all turn: rendering (R μ, q_R ⊗ q, M sh) with camera W
    gives the image of (μ, q, sh) with camera W R."""
    rng = np.random.default_rng(2)
    gaussians = scene(rng)
    rotation = axis_angle_to_matrix(np.array([0.3, 1.1, -0.4]))
    k = np.array([[80.0, 0, 32], [0, 80.0, 32], [0, 0, 1]])
    view = make_transform(np.eye(3), np.array([0.0, 0.0, 3.0]))
    turned = gaussians.with_means((gaussians.means.astype(np.float64) @ rotation.T).astype(np.float32)
                                  ).turned(matrix_to_quaternion(rotation))
    a = render(turned, Camera(k, view, 64, 64)).image
    b = render(gaussians, Camera(k, view @ make_transform(rotation, np.zeros(3)), 64, 64)).image
    unturned_sh = render(Gaussians(turned.means, turned.quats, turned.log_scales, turned.opacity_logits,
                                   gaussians.sh), Camera(k, view, 64, 64)).image
    assert np.abs(a - b).max() < 2e-3
    assert np.abs(unturned_sh - b).max() > 0.05  # the colours do depend on the view: the test can fail


def test_posed_reconstruction_turns_its_colours_with_each_part():
    rng = np.random.default_rng(3)
    gaussians = scene(rng, 20)
    parts = np.repeat([0, 1], 10)
    poses = np.stack([make_transform(axis_angle_to_matrix(v), t) for v, t in
                      (([0.2, -0.5, 0.1], [0.1, 0.0, 0.2]), ([-0.7, 0.3, 0.9], [0.0, -0.2, 0.1]))])
    posed = pose_gaussians(gaussians, parts, poses)
    np.testing.assert_allclose(posed.sh, rotate_sh(gaussians.sh, poses[:, :3, :3], parts), atol=0)
