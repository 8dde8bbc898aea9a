"""Playback controls (looping, reversal, motion scales) and camera paths."""

import json

import numpy as np
import pytest
from test_transfer import prior_from_motion

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.geometry import invert_transform, matrix_to_axis_angle, rotation_angle_deg
from marionette.render.camera_path import camera_path, load_camera_path
from marionette.transfer.controls import retime, scale_motion, source_times


def turning_prior(frames=6):
    t = np.linspace(0.0, 1.0, frames)[:, None]
    return prior_from_motion(t * [0.0, 1.0, 0.2], t * [0.5, 0.0, -0.5])


def test_source_times_per_loop_mode():
    np.testing.assert_allclose(source_times(7, 4, loop="hold"), [0, 1, 2, 3, 4, 4, 4])
    np.testing.assert_allclose(source_times(7, 4, loop="repeat"), [0, 1, 2, 3, 4, 0, 1])
    np.testing.assert_allclose(source_times(10, 4, loop="pingpong"), [0, 1, 2, 3, 4, 3, 2, 1, 0, 1])
    np.testing.assert_allclose(source_times(5, 4, reverse=True), [4, 3, 2, 1, 0])
    np.testing.assert_allclose(source_times(5, 4, speed=0.5), [0, 0.5, 1, 1.5, 2])
    with pytest.raises(InputError, match="loop"):
        source_times(5, 4, loop="bounce")


def test_reverse_starts_at_rest_and_undoes_the_motion():
    prior = turning_prior()
    back = retime(prior, reverse=True)
    np.testing.assert_allclose(back.poses[0, 0], np.eye(4), atol=1e-12)
    # Played backwards, the last frame shows the source's first pose seen from its last: P(T)⁻¹.
    np.testing.assert_allclose(back.poses[0, -1], invert_transform(prior.poses[0, -1]), atol=1e-9)
    np.testing.assert_allclose(back.centroids[0], prior.centroids[0, ::-1])


def test_pingpong_returns_to_rest():
    prior = turning_prior()
    looped = retime(prior, frames=11, loop="pingpong")
    np.testing.assert_allclose(looped.poses[0, 10], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(looped.poses[0, 5], prior.poses[0, 5], atol=1e-9)


def test_scale_motion_scales_angles_and_displacements():
    prior = turning_prior()
    big = scale_motion(prior, rotation=2.0, translation=0.5)
    np.testing.assert_allclose(rotation_angle_deg(big.poses[0, :, :3, :3]),
                               2 * rotation_angle_deg(prior.poses[0, :, :3, :3]), atol=1e-6)
    axes = matrix_to_axis_angle(big.poses[0, 1:, :3, :3])
    np.testing.assert_allclose(axes / np.linalg.norm(axes, axis=1, keepdims=True),
                               matrix_to_axis_angle(prior.poses[0, 1:, :3, :3])
                               / np.linalg.norm(matrix_to_axis_angle(prior.poses[0, 1:, :3, :3]), axis=1,
                                                keepdims=True), atol=1e-9)
    c0 = prior.centroids[0, 0]
    np.testing.assert_allclose(big.centroids[0] - c0, 0.5 * (prior.centroids[0] - c0))
    # The poses carry the centre along the scaled path.
    moved = np.einsum("tij,j->ti", big.poses[0, :, :3, :3], c0) + big.poses[0, :, :3, 3]
    np.testing.assert_allclose(moved, big.centroids[0], atol=1e-9)
    assert scale_motion(prior) is prior


def test_orbit_and_dolly_paths():
    cam = Camera.from_fov(64, 48)
    centre = np.array([0.0, 0.0, 5.0])
    orbit = camera_path(cam, centre, 9, "orbit", 40.0)
    assert len(orbit) == 9 and np.allclose(orbit[0].world_to_camera, cam.world_to_camera)
    distances = [np.linalg.norm(c.center - centre) for c in orbit]
    np.testing.assert_allclose(distances, 5.0)
    turn = orbit[-1].world_to_camera[:3, :3] @ orbit[0].world_to_camera[:3, :3].T
    assert rotation_angle_deg(turn) == pytest.approx(40.0)
    uv, _ = orbit[-1].project(centre[None])
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)  # still looking at the centre
    dolly = camera_path(cam, centre, 5, "dolly", 0.4)
    assert np.linalg.norm(dolly[-1].center - centre) == pytest.approx(3.0)
    assert all(c is cam for c in camera_path(cam, centre, 3, "static"))
    with pytest.raises(InputError, match="dolly"):
        camera_path(cam, centre, 3, "dolly", 1.5)


def test_camera_path_file(tmp_path):
    cams = [Camera.from_fov(32, 24, 50.0 + i).to_dict() for i in range(4)]
    path = tmp_path / "path.json"
    path.write_text(json.dumps(cams))
    loaded = load_camera_path(path, 4)
    assert [c.fx for c in loaded] == pytest.approx([c["fx"] for c in cams])
    path.write_text(json.dumps(cams[:1]))
    assert len(load_camera_path(path, 7)) == 7
    path.write_text(json.dumps(cams[:3]))
    with pytest.raises(InputError, match="3 cameras for 4 frames"):
        load_camera_path(path, 4)
    path.write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        load_camera_path(path, 4)
