import numpy as np
import pytest

from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
from marionette.render import render
from marionette.synthetic import object_view
from marionette.target.lift import LiftOptions, lift_image
from marionette.target.mirror import fit_mirror_hull

KWARGS = {"size": (160, 160), "seed": 0, "fov_deg": 60.0}


def turned_iou(lifted, centre, yaw: float, pitch: float, turn: float) -> float:
    """Silhouette IoU of the lift turned ``turn`` degrees about the car's own vertical axis, against the truth."""
    up = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    r = axis_angle_to_matrix(up * np.radians(turn))
    g = lifted.gaussians
    seen = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)),
                  lifted.camera).alpha > 0.5
    truth = object_view("car", yaw_deg=yaw + turn, pitch_deg=pitch, **KWARGS)[0][..., 3] > 0
    return float((seen & truth).sum() / (seen | truth).sum())


@pytest.mark.parametrize("yaw, pitch", [(50.0, 10.0), (35.0, 25.0)])
def test_a_car_seen_at_an_angle_is_carved_from_both_sides_and_turns_as_a_car(yaw, pitch):
    photo, camera, centre = object_view("car", yaw_deg=yaw, pitch_deg=pitch, **KWARGS)
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    assert lifted.shape.name == "mirror" and lifted.shape.solid_iou >= 0.9
    sheets = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2]), solids=False))
    assert turned_iou(lifted, centre, yaw, pitch, 0.0) > 0.9  # the photo's own outline
    solid, folded = turned_iou(lifted, centre, yaw, pitch, 90.0), turned_iou(sheets, centre, yaw, pitch, 90.0)
    assert solid > 0.72 and solid > folded + 0.1, (solid, folded)


def test_the_carved_car_is_its_own_mirror_image():
    photo, camera, centre = object_view("car", yaw_deg=45.0, pitch_deg=15.0, **KWARGS)
    hull = fit_mirror_hull(photo[..., 3] > 0, camera, float(centre[2]))
    assert hull is not None
    from scipy.spatial import cKDTree

    gap, _ = cKDTree(hull.vertices).query(hull.reflect(hull.vertices))
    cell = 2 * hull.box.half.max() / 64
    assert np.quantile(gap, 0.99) < 0.01 * cell  # the carving keeps both sides alike


def test_seen_square_on_one_side_tells_nothing_to_carve_with():
    photo, camera, centre = object_view("car", yaw_deg=0.0, pitch_deg=5.0, **KWARGS)
    assert fit_mirror_hull(photo[..., 3] > 0, camera, float(centre[2])) is None
    yy, xx = np.mgrid[:120, :120]
    disc = ((xx - 60) ** 2 + (yy - 60) ** 2 < 40**2).astype(np.uint8) * 255
    with pytest.raises(InputError, match="--shape mirror"):
        lift_image(np.dstack([np.full((120, 120, 3), 140, np.uint8), disc]), options=LiftOptions(shape="mirror"))
