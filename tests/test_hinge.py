"""The hinge model of a part (marionette.source.hinge) on exact synthetic tracks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from marionette.geometry import rotation_angle_deg
from marionette.source.extract import _HINGE_TOLERANCE_PX
from marionette.source.hinge import HingeFit, _initial_hinge, _wrapped, fit_hinge, hinge_poses, scaled_hinge
from marionette.source.joint_tracks import Observations, surface_scale

K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
T = 24


def lid_points(rng: np.random.Generator) -> np.ndarray:
    """(M, 3) points of a flat lid, 1.6 x 1 units, 5 units in front of the camera, its hinge edge at x = -0.8."""
    xy = rng.uniform([-0.8, -0.5], [0.8, 0.5], size=(150, 2))
    return np.column_stack([xy[:, 0], xy[:, 1] * 0.6, 5.0 + xy[:, 1] * 0.8])


def project(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(T, M, 2) pixels of ``points`` (M, 3) moved by ``poses`` (T, 4, 4)."""
    cam = np.einsum("tij,mj->tmi", poses[:, :3, :3], points) + poses[:, None, :3, 3]
    uv = cam @ K.T
    return uv[..., :2] / uv[..., 2:]


@pytest.fixture(scope="module")
def hinge():
    rng = np.random.default_rng(0)
    axis = np.array([0.0, 0.8, -0.6])
    point = np.array([-0.8, 0.0, 5.0])
    angles = np.radians(np.linspace(0, 70, T))
    body = np.tile(np.eye(4), (T, 1, 1))
    body[:, 0, 3] = np.linspace(0, 0.3, T)  # the body drifts sideways; the hinge moves with it
    points = lid_points(rng)
    uv = project(hinge_poses(body, axis, point, angles), points)
    visible = np.ones(uv.shape[:2], bool)
    visible[T // 2:, :40] = False  # some tracks end halfway, as they do when the lid turns away
    return body, axis, point, angles, points, np.where(visible[..., None], uv, np.nan), visible


def test_points_are_solved_from_exact_tracks(hinge):
    body, axis, point, angles, points, uv, visible = hinge
    obs = Observations(uv, visible, np.ones(len(points), bool))
    errors, solved = obs.residuals(hinge_poses(body, axis, point, angles), K)
    np.testing.assert_allclose(solved, points, atol=1e-8)
    assert np.abs(errors).max() < 1e-8


def test_the_start_reads_a_hinge_off_its_relative_poses_exactly(hinge):
    """The axis, a point of it and every angle, the widest turn's included."""
    body, axis, point, angles, *_ = hinge
    relative = np.linalg.inv(body) @ hinge_poses(body, axis, point, angles)
    found_axis, found_point, found_angles = _initial_hinge(relative)
    np.testing.assert_allclose(found_axis, axis, atol=1e-9)
    np.testing.assert_allclose(found_angles, angles, atol=1e-9)
    np.testing.assert_allclose(hinge_poses(body, found_axis, found_point, found_angles),
                               hinge_poses(body, axis, point, angles), atol=1e-9)


def test_a_hinge_comes_back_from_free_poses_off_by_the_bas_relief(hinge):
    """The free fit's typical error: too little turn about a tilted axis. The hinge model finds the truth."""
    body, axis, point, angles, points, uv, visible = hinge
    tilted = Rotation.from_rotvec(np.radians(12) * np.array([1.0, 0, 0])).apply(axis)
    free = hinge_poses(body, tilted, point + [0.1, 0, 0.3], 0.6 * angles)
    fit = fit_hinge(uv, visible, body, free, K)
    assert fit is not None and fit.dropped == 0
    true = hinge_poses(body, axis, point, angles)
    assert rotation_angle_deg(fit.poses[:, :3, :3] @ np.swapaxes(true[:, :3, :3], -1, -2)).max() < 0.05
    assert np.degrees(np.arccos(abs(fit.axis @ axis))) < 0.05
    assert np.abs(fit.poses[:, :3, 3] - true[:, :3, 3]).max() < 1e-3
    assert fit.residual_px < 0.01 < fit.free_residual_px


def test_on_a_still_body_the_part_keeps_the_depth_of_its_free_fit(hinge):
    """With the body still, the part's scale is free (nothing in the images fixes it): the fit keeps about the
    free fit's rather than wander off with the axis."""
    body, axis, point, angles, points, uv, visible = hinge
    still = np.tile(np.eye(4), (T, 1, 1))
    uv = np.where(visible[..., None], project(hinge_poses(still, axis, point, angles), points), np.nan)
    fit = fit_hinge(uv, visible, still, hinge_poses(still, axis, point, 0.7 * angles), K)
    true = hinge_poses(still, axis, point, angles)
    assert rotation_angle_deg(fit.poses[:, :3, :3] @ np.swapaxes(true[:, :3, :3], -1, -2)).max() < 0.05
    scale = np.sum(fit.poses[:, :3, 3] * true[:, :3, 3]) / np.sum(true[:, :3, 3] ** 2)
    assert 0.8 < scale < 1.25 and np.abs(fit.poses[:, :3, 3] - scale * true[:, :3, 3]).max() < 1e-3


@pytest.mark.parametrize("scale", [0.7, 1.4])
def test_on_a_still_body_the_axis_takes_its_distance_from_the_surface(hinge, scale):
    """A hinge whose axis (and part) sit nearer or farther than they are, which the tracks on a still body leave
    free, comes back to the true axis once the part's frame-0 points sit on the body's surface."""
    _, axis, point, angles, points, _, visible = hinge
    still = np.tile(np.eye(4), (T, 1, 1))
    uv = np.where(visible[..., None], project(hinge_poses(still, axis, point, angles), points), np.nan)
    surface = np.full((240, 320), np.nan)  # the lid's plane, z = 5 + 4/3 y, along each pixel's ray
    rows, cols = np.mgrid[:240, :320]
    y = (rows - K[1, 2]) / K[1, 1]
    surface[60:200, 60:260] = (5.0 / (1 - 4 / 3 * y))[60:200, 60:260]
    off = HingeFit(hinge_poses(still, axis, scale * point, angles), axis, scale * point, angles, 0.0, 0.0, 0,
                   np.zeros(T, int), np.ones(len(points), bool))
    factor = surface_scale(lambda f: scaled_hinge(off, still, f).poses, angles, uv, visible, K, surface)
    assert factor == pytest.approx(1 / scale, rel=1e-3)
    np.testing.assert_allclose(scaled_hinge(off, still, factor).point, point, atol=5e-3)


def test_tracks_of_another_part_are_dropped(hinge):
    body, axis, point, angles, points, uv, visible = hinge
    stray = project(body, lid_points(np.random.default_rng(1))[:10])  # body points labelled as the lid's
    uv, visible = np.concatenate([uv, stray], axis=1), np.concatenate([visible, np.ones((T, 10), bool)], axis=1)
    fit = fit_hinge(uv, visible, body, hinge_poses(body, axis, point, 0.8 * angles), K)
    assert fit.dropped == 10
    assert fit.followers.tolist() == [True] * (uv.shape[1] - 10) + [False] * 10
    assert np.array_equal(fit.seen, visible[:, fit.followers].sum(axis=1))
    true = hinge_poses(body, axis, point, angles)
    assert rotation_angle_deg(fit.poses[:, :3, :3] @ np.swapaxes(true[:, :3, :3], -1, -2)).max() < 0.05


def test_a_part_moving_freely_is_not_made_a_hinge(hinge):
    """A part that turns about changing axes and slides: the hinge explains its tracks much worse."""
    body, _, _, _, points, _, _ = hinge
    rotvecs = np.column_stack([np.linspace(0, 0.6, T), np.sin(np.linspace(0, 3, T)) * 0.4, np.zeros(T)])
    free = np.tile(np.eye(4), (T, 1, 1))
    free[:, :3, :3] = Rotation.from_rotvec(rotvecs).as_matrix()
    free[:, :3, 3] = np.column_stack([np.linspace(0, 1.0, T), np.linspace(0, -0.5, T), np.zeros(T)])
    free[:, :3, 3] += np.array([0, 0, 5.0]) - free[:, :3, :3] @ [0, 0, 5.0]  # turning about the lid, not the camera
    uv = project(free, points)
    fit = fit_hinge(uv, np.ones(uv.shape[:2], bool), body, free, K)
    assert fit is None or fit.residual_px > fit.free_residual_px + _HINGE_TOLERANCE_PX


def test_a_part_that_barely_turns_has_no_axis(hinge):
    body, axis, point, angles, points, uv, visible = hinge
    assert fit_hinge(uv, visible, body, hinge_poses(body, axis, point, angles * 0.05), K) is None


def test_a_long_clip_fits_the_key_frames_then_each_other_frame():
    """More frames than the joint fit takes: the frames between the key frames get their own angle (a turn
    that is not smooth in time, so interpolating the key frames would miss it)."""
    frames = 60
    axis, point = np.array([0.0, 0.8, -0.6]), np.array([-0.8, 0.0, 5.0])
    angles = np.radians(np.linspace(0, 60, frames) + 4 * np.sin(np.arange(frames) * 1.3))
    angles[0] = 0.0
    body = np.tile(np.eye(4), (frames, 1, 1))
    body[:, 0, 3] = np.linspace(0, 0.3, frames)
    points = lid_points(np.random.default_rng(2))
    true = hinge_poses(body, axis, point, angles)
    uv = project(true, points)
    fit = fit_hinge(uv, np.ones(uv.shape[:2], bool), body, hinge_poses(body, axis, point, 0.7 * angles), K)
    assert rotation_angle_deg(fit.poses[:, :3, :3] @ np.swapaxes(true[:, :3, :3], -1, -2)).max() < 0.05


def test_lid_frames_the_free_fit_loses_are_found_about_the_hinge(monkeypatch):
    """A 20-frame hinge where PnP keeps too few lid inliers at frames 8-12: from two starts the hinge fit finds
    the lid's true turn (from one, the free fit's, it settled 27° short), and those frames count as recovered."""
    from marionette.source import ExtractOptions, extract_prior
    from marionette.source import extract as extract_module
    from marionette.source.extract import HINGE_NOTE
    from marionette.synthetic import make_scene

    # The hinge as fitted to the tracks as tracked: on this small lid (a few tracks at frames 8-11) the refit to
    # the re-aligned tracks ends 7° short where this ends 3° off (docs/limitations.md).
    monkeypatch.setattr(extract_module, "_realigned_hinge", lambda part, fit, *args: fit)
    scene = make_scene("hinge", seed=0, num_frames=20, size=(200, 150))
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts="auto"))
    meta = prior.metadata
    assert meta["joints"]["0"]["model"] == "hinge" and meta["failed_frames"] == {}
    recovered = sorted(int(key.split(":")[1]) for key in meta["recovered_frames"])
    assert len(recovered) >= 3 and all(note.startswith(HINGE_NOTE) for note in meta["recovered_frames"].values())
    error = rotation_angle_deg(np.swapaxes(prior.poses[0, :, :3, :3], -1, -2) @ scene.poses[1, :, :3, :3])
    assert np.median(error[1:]) < 5.0 and error[recovered].max() < 5.0


def test_angles_a_whole_number_of_turns_away_are_brought_back():
    angles = np.radians([0.0, 30.0, 79.0, -120.0])
    np.testing.assert_allclose(_wrapped(angles + 2 * np.pi * np.array([0, 1, 140, -3])), angles, atol=1e-9)


def test_a_lid_the_free_fit_loses_edge_on_is_carried_on_from_its_first_half(monkeypatch):
    """A lid opening 72° turns edge-on halfway; its free fit ends at 25° and every start from it ends near 40°, its
    later tracks (seeded on the face that comes into view) too far off to pull it. Fitted on the first half of
    the key frames and carried on at the last rate, the hinge explains those tracks too (measured: 63° at the
    end, the axis 1.2° off; 39°, 11° off without). The hinge as fitted to the tracks as tracked: the refit to the
    re-aligned tracks that follows starts from it."""
    from marionette.source import ExtractOptions, extract_prior
    from marionette.source import extract as extract_module
    from marionette.source import hinge as hinge_module
    from marionette.synthetic import make_scene

    monkeypatch.setattr(extract_module, "_realigned_hinge", lambda part, fit, *args: fit)

    scene = make_scene("hinge", object="hinge", seed=100, num_frames=32, size=(400, 300))
    relative = np.linalg.inv(scene.poses[0]) @ scene.poses[1]
    true_axis = Rotation.from_matrix(relative[-1, :3, :3]).as_rotvec()
    true_angle = np.degrees(np.linalg.norm(true_axis))
    results = {}
    for carried in (True, False):
        if not carried:
            monkeypatch.setattr(hinge_module, "_continued", lambda *args: None)
        prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts=2))
        (_, joint), = prior.metadata["joints"].items()
        assert joint["model"] == "hinge"
        axis_error = np.degrees(np.arccos(min(1.0, abs(np.dot(joint["axis"], true_axis)) / np.linalg.norm(true_axis))))
        results[carried] = (abs(max(np.abs(joint["range_deg"])) - true_angle), axis_error)
    assert results[True][0] < 15.0 and results[True][1] < 3.0
    assert results[False][0] > 20.0
