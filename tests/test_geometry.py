import numpy as np
import pytest

from marionette.geometry import (
    axis_angle_to_matrix,
    invert_transform,
    make_transform,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    quaternion_to_matrix,
    rotation_angle_deg,
    se3_interpolate,
    umeyama,
)


def random_rotations(n, seed=0):
    rng = np.random.default_rng(seed)
    return axis_angle_to_matrix(rng.normal(size=(n, 3)) * 1.5)


def test_rotations_are_proper():
    r = random_rotations(50)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)


def test_quaternion_round_trip_and_sign():
    r = random_rotations(100)
    q = matrix_to_quaternion(r)
    assert np.all(q[:, 0] >= 0)
    assert np.allclose(quaternion_to_matrix(q), r, atol=1e-12)


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0]])
def test_rotation_by_pi(axis):
    axis = np.array(axis, float) / np.linalg.norm(axis)
    r = axis_angle_to_matrix(np.pi * axis)
    q = matrix_to_quaternion(r)
    assert np.all(np.isfinite(q))
    assert np.allclose(quaternion_to_matrix(q), r, atol=1e-12)
    assert rotation_angle_deg(r) == pytest.approx(180.0)


def test_frozen_values():
    # 90° about z maps x to y; quaternion (cos 45°, 0, 0, sin 45°).
    r = axis_angle_to_matrix([0, 0, np.pi / 2])
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(matrix_to_quaternion(r), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)])


def test_axis_angle_round_trip_small_angles():
    v = np.array([[1e-10, 0, 0], [0, 1e-5, 2e-5], [0.3, -0.2, 0.1]])
    assert np.allclose(matrix_to_axis_angle(axis_angle_to_matrix(v)), v, atol=1e-12)
    assert np.allclose(axis_angle_to_matrix(np.zeros(3)), np.eye(3))


def test_umeyama_recovers_rigid_and_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(40, 3))
    r = random_rotations(1, seed=2)[0]
    t = np.array([0.5, -2.0, 3.0])
    rr, tt, s = umeyama(src, src @ r.T + t)
    assert np.allclose(rr, r) and np.allclose(tt, t) and s == 1.0
    rr, tt, s = umeyama(src, 2.5 * src @ r.T + t, with_scale=True)
    assert np.allclose(rr, r) and np.allclose(tt, t) and s == pytest.approx(2.5)


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(30, 3))
    mirrored = src * [1, 1, -1]
    r, _, _ = umeyama(src, mirrored)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_invert_and_interpolate():
    r = random_rotations(2, seed=4)
    a, b = make_transform(r[0], [1, 2, 3]), make_transform(r[1], [-1, 0, 2])
    assert np.allclose(invert_transform(a) @ a, np.eye(4))
    assert np.allclose(se3_interpolate(a, b, 0.0), a)
    assert np.allclose(se3_interpolate(a, b, 1.0), b)
    mid = se3_interpolate(a, b, 0.5)
    # Halfway in angle: the rotation from a to mid equals that from mid to b.
    assert np.allclose(mid[:3, :3].T @ b[:3, :3], a[:3, :3].T @ mid[:3, :3])
    assert np.allclose(mid[:3, 3], [0, 1, 2.5])


def test_quaternion_product_composes_rotations_and_turning_gaussians_matches_the_matrix_route():
    from marionette.gaussians import Gaussians
    from marionette.geometry import quaternion_multiply

    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(50, 4)), rng.normal(size=(50, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(quaternion_to_matrix(quaternion_multiply(a, b)),
                               quaternion_to_matrix(a) @ quaternion_to_matrix(b), atol=1e-12)
    # Slow route: each orientation to a matrix, turned, and back (w >= 0 either way).
    g = Gaussians.from_rgb(rng.normal(size=(50, 3)), rng.uniform(size=(50, 3)), np.full(50, 0.1),
                           quats=rng.normal(size=(50, 4)))
    turns = quaternion_to_matrix(a)
    expected = matrix_to_quaternion(turns @ quaternion_to_matrix(g.quats))
    np.testing.assert_allclose(g.turned(a).quats, expected, atol=1e-6)


def test_turning_by_group_is_turning_each_gaussian_by_its_groups_quaternion():
    """``turned(quats (P, 4), labels)`` (the numba kernel a moving target's frames use) against the
    NumPy product on the quaternions picked per Gaussian, and the one- and per-Gaussian forms."""
    from marionette.errors import InputError
    from marionette.gaussians import Gaussians
    from marionette.geometry import quaternion_multiply

    rng = np.random.default_rng(3)
    g = Gaussians.from_rgb(rng.normal(size=(200, 3)), rng.uniform(size=(200, 3)), np.full(200, 0.1),
                           quats=rng.normal(size=(200, 4)) * rng.uniform(0.1, 10, size=(200, 1)))
    turns = rng.normal(size=(3, 4))
    turns /= np.linalg.norm(turns, axis=1, keepdims=True)
    labels = rng.integers(0, 3, size=200)
    own = g.quats.astype(np.float64) / np.linalg.norm(g.quats.astype(np.float64), axis=1, keepdims=True)
    expected = quaternion_multiply(turns[labels], own)
    expected *= np.where(expected[:, :1] < 0, -1.0, 1.0)
    np.testing.assert_allclose(g.turned(turns, labels).quats, expected, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(g.turned(turns, labels).quats, g.turned(turns[labels]).quats)
    np.testing.assert_array_equal(g.turned(turns[1]).quats, g.turned(turns, np.ones(200, int)).quats)
    assert np.all(g.turned(turns, labels).quats[:, 0] >= 0)
    with pytest.raises(InputError):
        g.turned(turns, np.full(200, 3))
    with pytest.raises(InputError):
        g.turned(turns)  # three quaternions for 200 Gaussians, no labels
