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
