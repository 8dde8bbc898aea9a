import numpy as np
import pytest

from marionette.camera import Camera
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
from marionette.render import render
from marionette.render.sh import eval_sh, rotate_sh
from marionette.synthetic import object_view
from marionette.target.lift import LiftOptions, lift_image
from marionette.target.shading import Light, estimate_light, shaded_sh


def lambert(normals: np.ndarray, light: Light) -> np.ndarray:
    """The shading model written out: ambient + (1 - ambient) · max(n · l, 0) for (..., 3) normals."""
    return light.ambient + (1 - light.ambient) * np.maximum(normals @ np.asarray(light.direction), 0.0)


def light_beside(view: np.ndarray, light: Light) -> np.ndarray:
    """(3,) the light's direction for a surfel seen along ``view`` (3,): where it is for one on the optical axis,
    relative to the view (forward, the camera's up square to it, and right)."""
    forward = view / np.linalg.norm(view)
    up = np.array([0.0, -1.0, 0.0]) - (np.array([0.0, -1.0, 0.0]) @ forward) * forward
    up /= np.linalg.norm(up)
    right = np.cross(forward, up)
    x, y, z = light.direction
    return x * right - y * up + z * forward


def random_light(rng: np.random.Generator) -> Light:
    """A light in front of the object (towards the camera, -z), within 60° of the view and above it (y < 0:
    the camera's y points down)."""
    polar, azimuth = np.radians(rng.uniform(10, 60)), rng.uniform(np.pi, 2 * np.pi)
    direction = np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), -np.cos(polar)])
    return Light(tuple(direction), float(rng.uniform(0.3, 0.7)))


def textured_ball(rng: np.random.Generator, light: Light, size: int = 96):
    """A ball of one speckled material facing the camera, lit by ``light``: (image, normals, pixels)."""
    y, x = (np.mgrid[:size, :size] + 0.5 - size / 2) / (0.45 * size)
    pixels = x**2 + y**2 < 1
    normals = np.stack([x, y, -np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))], axis=-1)
    albedo = rng.uniform(0.4, 0.9, (size, size, 1)) * rng.uniform(0.7, 1.0, 3)
    image = np.clip(np.rint(255 * albedo * lambert(normals, light)[..., None]), 0, 255).astype(np.uint8)
    return image, normals, pixels


def test_the_light_is_read_from_a_textured_ball():
    rng = np.random.default_rng(3)
    for _ in range(5):
        truth = random_light(rng)
        found = estimate_light(*textured_ball(rng, truth))
        assert found is not None
        angle = np.degrees(np.arccos(np.clip(np.dot(found.direction, truth.direction), -1, 1)))
        assert angle < 8.0 and abs(found.ambient - truth.ambient) < 0.12, (angle, found, truth)


def test_brightness_that_only_a_light_from_below_explains_is_taken_for_paint():
    rng = np.random.default_rng(4)
    for direction in ([0.3, 0.6, -0.7], [-0.4, 0.4, -0.8], [0.0, 0.5, -0.85]):  # y down: below the camera
        truth = Light(tuple(np.array(direction) / np.linalg.norm(direction)), 0.4)
        assert estimate_light(*textured_ball(rng, truth)) is None


def test_one_way_of_facing_tells_nothing_of_the_light():
    image = np.full((40, 40, 3), 120, np.uint8)
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (40, 40, 3))
    assert estimate_light(image, normals, np.ones((40, 40), bool)) is None


def test_shaded_surfels_show_the_photo_where_it_was_taken_and_turn_under_the_light():
    """Against the shading model written out: exact at the reference view, within the band limit elsewhere."""
    rng = np.random.default_rng(5)
    n = 200
    normals = rng.normal(size=(n, 3))
    normals[:, 2] = -np.abs(normals[:, 2])  # facing the camera at the origin
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    frames = np.cross([1.0, 0.0, 0.0], normals)  # no normal lies along x: every frame is proper
    frames /= np.linalg.norm(frames, axis=1, keepdims=True)
    rotations = np.stack([frames, np.cross(normals, frames), normals], axis=2)  # columns: tangent, tangent, normal
    means = np.column_stack([rng.uniform(-1, 1, (n, 2)), rng.uniform(6, 8, n)])
    gaussians = Gaussians.from_rgb(means, np.full((n, 3), 0.5), np.full((n, 3), 0.01), 0.9,
                                   matrix_to_quaternion(rotations))
    albedo = rng.uniform(0.2, 0.9, (n, 3))
    light = Light(tuple(np.array([-0.4, -0.6, -0.7]) / np.linalg.norm([-0.4, -0.6, -0.7])), 0.4)
    sh = shaded_sh(gaussians, albedo, light)
    assert sh.shape == (n, 9, 3)
    ahead = means / np.linalg.norm(means, axis=1, keepdims=True)
    lights = np.array([light_beside(d, light) for d in ahead])
    expected = albedo * (light.ambient + (1 - light.ambient)
                         * np.maximum(np.einsum("ni,ni->n", normals, lights), 0))[:, None]
    np.testing.assert_allclose(eval_sh(sh, ahead), expected, atol=1e-4)
    # Turned 50° about the vertical through each surfel, seen by the same camera: the light stays put.
    turn = axis_angle_to_matrix([0.0, np.radians(50.0), 0.0])
    seen = eval_sh(rotate_sh(sh, turn[None], np.zeros(n, np.int64)), ahead)
    turned = normals @ turn.T
    front = np.einsum("ni,ni->n", turned, ahead) < -0.2  # surfels still facing the camera
    truth = albedo * (light.ambient + (1 - light.ambient)
                      * np.maximum(np.einsum("ni,ni->n", turned, lights), 0))[:, None]
    assert front.sum() > 50
    assert np.abs(seen - truth)[front].max() < 0.12
    assert np.abs(seen - truth)[front].mean() < 0.02


def blurred_psnr(truth: np.ndarray, image: np.ndarray, alpha: np.ndarray) -> float:
    import cv2

    true_mask, mask = truth[..., 3] > 0, alpha > 0.5
    a = cv2.GaussianBlur(np.where(true_mask[..., None], truth[..., :3], 128).astype(np.float32), (0, 0), 3)
    b = cv2.GaussianBlur(np.where(mask[..., None], image, 128).astype(np.float32), (0, 0), 3)
    return float(10 * np.log10(255.0**2 / max(float(((a - b) ** 2)[true_mask | mask].mean()), 1e-12)))


@pytest.mark.parametrize("seed, yaw, pitch", [(0, 35.0, 20.0), (1, 50.0, 25.0)])
def test_a_box_turned_to_the_light_brightens_as_the_truth_does(seed, yaw, pitch):
    """A plain box (one colour per face, lit by the synthetic renderer's lamp) lifted from one view, turned 90°."""
    kwargs = {"size": (160, 160), "seed": seed, "pitch_deg": pitch, "fov_deg": 60.0, "plain": True}
    photo, camera, centre = object_view("box", yaw_deg=yaw, **kwargs)
    up = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    scores = {}
    for relight in (False, True):
        lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2]), relight=relight))
        assert (lifted.shape.light is not None) == relight and lifted.gaussians.sh_degree == (2 if relight else 0)
        g = lifted.gaussians
        for turn in (0, 90):
            r = axis_angle_to_matrix(up * np.radians(turn))
            out = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)), camera)
            image = np.clip(np.rint(out.image * 255), 0, 255).astype(np.uint8)
            scores[relight, turn] = blurred_psnr(object_view("box", yaw_deg=yaw + turn, **kwargs)[0], image, out.alpha)
    assert scores[True, 0] > 32  # the photo itself, again
    assert scores[True, 90] > scores[False, 90] + 4.0, scores
