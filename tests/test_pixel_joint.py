"""A plain part's joint from its pixels and the masks (marionette.source.pixel_joint), on synthetic scenes."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.geometry import invert_transform, matrix_to_axis_angle
from marionette.source.hinge import _initial_hinge
from marionette.source.pixel_joint import fit_pixel_joint, place_unseen_angles
from marionette.synthetic import make_scene


def _still_body_scene(obj: str, motion: str, seed: int):
    """The first plain scene from ``seed`` on whose body stays still."""
    while True:
        scene = make_scene(motion, object=obj, seed=seed, num_frames=24, size=(320, 240), plain=True)
        if np.abs(scene.poses[0] - np.eye(4)).max() < 1e-9:
            return scene
        seed += 1


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))))))


@pytest.mark.parametrize("obj, motion, seed", [("door", "hinge", 1), ("hinge", "hinge", 20), ("drawer", "slide", 1)])
def test_fit_pixel_joint_on_plain_parts(obj, motion, seed):
    """Plain faces, few tracks: with the parts' pixels and frame 0's depth, the joint's type and axis come out
    right (measured 0.1-0.4°) and its range within a few per cent; the poses it started from (the part not
    moving) cost more."""
    scene = _still_body_scene(obj, motion, seed)
    truth = scene.part_masks[0]
    mask = truth >= 0
    depth = np.where(mask, scene.depths[0], np.nan)
    still = np.tile(np.eye(4), (len(scene.frames), 1, 1))
    fit = fit_pixel_joint(scene.frames, scene.masks, scene.camera.K, still, mask, truth == 1, depth, still)
    relative = invert_transform(scene.poses[0][-1]) @ scene.poses[1][-1]
    turn = matrix_to_axis_angle(relative[:3, :3])
    if motion == "hinge":
        assert fit.kind == "hinge" and _angle(fit.axis, turn) < 1.0
        assert abs(abs(np.degrees(fit.values[-1])) - np.degrees(np.linalg.norm(turn))) < 6.0
    else:
        travel = relative[:3, 3]
        assert fit.kind == "slider" and _angle(fit.axis, travel) < 1.0
        assert abs(abs(fit.values[-1]) / np.linalg.norm(travel) - 1.0) < 0.05
    assert fit.cost < 0.8 * fit.start_cost
    # The poses move the part's frame-0 points as the joint says.
    assert np.allclose(fit.poses[0], np.eye(4), atol=1e-9)


@pytest.mark.parametrize("obj, seed", [("screen", 3), ("hinge", 4)])
def test_angles_where_the_tracks_do_not_see_the_part_come_from_its_pixels(obj, seed):
    """The last third of a turn that no track sees (its angles held where they were) is placed from the part's
    pixels and the mask, about the true hinge, within a few degrees at every frame; the other frames keep
    their angles."""
    scene = make_scene("hinge", object=obj, seed=seed, num_frames=24, size=(320, 240))
    axis, point, truth = _initial_hinge(invert_transform(scene.poses[0]) @ scene.poses[1])
    unseen = np.arange(24) >= 16
    held = np.where(unseen, truth[15], truth)
    mask = scene.part_masks[0] >= 0
    angles = place_unseen_angles(scene.frames, scene.masks, scene.camera.K, scene.poses[0], mask,
                                 scene.part_masks[0] == 1, np.where(mask, scene.depths[0], np.nan), axis, point,
                                 held, unseen)
    assert np.array_equal(angles[~unseen], truth[~unseen])
    assert np.degrees(np.abs(held - truth)[unseen]).max() > 8.0  # what there was to find
    assert np.degrees(np.abs(angles - truth)[unseen]).max() < 3.0
