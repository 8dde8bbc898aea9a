import numpy as np
import pytest

from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, make_transform, rotation_angle_deg
from marionette.prior import SpatPrior
from marionette.transfer.controls import retime
from marionette.transfer.velocity import integrate, part_radii


def prior_from_motion(rotvecs, shifts, centre=(0.0, 0.0, 5.0), radius=1.0):
    """One part turning by ``rotvecs[t]`` about ``centre`` and shifted by ``shifts[t]``."""
    c = np.asarray(centre, float)
    poses, cents = [], []
    for rv, sh in zip(rotvecs, shifts):
        r = axis_angle_to_matrix(rv)
        poses.append(make_transform(r, c + sh - r @ c))
        cents.append(c + sh)
    return SpatPrior.from_poses(np.array(poses)[None], np.array(cents)[None], np.array([radius]), fps=10.0,
                                image_size=(64, 64), intrinsics=np.eye(3))


def cloud(n=200, centre=(2.0, -1.0, 8.0), size=0.5, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * size + centre


def test_zero_motion_gives_zero_motion():
    pts = cloud()
    prior = prior_from_motion(np.zeros((5, 3)), np.zeros((5, 3)))
    traj = integrate(pts, np.zeros(len(pts), int), prior)
    assert np.allclose(traj.means, pts[None], atol=1e-6)
    assert np.allclose(traj.part_rotations, np.eye(3))


def test_single_part_is_rigid():
    pts = cloud()
    t = np.linspace(0, 1, 20)[:, None]
    prior = prior_from_motion(t * [0.3, 1.2, 0.2], t * [0.5, 0.0, -1.0])
    traj = integrate(pts, np.zeros(len(pts), int), prior)
    d0 = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    d = np.linalg.norm(traj.means[-1][:, None] - traj.means[-1][None], axis=2)
    # float32 storage: relative error ~1e-6.
    assert np.abs(d - d0).max() / d0.max() < 1e-5


def test_inplane_quarter_turn_about_own_centre():
    pts = cloud()
    t = np.linspace(0, 1, 10)[:, None]
    prior = prior_from_motion(t * [0, 0, np.pi / 2], np.zeros((10, 3)))
    traj = integrate(pts, np.zeros(len(pts), int), prior)
    c = pts.mean(axis=0)
    assert np.allclose(traj.means[-1].mean(axis=0), c, atol=1e-5)  # turns in place, no orbit
    expected = (pts - c) @ axis_angle_to_matrix([0, 0, np.pi / 2]).T + c
    assert np.allclose(traj.means[-1], expected, atol=1e-5)
    assert rotation_angle_deg(traj.part_rotations[-1, 0]) == pytest.approx(90.0, abs=1e-3)


def test_lateral_translation_scales_with_size():
    pts = cloud(size=0.5)
    _, (r_target,) = part_radii(pts, np.zeros(len(pts), int), 1)
    source_radius = 2.0
    t = np.linspace(0, 1, 8)[:, None]
    prior = prior_from_motion(np.zeros((8, 3)), t * [3.0, 0, 0], radius=source_radius)
    traj = integrate(pts, np.zeros(len(pts), int), prior)
    moved = traj.means[-1].mean(axis=0) - pts.mean(axis=0)
    # Source moved 1.5 of its radii: the target moves 1.5 of its own.
    assert moved[0] / r_target == pytest.approx(3.0 / source_radius, rel=1e-5)
    assert np.allclose(moved[1:], 0, atol=1e-6)


def test_world_anchor_is_the_papers_equation():
    pts = cloud()
    t = np.linspace(0, 1, 6)[:, None]
    prior = prior_from_motion(t * [0, 0.5, 0], t * [0.2, 0, 0])
    traj = integrate(pts, np.zeros(len(pts), int), prior, anchor="world")
    mu = pts.copy()
    for s in range(5):
        mu = mu @ prior.rotations[0, s].T + prior.translations[0, s]  # Eq. 5
    assert np.allclose(traj.means[-1], mu, atol=1e-5)


def test_two_parts_move_independently():
    pts = cloud(100)
    labels = (pts[:, 0] > pts[:, 0].mean()).astype(int)
    a = prior_from_motion(np.zeros((5, 3)), np.zeros((5, 3)))
    b = prior_from_motion(np.linspace(0, 1, 5)[:, None] * [0, 0, 1.0], np.zeros((5, 3)))
    two = SpatPrior.from_poses(np.concatenate([a.poses, b.poses]), np.concatenate([a.centroids, b.centroids]),
                               np.ones(2), fps=10, image_size=(64, 64), intrinsics=np.eye(3))
    traj = integrate(pts, labels, two)
    assert np.allclose(traj.means[-1][labels == 0], pts[labels == 0], atol=1e-6)
    assert not np.allclose(traj.means[-1][labels == 1], pts[labels == 1], atol=1e-2)


def test_bad_labels_and_anchor():
    pts = cloud(10)
    prior = prior_from_motion(np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(InputError):
        integrate(pts, np.ones(10, int), prior)
    with pytest.raises(InputError):
        integrate(pts, np.zeros(10, int), prior, anchor="nowhere")


def test_retime_half_speed_hits_source_poses_and_interpolates():
    t = np.linspace(0, 1, 5)[:, None]
    prior = prior_from_motion(t * [0, 1.0, 0], t * [1.0, 0, 0])
    slow = retime(prior, speed=0.5)
    assert slow.num_frames == 9
    assert np.allclose(slow.poses[0, ::2], prior.poses[0], atol=1e-12)
    # In-between frames turn by half a step: angle 0.125 rad at frame 1.
    assert rotation_angle_deg(slow.poses[0, 1, :3, :3]) == pytest.approx(np.degrees(0.125))


def test_retime_length_holds_last_pose_and_rejects_bad_speed():
    t = np.linspace(0, 1, 4)[:, None]
    prior = prior_from_motion(t * [0, 1.0, 0], np.zeros((4, 3)))
    longer = retime(prior, frames=10)
    assert np.allclose(longer.poses[0, 3:], prior.poses[0, -1])
    fast = retime(prior, speed=2.0)
    assert fast.num_frames == 2 and np.allclose(fast.poses[0, 1], prior.poses[0, 2])
    with pytest.raises(InputError):
        retime(prior, speed=0.0)
