import numpy as np
import pytest
from scipy import ndimage

from marionette.camera import Camera
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
from marionette.render import render
from marionette.synthetic import object_view
from marionette.target.lift import LiftOptions, lift_image
from marionette.target.revolution import fit_revolution
from marionette.target.shapes import choose_shape, revolve_profile


def turned(gaussians, centre, axis_angle):
    r = axis_angle_to_matrix(np.asarray(axis_angle, dtype=np.float64))
    return gaussians.with_means((gaussians.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r))


def can_view(yaw, pitch, plain=False):
    from marionette.synthetic import object_view

    return object_view("cylinder", size=(256, 256), seed=0, yaw_deg=yaw, pitch_deg=pitch, plain=plain)


@pytest.mark.parametrize("plain", [False, True])
def test_a_can_seen_from_above_leans_as_the_photo_shows_and_turns_about_its_own_axis(plain):
    pitch = 20.0
    photo, camera, centre = can_view(30, pitch, plain)
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    assert lifted.shape.name == "revolve" and lifted.shape.solid_iou > 0.95
    assert lifted.shape.pitch == pytest.approx(pitch, abs=5.0)
    sheets = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2]), solids=False))
    up = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    truth = can_view(120, pitch, plain)[0][..., 3] > 0

    def iou(gaussians):
        seen = render(turned(gaussians, centre, up * np.pi / 2), camera).alpha > 0.5
        return (seen & truth).sum() / (seen | truth).sum()

    # Measured 0.955 (both textures); the sheets about an axis in the image plane 0.83.
    assert iou(lifted.gaussians) > 0.93
    assert iou(lifted.gaussians) > iou(sheets.gaussians) + 0.05


@pytest.mark.parametrize("axis_angle", [(0, np.pi / 2, 0), (0, np.pi, 0), (np.pi / 2, 0, 0), (0.7, 0.9, 0)])
def test_a_solid_of_revolution_is_closed_from_every_side(axis_angle):
    size = 96
    img = np.zeros((size, size, 4), np.uint8)
    yy, xx = np.mgrid[:size, :size]
    inside = (xx - 47.5) ** 2 + (yy - 47.5) ** 2 < 28**2
    img[inside] = (90, 160, 220, 255)
    lifted = lift_image(img, camera=Camera.from_fov(size, size, 30.0))
    assert lifted.shape.name == "revolve" and lifted.shape.solid_iou is not None
    g = lifted.gaussians
    alpha = render(turned(g, 0.5 * (g.means.min(axis=0) + g.means.max(axis=0)), axis_angle), lifted.camera).alpha
    solid = alpha > 0.5
    assert solid.sum() > 500
    assert (ndimage.binary_fill_holes(solid) & ~solid).sum() == 0
    assert alpha[ndimage.binary_erosion(solid, iterations=2)].min() > 0.97


def test_hidden_surface_is_quilted_from_the_visible_side_not_streaked():
    from marionette.target.synthesis import fill_unseen

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:40, :60]
    stripes = np.stack([(xx // 3 % 2) * 0.8 + 0.1, (yy // 5 % 2) * 0.5 + 0.2, np.full(xx.shape, 0.4)], -1)
    known = xx < 30  # the right half unseen, its colours garbage
    filled = fill_unseen(np.where(known[..., None], stripes, 7.0), known, rng)
    assert np.array_equal(filled[known], stripes[known])
    hidden = filled[:, 40:]  # away from the seam: the stripes both ways, in the known colours
    assert hidden.min() >= 0.1 - 1e-9 and hidden.max() <= 0.9 + 1e-9
    assert np.abs(np.diff(hidden[..., 0], axis=1)).mean() > 0.1  # varies across, as the vertical stripes do
    assert np.abs(np.diff(hidden[..., 1], axis=0)).mean() > 0.03  # ... and down, as the horizontal ones do


def test_a_pots_bands_stay_at_their_heights_when_its_hidden_side_is_quilted():
    """A label between two bands of paint: quilted from any rows, the label's colours spread into the paint;
    kept to their rows (``keep_rows``, as a solid of revolution's side is filled), each row keeps its band's
    colour, and the patches still carry the texture across (checkers within the label)."""
    from marionette.target.synthesis import fill_unseen

    yy, xx = np.mgrid[:60, :80]
    label = (yy >= 20) & (yy < 40)
    checker = ((xx // 4 + yy // 4) % 2) * 0.4 + 0.5
    bands = np.where(label[..., None], np.stack([checker, checker, checker], -1), [0.8, 0.1, 0.1])
    known = xx < 40
    for keep_rows, share in ((False, 0.2), (True, 0.05)):  # measured 0.39 and 0.03
        filled = fill_unseen(np.where(known[..., None], bands, 7.0), known, np.random.default_rng(0), keep_rows)
        hidden = filled[:, 50:]
        red = np.abs(hidden - [0.8, 0.1, 0.1]).max(axis=-1) < 0.05
        misplaced = (red & label[:, 50:]).mean() + (~red & ~label[:, 50:] & (np.abs(yy[:, 50:] - 30) > 13)).mean()
        assert (misplaced < share) if keep_rows else (misplaced > share)
    assert np.abs(np.diff(filled[25:35, 50:, 0], axis=1)).mean() > 0.05


@pytest.mark.parametrize("seed, yaw, pitch", [(0, 50.7, 9.0), (1, 20.0, 25.0), (2, 35.0, 15.0)])
def test_a_cans_side_is_straight_without_ribs(seed, yaw, pitch):
    """Each ring is scaled where its outline is widest: read at its centre's row, perspective made it answer
    for a neighbour and the radii swung by several per cent along the side."""
    photo, camera, centre = object_view("cylinder", yaw_deg=yaw, pitch_deg=pitch, size=(192, 192), seed=seed,
                                        fov_deg=60.0)
    mask = photo[..., 3] > 0
    choice = choose_shape(mask, "auto")
    radius, _, pieces = revolve_profile(mask, *choice.axis)
    body = fit_revolution(pieces == 1, radius, *choice.axis, camera, float(centre[2]), photo)
    side = body.radii[len(body.radii) // 10: -(len(body.radii) // 10)]
    along = np.arange(len(side))
    straight = np.polyval(np.polyfit(along, side, 1), along)
    assert np.abs(side / straight - 1).max() < 0.025


def _fitted(obj, seed, yaw, pitch, fov, plain=True):
    photo, camera, centre = object_view(obj, yaw_deg=yaw, pitch_deg=pitch, size=(192, 192), seed=seed, fov_deg=fov,
                                        plain=plain)
    mask = photo[..., 3] > 0
    choice = choose_shape(mask, "auto")
    radius, _, pieces = revolve_profile(mask, *choice.axis)
    return fit_revolution(pieces == 1, radius, *choice.axis, camera, float(centre[2]), photo), centre


@pytest.mark.parametrize("obj", ["cylinder", "vase"])
def test_the_lean_is_read_from_any_ring_round_the_body(obj):
    """Random views (pitch 0-35°, field of view 30-70°), many with the top seen edge-on or from below, where
    no rim shows: the steps round a vase and the rim of a can tell the lean. Measured on these views: median
    error 2.3° (can) and 2.4° (vase), worst 4.9° and 11.1°; reading the top rim alone, medians 2.2° and 7.7°,
    worst 19.9° and 11.1°."""
    errors = []
    for seed in range(8):
        rng = np.random.default_rng(500 + seed)
        yaw, pitch, fov = rng.uniform(0, 90), rng.uniform(0, 35), rng.uniform(30, 70)
        body, _ = _fitted(obj, seed, yaw, pitch, fov)
        errors.append(abs(body.pitch - pitch))
    assert np.median(errors) < 3.5 and max(errors) < 12.5


def test_the_bodys_middle_is_at_the_depth_given_on_the_objects_axis():
    """Perspective puts the middle of the axis off the middle of the outline's rows: the body is placed by its
    3D middle, which lies on the true axis near the true centre (measured 0.002 of the height apart; 0.02
    placed by the rows' middle)."""
    pitch = 25.0
    body, centre = _fitted("cylinder", 1, 20.0, pitch, 60.0)
    middle = body.base + 0.5 * body.heights[-1] * body.axis
    assert middle[2] == pytest.approx(centre[2], rel=1e-9)
    assert np.linalg.norm(middle - centre) < 0.01 * body.heights[-1]


def test_a_spout_near_the_top_of_a_leaning_pot_stays_on_it():
    """A spout's sheets sit at the depth of the body's axis where it meets the body, not at the body's middle:
    on a pot leaning 25° towards the camera the axis near the top is nearer than the middle, and a spout left at
    the middle's depth would float off the pot once turned (measured: 0.05 of that gap from the axis; 0.96 at
    the middle's depth)."""
    photo, camera, centre = can_view(30, 25.0)
    mask = photo[..., 3] > 0
    rows, cols = np.nonzero(mask)
    top, right = rows.min(), cols.max()
    root = top + (rows.max() - top) // 4
    yy, xx = np.mgrid[: mask.shape[0], : mask.shape[1]]
    spout = (xx > right - 4) & (xx < right + 45) & (np.abs(yy - root + 0.6 * (xx - right)) < 5) & ~mask
    photo = photo.copy()
    photo[spout] = (40, 40, 200, 255)
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    assert lifted.shape.name == "revolve"
    u, v = lifted.pixel_of[:, 0], lifted.pixel_of[:, 1]
    on_spout = spout[v, u] & (u > right + 5)
    assert on_spout.sum() > 10
    # The body's axis where the spout leaves it: halfway between its nearest and farthest surface on that row.
    means = lifted.gaussians.means
    k = (root - camera.cy) / camera.fy
    on_row = ~spout[v, u] & (np.abs(means[:, 1] / means[:, 2] - k) < 1.0 / camera.fy)
    z_axis = 0.5 * (means[on_row, 2].min() + means[on_row, 2].max())
    z_spout = np.median(means[on_spout, 2])
    assert abs(z_spout - z_axis) < 0.25 * abs(centre[2] - z_axis)
