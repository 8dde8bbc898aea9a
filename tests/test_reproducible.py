"""Rounding onto a grid before a choice that could flip on last bits (marionette.reproducible)."""

from __future__ import annotations

import numpy as np

from marionette.geometry import axis_angle_to_matrix, make_transform, matrix_to_axis_angle
from marionette.reproducible import snap, snap_pose

STEP = 2.0 ** -16


def random_poses(count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_transform(axis_angle_to_matrix(rng.uniform(-2.5, 2.5, size=(count, 3))),
                          rng.normal(scale=3.0, size=(count, 3)))


def test_snap_rounds_to_the_nearest_multiple_and_keeps_nan():
    values = np.array([0.26, -0.26, 0.24, 1.0, np.nan])
    assert np.array_equal(snap(values, 0.5), np.array([0.5, -0.5, 0.0, 1.0, np.nan]), equal_nan=True)
    fine = np.random.default_rng(1).normal(size=1000)
    snapped = snap(fine, STEP)
    assert np.abs(snapped - fine).max() <= STEP / 2
    assert np.array_equal(snapped / STEP, np.round(snapped / STEP))


def test_snapped_poses_are_rigid_and_near_the_originals():
    poses = random_poses(200)
    snapped = snap_pose(poses, STEP)
    rotations = snapped[:, :3, :3]
    assert np.abs(rotations @ np.swapaxes(rotations, 1, 2) - np.eye(3)).max() < 1e-11
    assert np.allclose(np.linalg.det(rotations), 1.0, atol=1e-11)
    assert np.array_equal(snapped[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (200, 1)))
    vectors = matrix_to_axis_angle(rotations)
    assert np.abs(vectors - snap(vectors, STEP)).max() < 1e-11  # the rotation vector on the grid
    assert np.abs(vectors - matrix_to_axis_angle(poses[:, :3, :3])).max() <= STEP / 2 + 1e-11
    assert np.array_equal(snapped[:, :3, 3], snap(poses[:, :3, 3], STEP))


def test_poses_a_few_ulps_apart_snap_to_the_same_bits():
    """What two machines' BLAS kernels or SIMD paths hand on differs in the last bits; snapped, it does not."""
    poses = random_poses(300, seed=2)
    nudged = poses * (1.0 + 4e-16 * np.random.default_rng(3).standard_normal(poses.shape))
    assert not np.array_equal(poses, nudged)
    assert np.array_equal(snap_pose(poses, STEP), snap_pose(nudged, STEP))
    points = np.random.default_rng(4).normal(scale=5.0, size=(3000, 3))
    assert np.array_equal(snap(points, STEP), snap(points * (1.0 + 1e-15), STEP))
