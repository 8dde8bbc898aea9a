"""The slider model of a part (marionette.source.slider) on exact synthetic tracks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from marionette.geometry import rotation_angle_deg
from marionette.source.extract import _HINGE_TOLERANCE_PX
from marionette.source.hinge import hinge_poses
from marionette.source.joint_tracks import surface_scale
from marionette.source.slider import SliderFit, _initial_slider, fit_slider, scaled_slider, slider_poses

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
T = 24


def drawer_points(rng: np.random.Generator) -> np.ndarray:
    """(M, 3) points on a drawer's front and top, 1.2 x 0.4 x 0.8 units, 5 units in front of the camera."""
    front = np.column_stack([rng.uniform(-0.6, 0.6, 90), rng.uniform(-0.2, 0.2, 90), np.full(90, 4.6)])
    top = np.column_stack([rng.uniform(-0.6, 0.6, 60), np.full(60, -0.2), rng.uniform(4.6, 5.4, 60)])
    return np.concatenate([front, top])


def project(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    cam = np.einsum("tij,mj->tmi", poses[:, :3, :3], points) + poses[:, None, :3, 3]
    uv = cam @ K.T
    return uv[..., :2] / uv[..., 2:]


@pytest.fixture(scope="module")
def slider():
    rng = np.random.default_rng(0)
    axis = np.array([0.3, -0.2, -0.93])
    axis /= np.linalg.norm(axis)
    distances = np.linspace(0, 0.7, T) ** 1.2
    body = np.tile(np.eye(4), (T, 1, 1))
    body[:, :3, :3] = Rotation.from_rotvec(np.outer(np.linspace(0, 0.15, T), [0, 1, 0])).as_matrix()
    body[:, :3, 3] = np.array([0, 0, 5.0]) - body[:, :3, :3] @ [0, 0, 5.0]  # the body turns 9° about itself
    points = drawer_points(rng)
    uv = project(slider_poses(body, axis, distances), points)
    visible = np.ones(uv.shape[:2], bool)
    visible[T // 2:, :30] = False
    return body, axis, distances, points, np.where(visible[..., None], uv, np.nan), visible


def test_the_start_reads_a_slider_off_its_relative_poses_exactly(slider):
    body, axis, distances, points, *_ = slider
    relative = np.linalg.inv(body) @ slider_poses(body, axis, distances)
    found_axis, found_distances = _initial_slider(relative, points.mean(axis=0))
    np.testing.assert_allclose(found_axis, axis, atol=1e-9)
    np.testing.assert_allclose(found_distances, distances, atol=1e-9)


def test_a_slider_comes_back_from_free_poses_that_turn_and_stray(slider):
    """Free poses a little turned (3°), their travel tilted 10° and short by a fifth: the slider finds the
    truth."""
    body, axis, distances, points, uv, visible = slider
    tilted = Rotation.from_rotvec(np.radians(10) * np.array([1.0, 0, 0])).apply(axis)
    free = slider_poses(body, tilted, 0.8 * distances)
    free[:, :3, :3] = free[:, :3, :3] @ Rotation.from_rotvec(np.outer(np.linspace(0, np.radians(3), T),
                                                                       [0, 0, 1])).as_matrix()
    fit = fit_slider(uv, visible, body, free, K)
    assert fit is not None and fit.dropped == 0
    true = slider_poses(body, axis, distances)
    assert np.degrees(np.arccos(min(1.0, abs(fit.axis @ axis)))) < 0.05
    assert np.abs(fit.poses[:, :3, 3] - true[:, :3, 3]).max() < 1e-3
    assert rotation_angle_deg(fit.poses[:, :3, :3] @ np.swapaxes(true[:, :3, :3], -1, -2)).max() < 1e-6
    assert fit.residual_px < 0.01 < fit.free_residual_px


def test_on_a_still_body_the_travel_keeps_the_length_of_its_free_fit(slider):
    """With the body still nothing in the images fixes the scale: the travel keeps about the free fit's."""
    _, axis, distances, points, _, visible = slider
    still = np.tile(np.eye(4), (T, 1, 1))
    uv = np.where(visible[..., None], project(slider_poses(still, axis, distances), points), np.nan)
    fit = fit_slider(uv, visible, still, slider_poses(still, axis, distances), K)
    assert np.degrees(np.arccos(min(1.0, abs(fit.axis @ axis)))) < 0.05
    assert np.abs(fit.distances - distances).max() < 0.01 * distances.max()


def test_a_turning_part_is_no_slider_and_one_that_barely_moves_has_no_direction(slider):
    """Tracks of a lid turning 40° about its hinge: one direction of travel explains them much worse than the
    turn does."""
    body, axis, distances, points, uv, visible = slider
    lid = hinge_poses(body, np.array([1.0, 0.0, 0.0]), np.array([0.0, -0.2, 5.4]), np.radians(np.linspace(0, 40, T)))
    fit = fit_slider(project(lid, points), np.ones(visible.shape, bool), body, lid, K)
    assert fit is None or fit.residual_px > fit.free_residual_px + _HINGE_TOLERANCE_PX
    assert fit_slider(uv, visible, body, slider_poses(body, axis, 0.001 * distances), K) is None


def test_a_part_wandering_about_is_not_made_a_slider(slider):
    """A part that moves along a curve: one direction explains its tracks much worse than its free poses."""
    body, _, _, points, _, _ = slider
    free = body.copy()
    s = np.linspace(0, 1, T)
    free[:, :3, 3] += np.column_stack([0.6 * np.sin(3 * s), 0.5 * (1 - np.cos(3 * s)), -0.3 * s])
    uv = project(free, points)
    fit = fit_slider(uv, np.ones(uv.shape[:2], bool), body, free, K)
    assert fit is None or fit.residual_px > fit.free_residual_px + _HINGE_TOLERANCE_PX


def _surface(points: np.ndarray) -> np.ndarray:
    """(240, 320) frame-0 depth of the drawer's front plane (z = 4.6) over its pixels, NaN elsewhere."""
    uv = project(np.eye(4)[None], points)[0]
    surface = np.full((240, 320), np.nan)
    lo, hi = np.floor(uv.min(axis=0)).astype(int) - 2, np.ceil(uv.max(axis=0)).astype(int) + 2
    surface[lo[1]:hi[1], lo[0]:hi[0]] = 4.6
    return surface


@pytest.mark.parametrize("short", [0.5, 1.0, 1.6])
def test_on_a_still_body_the_travel_takes_its_length_from_the_surface(slider, short):
    """A slider whose travel is off by a factor (the tracks leave it free on a still body) comes back to the
    true length once its front sits on the body's surface, though more of its tracks are the body's (still;
    some covered halfway) than its own."""
    _, axis, distances, points, _, _ = slider
    rng = np.random.default_rng(1)
    front = points[points[:, 2] == 4.6]
    still = np.tile(np.eye(4), (T, 1, 1))
    body_points = np.column_stack([rng.uniform(-0.6, 0.6, 150), rng.uniform(0.25, 0.35, 150), np.full(150, 4.6)])
    uv = np.concatenate([project(slider_poses(still, axis, distances), front), project(still, body_points)], axis=1)
    visible = np.ones(uv.shape[:2], bool)
    visible[T // 2:, len(front):len(front) + 20] = False  # under the drawer: covered as it comes out
    surface = _surface(np.concatenate([front, body_points]))
    off = SliderFit(slider_poses(still, axis, short * distances), axis, short * distances, 0.0, 0.0, 0,
                    np.zeros(T, int))
    uv = np.where(visible[..., None], uv, np.nan)
    factor = surface_scale(lambda f: scaled_slider(off, still, f).poses, distances, uv, visible, K, surface)
    assert factor == pytest.approx(1.0 / short, rel=1e-3)
    scaled = scaled_slider(off, still, factor)
    np.testing.assert_allclose(scaled.distances, distances, atol=1e-3 * distances.max())
    np.testing.assert_allclose(scaled.poses, slider_poses(still, axis, distances), atol=1e-3)


def test_the_surface_gives_no_scale_without_tracks_that_see_the_travel(slider):
    """Tracks lost early in the travel, or off the surface, give no factor."""
    _, axis, distances, points, _, _ = slider
    still = np.tile(np.eye(4), (T, 1, 1))
    uv = project(slider_poses(still, axis, distances), points)
    fit = SliderFit(slider_poses(still, axis, distances), axis, distances, 0.0, 0.0, 0, np.zeros(T, int))
    lost = np.ones(uv.shape[:2], bool)
    lost[distances >= 0.25 * distances.max()] = False  # lost before a quarter of the travel
    poses = lambda f: scaled_slider(fit, still, f).poses  # noqa: E731
    assert surface_scale(poses, distances, uv, lost, K, _surface(points)) is None
    assert surface_scale(poses, distances, uv, np.ones(uv.shape[:2], bool), K, np.full((240, 320), np.nan)) is None
