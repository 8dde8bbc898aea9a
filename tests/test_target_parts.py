"""Target part assignment: seeds from the source layout, geodesic flood fill, boundary band."""

import numpy as np
import pytest

from marionette.errors import InputError
from marionette.transfer.parts import boundary_band, labels_from_seeds, seeds_from_layout


def u_shape():
    """A 'U' of points (two arms joined at the bottom) in the plane z = 5; pixels = (x, y) * 10."""
    xs, ys = np.meshgrid(np.arange(0, 10.0), np.arange(0, 30.0))
    arm = np.column_stack([xs.ravel(), ys.ravel()])
    left, right = arm, arm + [14, 0]
    bottom = np.column_stack([g.ravel() for g in np.meshgrid(np.arange(0, 24.0), np.arange(30, 40.0))])
    xy = np.concatenate([left, right, bottom]) * 0.1
    means = np.column_stack([xy, np.full(len(xy), 5.0)])
    return means, np.rint(xy * 10).astype(int)


def test_flood_fill_follows_the_shape_not_straight_lines():
    means, pixels = u_shape()
    # Seeds at the top of the left arm and in the middle of the bottom bar.
    labels = labels_from_seeds(means, pixels, {0: (4, 0), 1: (12, 35)})
    top_right = (pixels[:, 0] >= 14) & (pixels[:, 1] < 5)
    # The right arm's top is nearer the left seed in a straight line, but reached through the bottom: part 1.
    assert np.linalg.norm(means[top_right][0, :2] - [0.4, 0]) < np.linalg.norm(means[top_right][0, :2] - [1.2, 3.5])
    assert np.all(labels[top_right] == 1)
    assert np.all(labels[(pixels[:, 0] < 10) & (pixels[:, 1] < 10)] == 0)
    band = boundary_band(means, labels)
    assert 0 < band.sum() < 0.2 * len(means)
    assert set(np.unique(labels[band])) == {0, 1}
    with pytest.raises(InputError, match="seeds"):
        labels_from_seeds(means, pixels, {})


def test_layout_seeds_land_at_the_same_relative_place():
    source = np.full((40, 80), -1)
    source[10:30, 20:40] = 0  # left half of the object
    source[10:30, 40:60] = 1  # right half
    target = np.zeros((100, 100), bool)
    target[20:80, 10:90] = True
    seeds = seeds_from_layout(source, target)
    assert seeds[0] == pytest.approx((29.5, 49.5), abs=0.6)
    assert seeds[1] == pytest.approx((69.5, 49.5), abs=0.6)


def test_joint_of_a_hinge_is_found_and_kept_attached():
    from marionette.synthetic import make_scene
    from marionette.transfer.parts import joint_offsets
    from marionette.transfer.velocity import integrate, part_radii

    scene = make_scene("hinge", seed=0, num_frames=12, size=(160, 120))
    prior = scene.ground_truth_prior()  # part 0 the body (static here), part 1 the lid
    root, offsets = joint_offsets(prior)
    assert root == 0 and set(offsets) == {1}
    # The joint lies on the hinge axis: it stays put under the lid's motion.
    joint = prior.centroids[1, 0] + offsets[1] * prior.radii[1]
    moved = np.einsum("tij,j->ti", prior.poses[1, :, :3, :3], joint) + prior.poses[1, :, :3, 3]
    assert np.abs(moved - joint).max() < 1e-4 * prior.radii[1]
    # Integrated on the source's own points, the lid's joint stays where it was.
    points = np.concatenate(scene.part_points)
    labels = np.repeat([0, 1], [len(p) for p in scene.part_points])
    cents, radii = part_radii(points, labels, 2)
    target_joint = cents[1] + offsets[1] * radii[1]
    traj = integrate(points, labels, prior, joints={1: target_joint}, root=0)
    lid = traj.means[:, labels == 1].astype(np.float64)
    nearest = np.argmin(np.linalg.norm(points[labels == 1] - target_joint, axis=1))
    drift = np.linalg.norm(lid[:, nearest] - lid[0, nearest], axis=1).max()
    assert drift < 0.05 * radii[1] + np.linalg.norm(points[labels == 1][nearest] - target_joint)
