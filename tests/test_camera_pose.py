"""The camera's full pose from background tracks with parallax (issue 16, item 3): known answers on synthetic
tracks of 3D points seen by a camera that travels and turns."""

import cv2
import numpy as np
import pytest

from marionette.geometry import axis_angle_to_matrix, invert_transform, make_transform
from marionette.source import camera_pose
from marionette.source.camera_motion import _scale
from marionette.source.camera_pose import _refine, fit_camera_poses
from marionette.source.tracks import Tracks

W, H, F = 640, 480, 600.0
K = np.array([[F, 0, 319.5], [0, F, 239.5], [0, 0, 1]])


def travelling_camera(num_frames=30):
    """World-to-camera (T, 4, 4) of a camera moving 1 unit sideways and 0.3 forward while it yaws 8°."""
    centres = np.stack([np.linspace(0, 1.0, num_frames), np.zeros(num_frames), np.linspace(0, 0.3, num_frames)], 1)
    yaw = np.radians(np.linspace(0, 8, num_frames))
    to_world = axis_angle_to_matrix(np.stack([np.zeros(num_frames), yaw, np.zeros(num_frames)], 1))
    return make_transform(np.swapaxes(to_world, 1, 2), -np.einsum("tji,tj->ti", to_world, centres))


def still_then_travelling_camera(num_frames=30, still=15):
    """World-to-camera (T, 4, 4) of a hand-held camera that only yaws (8° over the clip) for ``still`` frames,
    then travels 1 unit sideways and 0.3 forward."""
    s = np.clip((np.arange(num_frames) - still) / (num_frames - 1 - still), 0, 1)
    centres = np.stack([s, np.zeros(num_frames), 0.3 * s], 1)
    yaw = np.radians(np.linspace(0, 8, num_frames))
    to_world = axis_angle_to_matrix(np.stack([np.zeros(num_frames), yaw, np.zeros(num_frames)], 1))
    return make_transform(np.swapaxes(to_world, 1, 2), -np.einsum("tji,tj->ti", to_world, centres))


def background_tracks(w2c, noise=0.3, seed=0, depth=None):
    """Tracks of points at random depths in 3-12 (a near background: strong parallax), or ``depth(pixels (N, 2))``
    in their seed frame, seeded at frames 0, 10 and 20 and followed while they stay in the picture, with Gaussian
    pixel noise."""
    rng = np.random.default_rng(seed)
    uvs, visible, starts = [], [], []
    for start in (0, 10, 20):
        px = rng.uniform([0, 0], [W, H], (400, 2))
        z = rng.uniform(3.0, 12.0, 400) if depth is None else depth(px)
        cam = np.stack([(px[:, 0] - K[0, 2]) / F * z, (px[:, 1] - K[1, 2]) / F * z, z], 1)
        c2w = invert_transform(w2c[start])
        world = cam @ c2w[:3, :3].T + c2w[:3, 3]
        seen = np.einsum("tij,nj->tni", w2c[:, :3, :3], world) + w2c[:, None, :3, 3]
        uv = F * seen[..., :2] / seen[..., 2:] + K[:2, 2]
        uv += rng.normal(0, noise, uv.shape)
        inside = np.all((uv >= 0) & (uv < [W, H]), axis=2) & (seen[..., 2] > 0)
        inside[:start] = False
        inside[start:] = np.cumprod(inside[start:], axis=0).astype(bool)  # lost once it leaves
        uv[~inside] = np.nan
        uvs.append(uv), visible.append(inside), starts.append(np.full(400, start))
    return Tracks(np.concatenate(uvs, 1).astype(np.float32), np.concatenate(visible, 1), np.concatenate(starts))


def angle_deg(a, b):
    cos = np.einsum("...i,...i", a, b) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_a_travelling_camera_comes_back_with_its_translation_direction():
    truth = travelling_camera()
    fit = fit_camera_poses(background_tracks(truth), K)
    relative = fit.world_to_camera[:, :3, :3] @ np.swapaxes(truth[:, :3, :3], 1, 2)
    rotation_error = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert rotation_error.max() < 0.1
    centres = invert_transform(fit.world_to_camera)[:, :3, 3]
    true_centres = invert_transform(truth)[:, :3, 3]
    # The direction of travel, wherever the camera has gone a fifth of its way (before that a 0.3 px
    # noise on a few pixels of parallax leaves the direction loose).
    far = np.linalg.norm(true_centres, axis=1) > 0.2 * np.linalg.norm(true_centres[-1])
    assert angle_deg(centres[far], true_centres[far]).max() < 2.0
    assert fit.inlier_ratio[1:].min() > 0.9 and np.median(fit.residual_px[1:]) < 0.7


def test_it_repeats_exactly_and_refuses_a_background_it_cannot_fix():
    truth = travelling_camera()
    tracks = background_tracks(truth)
    first, second = fit_camera_poses(tracks, K), fit_camera_poses(tracks, K)
    assert first.world_to_camera.tobytes() == second.world_to_camera.tobytes()
    few = Tracks(tracks.uv[:, :8], tracks.visible[:, :8], tracks.start[:8])
    assert fit_camera_poses(few, K) is None
    # Tracks that no camera explains (each frame's positions drawn anew): no two views fix a pose.
    rng = np.random.default_rng(5)
    scrambled = np.where(tracks.visible[..., None], rng.uniform(0, [W, H], tracks.uv.shape), np.nan)
    assert fit_camera_poses(Tracks(scrambled.astype(np.float32), tracks.visible, tracks.start), K) is None


def test_the_poses_do_not_follow_rounding_noise(monkeypatch):
    """Another BLAS kernel (OpenBLAS's without FMA) moves the triangulations by ~1e-13, and the next frames'
    RANSAC turned that into other cameras (the backpack clip: 0.35 units apart by its end). What each step hands
    on is rounded onto a grid (:mod:`marionette.reproducible`): the cameras come out the same bits."""
    tracks = background_tracks(travelling_camera(), noise=1.0)
    reference = fit_camera_poses(tracks, K)
    rng = np.random.default_rng(0)
    triangulate, triangulate_all = cv2.triangulatePoints, camera_pose._triangulate_all

    def nudged(values):
        return values * (1 + 1e-13 * rng.standard_normal(values.shape))

    monkeypatch.setattr(camera_pose.cv2, "triangulatePoints", lambda *args: nudged(triangulate(*args)))
    monkeypatch.setattr(camera_pose, "_triangulate_all", lambda *args: nudged(triangulate_all(*args)))
    perturbed = fit_camera_poses(tracks, K)
    assert np.array_equal(perturbed.world_to_camera, reference.world_to_camera)
    assert np.array_equal(perturbed.points, reference.points, equal_nan=True)


@pytest.mark.parametrize("object_depth", [2.0, 7.5])
def test_the_scale_puts_the_background_beside_the_object_at_its_depth(object_depth):
    """Background points within 190 px of the object (at the image centre) 4 units away, the rest 10: the
    camera's travel comes out in the object's units, 1.04 true units times ``object_depth / 4``."""
    truth = travelling_camera()
    near = lambda px: np.linalg.norm(px - [320, 240], axis=1) < 190  # noqa: E731
    tracks = background_tracks(truth, depth=lambda px: np.where(near(px), 4.0, 10.0))
    fit = fit_camera_poses(tracks, K)
    mask = np.zeros((H, W), bool)
    mask[200:280, 280:360] = True
    scale = _scale(fit, tracks, mask, object_depth)
    travel = np.linalg.norm(invert_transform(fit.world_to_camera[-1])[:3, 3]) * scale
    true_travel = np.linalg.norm(invert_transform(truth[-1])[:3, 3])
    assert travel == pytest.approx(true_travel * object_depth / 4.0, rel=0.03)


def short_lived(tracks, mean_life=14, seed=2):
    """The tracks cut after a random (geometric) number of frames, as a tracker loses them."""
    life = np.random.default_rng(seed).geometric(1 / mean_life, tracks.num_tracks)
    alive = tracks.visible & (np.arange(tracks.num_frames)[:, None] < tracks.start[None] + life[None])
    return Tracks(np.where(alive[..., None], tracks.uv, np.nan).astype(np.float32), alive, tracks.start)


def errors_against(fit, truth):
    """Largest rotation error (degrees) over frames, and largest angle between the fitted and the true camera
    centres over the frames where the camera has gone a fifth of its way."""
    relative = fit.world_to_camera[:, :3, :3] @ np.swapaxes(truth[:, :3, :3], 1, 2)
    rotation = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    centres, true_centres = invert_transform(fit.world_to_camera)[:, :3, 3], invert_transform(truth)[:, :3, 3]
    far = np.linalg.norm(true_centres, axis=1) > 0.2 * np.linalg.norm(true_centres[-1])
    return rotation.max(), angle_deg(centres[far], true_centres[far]).max()


def test_a_camera_that_starts_still_is_placed_from_a_later_pair_of_frames():
    """While the camera only turns, no two frames near frame 0 fix a translation, and by the time it travels
    most of frame 0's tracks are lost: the two views come from later frames, frame 0 is placed after them."""
    truth = still_then_travelling_camera()
    tracks = short_lived(background_tracks(truth))
    assert tracks.visible[15, tracks.start == 0].sum() < 0.5 * tracks.visible[0].sum()
    fit = fit_camera_poses(tracks, K)
    assert fit is not None
    np.testing.assert_allclose(fit.world_to_camera[0], np.eye(4), atol=1e-9)
    rotation, direction = errors_against(fit, truth)
    assert rotation < 0.2 and direction < 2.0
    assert fit.inlier_ratio[1:].min() > 0.9


def test_tracks_on_things_that_move_do_not_pull_the_poses():
    """A quarter of the background tracks drift (a person, a shadow): a random walk of 1.5 px per frame."""
    truth = travelling_camera()
    tracks = background_tracks(truth)
    rng = np.random.default_rng(1)
    moving = rng.random(tracks.num_tracks) < 0.25
    uv = tracks.uv.astype(np.float64)
    uv[:, moving] += np.cumsum(rng.normal(0, 1.5, (tracks.num_frames, moving.sum(), 2)), axis=0)
    fit = fit_camera_poses(Tracks(uv.astype(np.float32), tracks.visible, tracks.start), K)
    rotation, direction = errors_against(fit, truth)
    assert rotation < 0.2 and direction < 2.0
    assert np.median(fit.residual_px[1:]) < 0.7


def test_the_bundle_adjustment_moves_a_displaced_camera_back():
    """Cameras moved 0.05 units off their true places (tens of pixels at depths of 3-12) come back to within
    0.02 and 0.05 degrees: the points are triangulated again from the displaced cameras first, which leaves
    about 0.01."""
    truth = travelling_camera()
    tracks = background_tracks(truth, noise=0.0)
    uv = tracks.uv.astype(np.float64)
    # Each track's true point, from its first and last frames' true cameras (the tracks have no noise).
    points = np.full((tracks.num_tracks, 3), np.nan)
    for m in range(tracks.num_tracks):
        seen = np.nonzero(tracks.visible[:, m])[0]
        if len(seen) >= 2:
            h = cv2.triangulatePoints(K @ truth[seen[0], :3], K @ truth[seen[-1], :3], uv[seen[0], m, :, None],
                                      uv[seen[-1], m, :, None])
            points[m] = h[:3, 0] / h[3, 0]
    start = truth.copy()
    start[1:, :3, 3] += np.random.default_rng(3).normal(0, 0.05 / np.sqrt(3), (len(truth) - 1, 3))
    solved = np.ones(len(truth), bool)
    poses, _ = _refine(start, points, uv, tracks.visible, solved, 0, K, 100.0, 12, 2)
    assert np.abs(poses[:, :3, 3] - truth[:, :3, 3]).max() < 0.02
    assert errors_against(type("Fit", (), {"world_to_camera": poses})(), truth)[0] < 0.05
