"""Camera motion: synthetic moving cameras, their estimation from the background, and their removal."""

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from marionette.errors import InputError
from marionette.geometry import invert_transform, rotation_angle_deg, transform_points
from marionette.source import camera_motion
from marionette.source.camera_motion import CameraMotion, estimate_camera_motion, to_world
from marionette.synthetic import make_scene

SIZE = (160, 120)


@pytest.fixture(scope="module")
def scenes():
    return {cm: make_scene("oscillation", num_frames=24, size=SIZE, seed=1, camera_motion=cm)
            for cm in ("static", "pan", "handheld")}


def test_static_camera_is_unchanged(scenes):
    plain = make_scene("oscillation", num_frames=24, size=SIZE, seed=1)
    assert np.array_equal(plain.frames, scenes["static"].frames)
    np.testing.assert_array_equal(scenes["static"].camera_poses, np.tile(np.eye(4), (24, 1, 1)))


@pytest.mark.parametrize("kind, low, high", [("pan", 10.0, 20.0), ("handheld", 0.5, 5.0)])
def test_moving_camera_scene(scenes, kind, low, high):
    sc = scenes[kind]
    np.testing.assert_allclose(sc.camera_poses[0], np.eye(4), atol=1e-12)
    angles = rotation_angle_deg(sc.camera_poses[:, :3, :3])
    assert low < angles.max() < high
    # Same object motion as with a static camera; only the view changes.
    np.testing.assert_allclose(sc.poses, scenes["static"].poses)
    assert np.array_equal(sc.frames[0], scenes["static"].frames[0])
    assert np.abs(sc.frames[-1].astype(int) - scenes["static"].frames[-1]).mean() > 3
    # Depths lifted in camera t and taken back through the camera and object motion land on the surface.
    t = len(sc.frames) - 1
    v, u = np.nonzero(np.isfinite(sc.depths[t]))
    assert np.isfinite(sc.depths[t][sc.masks[t]]).mean() > 0.98
    rays = np.stack([(u - sc.camera.cx) / sc.camera.fx, (v - sc.camera.cy) / sc.camera.fy, np.ones(len(u))], 1)
    back = invert_transform(sc.poses[0, t]) @ invert_transform(sc.camera_poses[t])
    gap, _ = cKDTree(sc.part_points[0]).query(transform_points(back, rays * sc.depths[t][v, u, None]))
    assert gap.max() < 0.04  # half the diagonal of the 0.05 point grid


@pytest.mark.parametrize("kind", ["pan", "handheld"])
def test_estimates_camera_rotation(scenes, kind):
    sc = scenes[kind]
    est = estimate_camera_motion(sc.frames, sc.masks, sc.camera.K)
    assert not est.static
    assert est.world_to_camera.shape == (24, 4, 4)
    np.testing.assert_allclose(est.world_to_camera[0], np.eye(4))
    err = rotation_angle_deg(est.world_to_camera[:, :3, :3] @ np.swapaxes(sc.camera_poses[:, :3, :3], 1, 2))
    assert np.median(err[1:]) < 0.3
    assert err.max() < 1.0
    assert est.inlier_ratio[1:].min() > 0.8
    assert est.residual_px.max() < 1.0


def test_the_rotations_do_not_follow_rounding_noise(scenes, monkeypatch):
    """Another machine's SVD differs in the last bits; each frame's rotation seeds the next frames' (the
    directions of the tracks found there), so the bits would carry on into RANSAC's choices. Each rotation is
    rounded onto a grid (:mod:`marionette.reproducible`): the cameras come out the same bits."""
    sc = scenes["pan"]
    reference = estimate_camera_motion(sc.frames, sc.masks, sc.camera.K)
    assert reference.model == "rotation"
    rng = np.random.default_rng(0)
    exact = camera_motion.rotation_between_directions
    monkeypatch.setattr(camera_motion, "rotation_between_directions",
                        lambda src, dst: (r := exact(src, dst)) * (1 + 1e-15 * rng.standard_normal(r.shape)))
    perturbed = estimate_camera_motion(sc.frames, sc.masks, sc.camera.K)
    assert np.array_equal(perturbed.world_to_camera, reference.world_to_camera)
    assert np.array_equal(perturbed.inlier_ratio, reference.inlier_ratio)


def test_static_camera_detected(scenes):
    sc = scenes["static"]
    est = estimate_camera_motion(sc.frames, sc.masks, sc.camera.K)
    assert est.static and est.displacement_px < 0.5
    np.testing.assert_array_equal(est.world_to_camera, np.tile(np.eye(4), (24, 1, 1)))


def test_a_static_camera_stays_static_through_motion_blurred_frames():
    # The few background tracks that survive a smear slide along it; they say nothing about the camera.
    sc = make_scene("oscillation", num_frames=32, seed=0)
    frames = sc.frames.copy()
    kernel = np.zeros((61, 61), np.float32)
    kernel[30, :] = 1 / 61
    for t in range(12, 16):
        frames[t] = cv2.filter2D(frames[t], -1, kernel)
    est = estimate_camera_motion(frames, sc.masks, sc.camera.K)
    assert est.static and est.displacement_px < 0.5


def test_to_world_removes_camera_motion(scenes):
    sc = scenes["handheld"]
    truth = CameraMotion(sc.camera_poses, False, np.ones(24), np.zeros(24), 0.0, 0)
    # What a pose fit sees in camera t: world motion followed by the camera's view.
    poses_cam = sc.camera_poses[None] @ sc.poses  # (P, T, 4, 4)
    assert np.abs(poses_cam - sc.poses).max() > 1e-2
    np.testing.assert_allclose(to_world(poses_cam, truth), sc.poses, atol=1e-12)
    # Per point: camera-t coordinates taken back to the world are the moved world points.
    t = 17
    x_cam = transform_points(poses_cam[0, t], sc.part_points[0])
    np.testing.assert_allclose(transform_points(invert_transform(sc.camera_poses[t]), x_cam),
                               transform_points(to_world(poses_cam, truth)[0, t], sc.part_points[0]), atol=1e-12)
    with pytest.raises(ValueError):
        to_world(poses_cam[:, :5], truth)


def test_bad_inputs(scenes):
    sc = scenes["static"]
    with pytest.raises(InputError):
        estimate_camera_motion(sc.frames, sc.masks, np.eye(2))
    with pytest.raises(InputError):
        estimate_camera_motion(sc.frames, sc.masks[:3], sc.camera.K)
