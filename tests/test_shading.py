"""Shading of the reconstruction (``marionette.reconstruct.shading``): known answers and gradients."""

import numpy as np
import pytest

from marionette.camera import Camera
from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_quaternion
from marionette.reconstruct import ReconstructOptions, reconstruct_object
from marionette.reconstruct._views import FitView
from marionette.reconstruct.fit import _loss_and_grads
from marionette.reconstruct.shading import Lighting, shade_factors, shade_sh, unit_rows
from marionette.render.sh import eval_sh
from marionette.synthetic import make_scene


def test_shaded_coefficients_give_the_colour_times_the_factor():
    rng = np.random.default_rng(0)
    sh = rng.normal(0, 0.2, (50, 4, 3)).astype(np.float32)
    dirs = rng.normal(size=(50, 3))
    factors = rng.uniform(0.3, 1.0, 50)
    np.testing.assert_allclose(eval_sh(shade_sh(sh, factors), dirs), factors[:, None] * eval_sh(sh, dirs),
                               atol=2e-6)


def test_faces_towards_the_light_are_brighter_and_away_from_it_ambient():
    light = Lighting(np.array([0.0, 0.0, -1.0]), 0.4)
    normals = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], unit_rows(np.array([0.0, 1, -1]))])
    np.testing.assert_allclose(shade_factors(normals, light), [1.0, 0.6, 0.6, 0.6 + 0.4 / np.sqrt(2)])


def fit_problem(rng: np.random.Generator, n: int = 24):
    """Random Gaussians on two parts, their poses, a view of them and a light."""
    params = {"means": rng.normal(0, 0.25, (n, 3)).astype(np.float32),
              "quats": rng.normal(size=(n, 4)).astype(np.float32),
              "log_scales": np.log(rng.uniform(0.08, 0.2, (n, 3))).astype(np.float32),
              "logits": np.full(n, 1.5, np.float32), "dc": rng.normal(0, 0.3, (n, 3)).astype(np.float32),
              "rest": rng.normal(0, 0.2, (n, 3, 3)).astype(np.float32), "normals": rng.normal(size=(n, 3))}
    parts = np.repeat([0, 1], n // 2)
    poses = np.stack([make_transform(axis_angle_to_matrix(v), t) for v, t in
                      (([0.4, -0.9, 0.2], [0.0, 0.0, 3.0]), ([-0.8, 0.5, 1.1], [0.1, -0.1, 3.2]))])
    camera = Camera(np.array([[60.0, 0, 24], [0, 60.0, 24], [0, 0, 1]]), np.eye(4), 48, 48)
    view = FitView(0, camera, rng.uniform(0, 1, (48, 48, 3)).astype(np.float32), np.ones((48, 48), np.float32))
    light = {"direction": np.array([[0.3, -0.5, -0.8]]), "diffuse": np.array([0.2])}
    return params, parts, view, poses, matrix_to_quaternion(poses[:, :3, :3]), light


@pytest.mark.parametrize("name", ["normals", "direction", "diffuse", "dc", "rest"])
def test_fit_gradients_of_the_shading_match_finite_differences(name):
    """Normals turned with their parts, the light, the diffuse share, and the colours under them."""
    rng = np.random.default_rng(7)
    params, parts, view, poses, q_pose, light = fit_problem(rng)
    _, grads, _ = _loss_and_grads(params, parts, view, poses, q_pose, 0.5, light)
    source = light if name in light else params
    direction = rng.normal(size=source[name].shape)
    step = 1e-2

    def loss_at(offset: float) -> float:
        moved = {**source, name: (source[name] + offset * direction).astype(source[name].dtype)}
        if source is light:
            return _loss_and_grads(params, parts, view, poses, q_pose, 0.5, moved)[0]
        return _loss_and_grads(moved, parts, view, poses, q_pose, 0.5, light)[0]

    numeric = (loss_at(step) - loss_at(-step)) / (2 * step)
    analytic = float(np.sum(grads[name] * direction))
    assert abs(numeric) > 1e-4  # the term does move the loss
    assert analytic == pytest.approx(numeric, rel=0.05)


def test_an_object_turning_under_a_fixed_light_is_fitted_with_it():
    """The synthetic renderer lights its objects from a light fixed to the camera; turning about the
    optical axis, the faces change their shading but not the direction they are seen from. The fit
    with shading finds a light above, left and in front (the renderer's) and beats the fit without."""
    scene = make_scene("inplane", num_frames=12, size=(128, 96), seed=0)
    prior = scene.ground_truth_prior()
    from marionette.eval.metrics import masked_psnr

    odd = range(1, 12, 2)
    held = {}
    for shading in (False, True):
        rec = reconstruct_object(scene.frames, scene.masks, prior, frames_used=range(0, 12, 2),
                                 options=ReconstructOptions(iterations=200, shading=shading))
        held[shading] = np.mean([masked_psnr(rec.render_frame(prior, t), scene.frames[t], scene.masks[t])
                                 for t in odd])
    assert rec.shading is not None and rec.shading.lighting.diffuse > 0.2
    light = rec.shading.lighting.direction
    assert light[2] < 0 and light[1] < 0  # in front (towards the camera) and above (image y points down)
    assert held[True] > held[False] + 1.0, held


def test_the_trajectory_of_a_shaded_fit_renders_its_frames_as_the_fit_does():
    """eval-self renders the reconstruction through its trajectory: each frame as ``at`` gives it."""
    from marionette.render import render

    scene = make_scene("inplane", num_frames=6, size=(96, 72), seed=2)
    prior = scene.ground_truth_prior()
    rec = reconstruct_object(scene.frames, scene.masks, prior, options=ReconstructOptions(iterations=30))
    trajectory = rec.trajectory(prior)
    camera = Camera(prior.intrinsics, np.eye(4), 96, 72)
    for t in (0, 5):
        np.testing.assert_allclose(render(trajectory.frame(rec.gaussians, t), camera).image,
                                   rec.render_frame(prior, t), atol=2e-3)
    # the colours at rest are the shaded ones (what a .ply holds), and they change as the object turns
    np.testing.assert_allclose(trajectory.frame(rec.gaussians, 0).sh, rec.gaussians.sh, atol=1e-5)
    assert np.abs(trajectory.frame(rec.gaussians, 5).sh[:, 0] - rec.gaussians.sh[:, 0]).max() > 0.01
