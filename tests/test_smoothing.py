"""SE(3) pose smoothing: against a dense reference solver and on synthetic ground truth."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle, rotation_angle_deg
from marionette.source.smoothing import _LAMBDA_1, _smooth_trajectory, jitter, smooth_poses
from marionette.synthetic import make_scene


def _random_walk(rng, t_count, step_deg=15.0):
    """Rotations (T, 3, 3) with large random steps and positions (T, 3): a strongly non-flat case."""
    steps = axis_angle_to_matrix(rng.normal(size=(t_count, 3)) * np.radians(step_deg))
    rot = np.empty((t_count, 3, 3))
    rot[0] = np.eye(3)
    for t in range(1, t_count):
        rot[t] = rot[t - 1] @ steps[t]
    return rot, np.cumsum(rng.normal(size=(t_count, 3)), axis=0)


def _huber_vectors(e, c):
    """Vectors (N, 3) with |u|² = ρ(|e|): ``r²`` up to ``c``, ``2 c r - c²`` beyond."""
    r = np.linalg.norm(e, axis=1, keepdims=True)
    with np.errstate(invalid="ignore"):  # inf - inf in the branch unused when c is infinite
        rho = np.where(r <= c, r**2, 2 * c * r - c**2)
    return e * np.sqrt(rho) / np.maximum(r, 1e-300)


def _reference(rot, pos, lam, c_rot=np.inf, c_pos=np.inf):
    """The module's objective minimised by dense least squares, frames 1.. free: (T, 3, 3), (T, 3)."""
    t_count = len(rot)

    def unpack(x):
        x = x.reshape(t_count - 1, 6)
        r = np.concatenate([rot[:1], rot[1:] @ axis_angle_to_matrix(x[:, :3])])
        return r, np.concatenate([pos[:1], pos[1:] + x[:, 3:]])

    def residuals(x):
        r, p = unpack(x)
        e_rot = matrix_to_axis_angle(np.swapaxes(rot[1:], -1, -2) @ r[1:])
        omega = matrix_to_axis_angle(np.swapaxes(r[:-1], -1, -2) @ r[1:])
        return np.concatenate([
            _huber_vectors(e_rot, c_rot).ravel(), _huber_vectors(p[1:] - pos[1:], c_pos).ravel(),
            np.sqrt(lam) * np.diff(omega, axis=0).ravel(), np.sqrt(lam) * np.diff(p, n=2, axis=0).ravel(),
        ])

    x = least_squares(residuals, np.zeros(6 * (t_count - 1)), xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    return unpack(x)


def _angle_between(a, b):
    """Rotation angle in degrees between rotations (..., 3, 3)."""
    return rotation_angle_deg(np.swapaxes(a, -1, -2) @ b)


@pytest.mark.parametrize("lam", [0.3, 5.0])
def test_solver_matches_dense_reference(lam):
    rot, pos = _random_walk(np.random.default_rng(1), 9)
    rot_s, pos_s = _smooth_trajectory(rot, pos, lam, None)
    _rot, _pos = _reference(rot, pos, lam)
    # Both solve the same smooth problem to ~1e-10; least_squares stops a little earlier.
    assert _angle_between(rot_s, _rot).max() < 1e-5
    np.testing.assert_allclose(pos_s, _pos, atol=1e-6)
    # The smoother really moved things: this is not a trivial case.
    assert _angle_between(rot_s, rot).max() > 3.0


def test_robust_solver_matches_dense_huber_reference():
    rng = np.random.default_rng(2)
    rot, pos = _random_walk(rng, 10, step_deg=8.0)
    rot[5] = rot[5] @ axis_angle_to_matrix([0.5, 0.0, 0.0])  # a ~30° outlier frame
    c_rot, c_pos = 0.05, 0.3
    rot_s, pos_s = _smooth_trajectory(rot, pos, 2.0, lambda norms: np.array([c_rot, c_pos]))
    _rot, _pos = _reference(rot, pos, 2.0, c_rot, c_pos)
    assert _angle_between(rot_s, _rot).max() < 1e-4
    np.testing.assert_allclose(pos_s, _pos, atol=1e-5)


def test_strength_zero_and_frame_zero():
    rng = np.random.default_rng(3)
    rot, pos = _random_walk(rng, 12)
    poses = make_transform(rot, pos - pos[0])[None]
    np.testing.assert_array_equal(smooth_poses(poses, 0.0), poses)
    out = smooth_poses(poses, 2.0, centers=rng.normal(size=(1, 3)))
    np.testing.assert_array_equal(out[0, 0], np.eye(4))
    assert not np.allclose(out, poses)
    rot_out = out[..., :3, :3]
    np.testing.assert_allclose(rot_out @ np.swapaxes(rot_out, -1, -2), np.broadcast_to(np.eye(3), rot_out.shape),
                               atol=1e-12)
    np.testing.assert_array_equal(out[..., 3, :], poses[..., 3, :])


def test_constant_velocity_is_kept_exactly():
    # A spin of 7° per frame about a tilted axis through the part's centre, which drifts at constant velocity.
    t = np.arange(20)
    axis = np.array([0.2, 1.0, -0.3]) / np.linalg.norm([0.2, 1.0, -0.3])
    center = np.array([0.5, -0.2, 4.0])
    r = axis_angle_to_matrix(np.radians(7.0) * t[:, None] * axis)
    poses = make_transform(r, center - r @ center + 0.05 * t[:, None] * np.array([1.0, 0.3, -0.5]))[None]
    assert jitter(poses)[0] < 1e-9
    np.testing.assert_allclose(smooth_poses(poses, 3.0, centers=center[None]), poses, atol=1e-9)
    # Pure translation at constant velocity, whatever the centre.
    shift = make_transform(np.eye(3), 0.1 * t[:, None] * np.array([1.0, -2.0, 0.5]))[None]
    np.testing.assert_allclose(smooth_poses(shift, 3.0), shift, atol=1e-12)


def _noisy(scene, rot_deg, shift, seed):
    """Ground-truth poses with a random rotation about each part's centroid and a shift, per frame."""
    rng = np.random.default_rng(seed)
    k_count, t_count = scene.poses.shape[:2]
    cent = scene.centroids()
    rn = axis_angle_to_matrix(rng.normal(size=(k_count, t_count, 3)) * np.radians(rot_deg) / np.sqrt(3))
    tn = rng.normal(size=(k_count, t_count, 3)) * shift / np.sqrt(3)
    noise = make_transform(rn, cent - np.einsum("ktij,ktj->kti", rn, cent) + tn)
    noise[:, 0] = np.eye(4)
    return noise @ scene.poses


def _signed_angle(poses, axis):
    """Rotation angle about ``axis`` (3,) in degrees of poses (T, 4, 4)."""
    return np.degrees(matrix_to_axis_angle(poses[:, :3, :3]) @ axis)


@pytest.fixture(scope="module")
def oscillation():
    # 32 frames hold 1.75-2.5 periods: periods of 13-18 frames.
    return make_scene("oscillation", num_frames=32, size=(64, 48), seed=4)


def test_oscillation_jitter_removed_amplitude_kept(oscillation):
    gt = oscillation.poses
    radius = oscillation.radii()[0]
    noisy = _noisy(oscillation, 1.0, 0.01 * radius, seed=0)
    out = smooth_poses(noisy, centers=oscillation.centroids()[:, 0])
    err_in = np.sqrt((_angle_between(noisy[..., :3, :3], gt[..., :3, :3]) ** 2).mean())
    err_out = np.sqrt((_angle_between(out[..., :3, :3], gt[..., :3, :3]) ** 2).mean())
    # The 12.8-18-frame periods lose up to 3.5 % of their amplitude, which limits the gain here.
    assert err_out < 0.9 * err_in
    # Jitter beyond the motion's own second difference drops by more than half.
    assert jitter(out)[0] - jitter(gt)[0] < 0.5 * (jitter(noisy)[0] - jitter(gt)[0])
    # Amplitude of the swing about its axis: peak-to-peak kept to >= 95 %.
    axis = matrix_to_axis_angle(gt[0, np.argmax(rotation_angle_deg(gt[0, :, :3, :3])), :3, :3])
    axis /= np.linalg.norm(axis)
    swing, swing_gt = _signed_angle(out[0], axis), _signed_angle(gt[0], axis)
    assert np.ptp(swing_gt) > 35.0
    assert np.ptp(swing) >= 0.95 * np.ptp(swing_gt)
    # The centroid path gets closer to the truth too.
    c0 = oscillation.centroids()[:, 0]

    def path(poses):
        return np.einsum("ktij,kj->kti", poses[..., :3, :3], c0) + poses[..., :3, 3]

    truth = oscillation.centroids()
    assert (np.linalg.norm(path(out) - truth, axis=-1).mean()
            < 0.8 * np.linalg.norm(path(noisy) - truth, axis=-1).mean())


def test_clean_oscillation_barely_changes(oscillation):
    out = smooth_poses(oscillation.poses, centers=oscillation.centroids()[:, 0])
    err = _angle_between(out[..., :3, :3], oscillation.poses[..., :3, :3])[0]
    amplitude = rotation_angle_deg(oscillation.poses[0, :, :3, :3]).max()
    # Periods of 12.8 frames or more keep >= 96.5 % of their amplitude; the free last frames bend a bit more.
    assert err[:-3].max() < 0.04 * amplitude
    assert err.max() < 0.06 * amplitude


def test_yaw_ramp_unbiased():
    scene = make_scene("outofplane", num_frames=24, size=(64, 48), seed=1)
    gt = scene.poses
    axis = matrix_to_axis_angle(gt[0, -1, :3, :3])
    axis /= np.linalg.norm(axis)
    assert abs(_signed_angle(gt[0], axis)[-1]) > 80.0
    noisy = _noisy(scene, 1.0, 0.0, seed=5)
    out = smooth_poses(noisy, centers=scene.centroids()[:, 0])
    bias = _signed_angle(out[0], axis) - _signed_angle(gt[0], axis)
    assert abs(bias.mean()) < 0.25
    assert abs(bias[-1]) < 1.0
    # A constant-velocity ramp itself is left alone.
    np.testing.assert_allclose(smooth_poses(gt, centers=scene.centroids()[:, 0]), gt, atol=1e-9)


def test_outlier_frame_is_pulled_in():
    t_count = 30
    r = axis_angle_to_matrix(np.radians(3.0) * np.arange(t_count)[:, None] * np.array([0.0, 1.0, 0.0]))
    rng = np.random.default_rng(6)
    noise = axis_angle_to_matrix(rng.normal(size=(t_count, 3)) * np.radians(0.5))
    noise[0] = np.eye(3)
    noise[15] = axis_angle_to_matrix([np.radians(15.0), 0.0, 0.0])
    gt = make_transform(r, np.zeros(3))[None]
    noisy = make_transform(r @ noise, np.zeros(3))[None]
    err = {robust: _angle_between(smooth_poses(noisy, robust=robust)[0, :, :3, :3], r) for robust in (True, False)}
    assert err[False][14:17].max() > 4.0
    assert err[True][14:17].max() < 2.5  # the Huber loss still gives it a bounded pull
    assert jitter(smooth_poses(noisy))[0] < 0.3 * jitter(noisy)[0]
    np.testing.assert_allclose(smooth_poses(gt), gt, atol=1e-9)


def test_jitter_frozen_values():
    # One frame turned by d: velocities 0, d, -d, 0 give second differences d, -2d, d, RMS d √2.
    angles = np.radians([0.0, 0.0, 2.0, 0.0, 0.0])
    poses = make_transform(axis_angle_to_matrix(angles[:, None] * [1.0, 0.0, 0.0]), np.zeros(3))[None]
    np.testing.assert_allclose(jitter(poses), [2.0 * np.sqrt(2.0)], rtol=1e-9)
    np.testing.assert_array_equal(jitter(poses[:, :2]), [0.0])
    assert jitter(np.tile(np.eye(4), (3, 6, 1, 1))).shape == (3,)


def test_strength_unit_is_the_cutoff_period():
    # A sinusoid with the cutoff period (5 frames at strength 1, 10 at 2) keeps half its amplitude.
    assert np.isclose(1.0 / (1.0 + 16 * _LAMBDA_1 * np.sin(np.pi / 5.0) ** 4), 0.5)
    t = np.arange(400)
    for strength, period in ((1.0, 5.0), (2.0, 2 * np.pi / (2 * np.arcsin(np.sin(np.pi / 5) / 2)))):
        angles = np.radians(0.5) * np.sin(2 * np.pi * t / period)
        poses = make_transform(axis_angle_to_matrix(angles[:, None] * [0.0, 0.0, 1.0]), np.zeros(3))[None]
        out = np.degrees(matrix_to_axis_angle(smooth_poses(poses, strength, robust=False)[0, :, :3, :3])[:, 2])
        inner = slice(100, 300)  # away from the ends
        gain = np.sqrt((out[inner] ** 2).mean() / (np.degrees(angles[inner]) ** 2).mean())
        assert abs(gain - 0.5) < 0.02


@pytest.mark.parametrize("kwargs, message", [
    ({"poses": np.zeros((2, 3, 3))}, "shape"),
    ({"poses": np.full((1, 3, 4, 4), np.nan)}, "NaN"),
    ({"strength": -1.0}, "strength"),
    ({"strength": float("nan")}, "strength"),
    ({"centers": np.zeros((2, 3))}, "centers"),
])
def test_bad_input(kwargs, message):
    args = {"poses": np.tile(np.eye(4), (1, 5, 1, 1)), "strength": 1.0} | kwargs
    poses, strength = args.pop("poses"), args.pop("strength")
    with pytest.raises(InputError, match=message):
        smooth_poses(poses, strength, **args)
