"""Playback controls (looping, reversal, motion scales) and camera paths."""

import json
import warnings

import numpy as np
import pytest
from test_transfer import cloud, prior_from_motion

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.gaussians import Gaussians
from marionette.geometry import invert_transform, matrix_to_axis_angle, rotation_angle_deg
from marionette.pipeline import output_cameras
from marionette.render.camera_path import camera_path, check_camera_move, load_camera_path
from marionette.target.lift import LiftedTarget
from marionette.transfer.controls import retime, scale_motion, source_times
from marionette.transfer.velocity import integrate


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


def travelling(shift, frames=40):
    """A target cloud 20 radii away moved as a source object that turns and travels ``shift`` (radii) over
    ``frames`` frames, with the target's reference camera."""
    t = np.linspace(0.0, 1.0, frames)[:, None]
    prior = prior_from_motion(t * [0.0, 0.8, 0.0], t * np.asarray(shift), centre=(0.0, 0.0, 20.0))
    points = cloud(300, centre=(0.0, 0.0, 20.0), size=0.5)
    gaussians = Gaussians.from_rgb(points, np.full((len(points), 3), 0.5), np.full(len(points), 0.05))
    target = LiftedTarget(gaussians, Camera.from_fov(64, 48), np.ones((48, 64), bool),
                          np.zeros((len(points), 2), np.int32))
    return target, integrate(points, np.zeros(len(points), int), prior)


def centre_pixels(trajectory, cameras):
    """(T, 2) pixel and (T,) depth of the object's centre in each frame, seen by that frame's camera."""
    seen = [cam.project(c[None]) for cam, c in zip(cameras, trajectory.means.mean(axis=1, dtype=np.float64))]
    return np.array([uv[0] for uv, _ in seen]), np.array([z[0] for _, z in seen])


@pytest.mark.parametrize("move, amount", [("orbit", 45.0), ("orbit", 180.0), ("dolly", 0.3), ("dolly", 0.6)])
def test_camera_moves_keep_a_travelling_object_in_view(move, amount):
    # Across the view and closer, as car-turn's car goes: a move about where it started left its centre out
    # of view in the clip's second half.
    target, trajectory = travelling([22.0, 0.0, -6.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no frame out of view to warn about
        cameras = output_cameras(target, trajectory, move, amount)
    uv, z = centre_pixels(trajectory, cameras)
    assert (z > 0).all()
    assert ((uv >= 0) & (uv <= [63, 47])).all()
    static = output_cameras(target, trajectory)
    if move == "orbit":  # still the turn asked for
        turn = cameras[-1].world_to_camera[:3, :3] @ cameras[0].world_to_camera[:3, :3].T
        assert rotation_angle_deg(turn) == pytest.approx(abs(amount))
        assert cameras[0].center == pytest.approx(static[0].center)
    else:  # nearer by the share asked for, the object's centre where the static camera shows it
        centre = trajectory.means[-1].mean(axis=0, dtype=np.float64)
        assert np.linalg.norm(cameras[-1].center - centre) == pytest.approx(
            (1 - amount) * np.linalg.norm(static[-1].center - centre))
        np.testing.assert_allclose(uv, centre_pixels(trajectory, static)[0], atol=1e-6)


def test_frames_out_of_view_are_warned():
    target, trajectory = travelling([0.0, 0.0, -60.0])  # it flies past the camera
    with pytest.warns(UserWarning, match=r"nothing of the object is in view in \d+ of 40 frames of the static"):
        output_cameras(target, trajectory)


def test_camera_amounts_are_bounded():
    assert check_camera_move("orbit", -360) == -360 and check_camera_move("dolly", 0.9) == 0.9
    for move, amount in (("orbit", 1e9), ("orbit", 361.0), ("dolly", 0.95), ("dolly", -0.1), ("orbit", float("nan"))):
        with pytest.raises(InputError, match=f"camera amount for {move} must be a number within"):
            check_camera_move(move, amount)


def test_orbit_and_dolly_paths():
    cam = Camera.from_fov(64, 48)
    centre = np.array([0.0, 0.0, 5.0])
    centres = np.tile(centre, (9, 1))
    orbit = camera_path(cam, centres, "orbit", 40.0)
    assert len(orbit) == 9 and np.allclose(orbit[0].world_to_camera, cam.world_to_camera)
    distances = [np.linalg.norm(c.center - centre) for c in orbit]
    np.testing.assert_allclose(distances, 5.0)
    turn = orbit[-1].world_to_camera[:3, :3] @ orbit[0].world_to_camera[:3, :3].T
    assert rotation_angle_deg(turn) == pytest.approx(40.0)
    uv, _ = orbit[-1].project(centre[None])
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy], atol=1e-9)  # still looking at the centre
    dolly = camera_path(cam, centres[:5], "dolly", 0.4)
    assert np.linalg.norm(dolly[-1].center - centre) == pytest.approx(3.0)
    assert all(c is cam for c in camera_path(cam, centres[:3], "static"))
    with pytest.raises(InputError, match="dolly"):
        camera_path(cam, centres[:3], "dolly", 1.5)


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
