import cv2
import numpy as np
import pytest

from marionette.errors import InputError
from marionette.target.lift import lift_image
from marionette.target.shapes import SHAPES, choose_shape, shape_depth


def polygon_mask(points, size=(120, 160)):
    mask = np.zeros(size, np.uint8)
    cv2.fillPoly(mask, [np.asarray(points, np.int32)], 1)
    return mask.astype(bool)


def vase_mask(size=(160, 120), tilt=0.0, spout=False):
    """A vase-like silhouette symmetric about x = 60 + tilt (y - 80); optionally a spout on one side."""
    yy, xx = np.mgrid[: size[0], : size[1]].astype(np.float64)
    t = (yy - 20) / 120
    radius = 18 + 22 * np.sin(np.pi * np.clip(t, 0, 1)) ** 0.8
    mask = (np.abs(xx - (60 + tilt * (yy - 80))) < radius) & (t >= 0) & (t <= 1)
    if spout:
        mask |= (xx > 80) & (xx < 108) & (np.abs(yy - 50 + 0.6 * (xx - 80)) < 4)
    return mask


def test_a_rectangle_and_a_box_seen_at_an_angle_are_boxes_other_polygons_extruded():
    rect = polygon_mask([(30, 30), (130, 30), (130, 90), (30, 90)])
    choice = choose_shape(rect)
    assert choice.name == "cuboid" and not choice.forced and choice.corners == 4
    assert choice.confidence > 0.97
    hexagon = polygon_mask([(20, 40), (70, 25), (140, 35), (140, 95), (70, 108), (20, 92)])
    assert choose_shape(hexagon).name == "cuboid"
    # A pentagon may be a box whose hexagon lost a corner to a straight line, but a house's gable end is
    # none: no box explains it, and the lift pushes it straight back.
    gable = polygon_mask([(30, 60), (80, 20), (130, 60), (130, 110), (30, 110)])
    choice = choose_shape(gable)
    assert choice.name == "cuboid" and choice.fallback == "extrude"
    photo = np.dstack([np.full(gable.shape + (3,), 150, np.uint8), gable.astype(np.uint8) * 255])
    assert lift_image(photo).shape.name == "extrude"


def test_round_symmetric_outlines_are_revolved_and_asymmetric_ones_inflated():
    choice = choose_shape(vase_mask())
    assert choice.name == "revolve" and choice.symmetry > 0.99 and choice.corners > 6
    assert choice.axis[0] == pytest.approx(60, abs=0.5) and choice.axis[1] == pytest.approx(0, abs=1e-9)
    # A spout breaks the symmetry a little: still a surface of revolution.
    assert choose_shape(vase_mask(spout=True)).name == "revolve"
    # A kidney-shaped blob has no mirror axis and no corners.
    yy, xx = np.mgrid[:120, :160]
    blob = ((xx - 70) ** 2 / 50**2 + (yy - 60) ** 2 / 30**2 < 1) & ~((xx - 60) ** 2 + (yy - 95) ** 2 < 26**2)
    blob |= (xx - 115) ** 2 + (yy - 40) ** 2 < 18**2
    choice = choose_shape(blob)
    assert choice.name == "inflate" and choice.symmetry < 0.85


def test_a_tilted_axis_is_found():
    choice = choose_shape(vase_mask(tilt=0.1))
    assert choice.name == "revolve"
    assert choice.axis[1] == pytest.approx(0.1, abs=0.03)


def test_forcing_a_shape_is_reported_and_bad_names_refused():
    mask = vase_mask()
    for name in SHAPES:
        choice = choose_shape(mask, name)
        assert choice.name == name and choice.forced
        assert name in choice.describe() and "forced" in choice.describe()
        assert choice.as_dict()["name"] == name
    with pytest.raises(InputError, match="shape must be auto or one of"):
        choose_shape(mask, "sphere")
    with pytest.raises(InputError, match="empty"):
        choose_shape(np.zeros((10, 10), bool))


def test_revolved_rows_are_circles_and_a_spout_gets_its_own_volume():
    mask = vase_mask(spout=True)
    _, half, pieces = shape_depth(mask, choose_shape(mask, "revolve"))
    spout = mask & ~vase_mask()
    assert len(np.unique(pieces[spout])) == 1 and pieces[spout][0] > 1  # a piece of its own, closed apart
    assert (pieces[vase_mask()] == 1).mean() > 0.95
    for row in (40, 80, 120):
        cols = np.nonzero(mask[row, :80])[0]
        radius = 60 - cols.min() + 0.5  # the chord reaches half a pixel beyond its end pixels
        assert half[row, 60] == pytest.approx(radius, abs=0.6)  # as deep as the row is wide
        off = int(radius // 2)
        assert half[row, 60 + off] == pytest.approx(np.sqrt(radius**2 - off**2), abs=0.6)
    assert (half[spout] > 0).all() and half[spout].max() < 8  # thin: its own inflation, not the body's
    assert (half[~mask] == 0).all()


def test_an_extrusion_is_flat_with_rounded_edges():
    rect = polygon_mask([(30, 30), (130, 30), (130, 90), (30, 90)])
    half = shape_depth(rect, choose_shape(rect, "extrude"))[1]
    depth = 2 * half[60, 80]
    assert depth == pytest.approx(61, abs=1.5)  # the short side of the silhouette
    assert np.ptp(half[40:80, 40:120]) < 1e-6  # flat away from the outline
    assert half[60, 30] < half[60, 33] < half[60, 80]  # rounded toward the outline
    assert half[60, 30] > 0.5 * half[60, 80]  # a wall remains: rounded edges, not a cushion


def test_a_handle_and_a_spout_facing_each_other_do_not_widen_the_body():
    yy, xx = np.mgrid[:140, :200].astype(np.float64)
    body = (xx - 100) ** 2 / 45**2 + (yy - 80) ** 2 / 40**2 < 1
    handle = (np.abs(np.hypot(xx - 150, yy - 70) - 18) < 4) & (xx > 140)  # a thin ring on the right
    spout = (xx > 40) & (xx < 60) & (np.abs(yy - 70 + 0.5 * (60 - xx)) < 4)  # a thin spout on the left
    mask = body | handle | spout
    choice = choose_shape(mask)
    assert choice.name == "revolve"
    half = shape_depth(mask, choice).half
    # On the rows the two reach, the body keeps its own radius: their mirror images overlap, and joined to the
    # body they would make a row 130 px wide, a disc like a brim seen from the side.
    for row in (62, 70, 78):
        body_radius = 45 * np.sqrt(1 - (row - 80) ** 2 / 40**2)
        assert half[row, 100] == pytest.approx(body_radius, rel=0.15)
