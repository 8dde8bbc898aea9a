import json

import numpy as np
import pytest

from marionette.camera import Camera
from marionette.errors import InputError


def test_centre_projects_to_principal_point():
    cam = Camera.from_fov(64, 48)
    uv, z = cam.project(np.array([[0.0, 0.0, 3.0]]))
    assert np.allclose(uv, [[31.5, 23.5]]) and z[0] == 3.0


def test_json_round_trip(tmp_path):
    pose = np.eye(4)
    pose[:3, 3] = [0.1, -0.2, 2.0]
    cam = Camera.from_fov(100, 80, 50.0, pose)
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(cam.to_dict()))
    back = Camera.load(path)
    assert np.allclose(back.K, cam.K) and np.allclose(back.world_to_camera, cam.world_to_camera)
    assert np.allclose(back.center, [-0.1, 0.2, -2.0])


def test_resized_keeps_pixel_centres():
    cam = Camera.from_fov(64, 48)
    half = cam.resized(32, 24)
    assert half.cx == pytest.approx(15.5) and half.fx == pytest.approx(cam.fx / 2)


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d.pop("fx"), "missing key 'fx'"),
    (lambda d: d.update(width=-3), "width"),
    (lambda d: d.update(fy="a"), "'fy' must be a finite number"),
    (lambda d: d.update(world_to_camera=[[1, 0], [0, 1]]), "4x4"),
    (lambda d: d.update(world_to_camera=(2 * np.eye(4)).tolist()), "not a proper rotation"),
])
def test_bad_camera_json(tmp_path, mutate, words):
    d = Camera.from_fov(64, 48).to_dict()
    mutate(d)
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match=words):
        Camera.load(path)


def test_not_json(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text("{nope")
    with pytest.raises(InputError, match="not valid JSON"):
        Camera.load(path)


def test_framing_keeps_points_in_view_and_leaves_fitting_views_alone():
    cam = Camera.from_fov(200, 100, 60.0)
    inside = np.array([[0.0, 0.0, 5.0], [0.5, 0.2, 5.0]])
    assert np.array_equal(cam.framing(inside).K, cam.K)
    # A path running far off to the left and nearer the camera.
    path = np.array([[0.0, 0.0, 5.0], [-6.0, 0.5, 4.0], [-3.0, -1.0, 6.0]])
    framed = cam.framing(path, margin=0.1)
    uv, _ = framed.project(path)
    assert np.all(uv[:, 0] >= 0.1 * 200 - 1e-6) and np.all(uv[:, 0] <= 0.9 * 200 + 1e-6)
    assert np.all(uv[:, 1] >= 0.1 * 100 - 1e-6) and np.all(uv[:, 1] <= 0.9 * 100 + 1e-6)
    assert framed.fx < cam.fx and framed.fx == framed.fy
    # Zoomed out only as far as needed: the widest span fills the room exactly.
    assert uv[:, 0].max() - uv[:, 0].min() == pytest.approx(0.8 * 200)


def test_framing_leaves_out_frames_that_come_up_to_the_lens():
    cam = Camera.from_fov(200, 100, 60.0)
    path = np.array([[0.0, 0.0, 5.0], [-6.0, 0.5, 4.0], [-3.0, -1.0, 6.0]])
    close = np.array([[1.5, 0.1, 0.2]])  # within a quarter of the path's median depth, far to the right
    framed = cam.framing(np.concatenate([path, close]))
    np.testing.assert_allclose(framed.K, cam.framing(path).K)
    assert cam.framing(np.concatenate([path, close]), near=0.0).fx < 0.2 * framed.fx  # what it would cost
