import numpy as np
import pytest
from scipy import ndimage

from marionette.camera import Camera
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion, quaternion_to_matrix
from marionette.render import render
from marionette.target.lift import LiftOptions, lift_image

SIZE = 96


def rectangle_photo(stripes=False):
    """RGBA photo of a 50 x 30 px rectangle; with ``stripes``, its colour alternates every 4 columns."""
    img = np.zeros((SIZE, SIZE, 4), np.uint8)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    inside = (np.abs(xx - 47.5) < 25) & (np.abs(yy - 47.5) < 15)
    img[inside] = (200, 120, 40, 255)
    if stripes:
        img[inside & ((xx // 4) % 2 == 0), :3] = (40, 60, 200)
    return img, inside


def disc_photo():
    img = np.zeros((SIZE, SIZE, 4), np.uint8)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    inside = (xx - 47.5) ** 2 + (yy - 47.5) ** 2 < 28**2
    img[inside] = (90, 160, 220, 255)
    return img, inside


def turned(lifted, axis_angle):
    """The lifted Gaussians turned about the centre of their bounding box."""
    g = lifted.gaussians
    centre = 0.5 * (g.means.min(axis=0) + g.means.max(axis=0))
    r = axis_angle_to_matrix(np.asarray(axis_angle, dtype=np.float64))
    return g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r))


def lift(img, shape):
    """The sheets lift (these tests are about :mod:`marionette.target.surfels`, not the solids)."""
    camera = Camera.from_fov(SIZE, SIZE, 30.0)
    return lift_image(img, camera=camera, options=LiftOptions(shape=shape, solids=False))


@pytest.mark.parametrize("shape", ["inflate", "revolve", "extrude"])
@pytest.mark.parametrize("axis_angle", [(0, np.pi / 2, 0), (0, np.pi, 0), (np.pi / 2, 0, 0), (0.7, 0.9, 0)])
def test_the_surface_is_closed_from_every_side(shape, axis_angle):
    img, _ = disc_photo()
    lifted = lift(img, shape)
    alpha = render(turned(lifted, axis_angle), lifted.camera).alpha
    solid = alpha > 0.5
    assert solid.sum() > 500
    holes = ndimage.binary_fill_holes(solid) & ~solid
    assert holes.sum() == 0
    inner = ndimage.binary_erosion(solid, iterations=2)
    assert alpha[inner].min() > 0.97


def test_an_extruded_box_shows_its_depth_and_straight_sides_from_the_side():
    img, inside = rectangle_photo()
    lifted = lift(img, "extrude")
    alpha = render(turned(lifted, (0, np.pi / 2, 0)), lifted.camera).alpha
    cols = np.nonzero((alpha > 0.5).any(axis=0))[0]
    rows = np.nonzero((alpha > 0.5).any(axis=1))[0]
    # The depth is the silhouette's short side: the side view is as wide as it is tall (both magnified a
    # little by perspective, its near end now being closer).
    assert len(cols) / len(rows) == pytest.approx(1.0, abs=0.08)
    assert len(rows) == pytest.approx(30, rel=0.2)
    # Straight sides: the side view's silhouette fills its bounding box but for the rounded corners.
    box = alpha[rows.min():rows.max() + 1, cols.min():cols.max() + 1] > 0.5
    assert box.mean() > 0.93


def test_walls_are_not_rim_pixels_drawn_out_along_depth():
    img, inside = rectangle_photo(stripes=True)
    lifted = lift(img, "extrude")
    g = lifted.gaussians
    # Left wall, seen from the left: turn the box 90 degrees so its left side faces the camera.
    out = render(turned(lifted, (0, np.pi / 2, 0)), lifted.camera)
    solid = out.alpha > 0.5
    rows = np.nonzero(solid.any(axis=1))[0]
    middle = out.image[(rows.min() + rows.max()) // 2][solid[(rows.min() + rows.max()) // 2]]
    # The photo's stripes run across the wall (folded in from the front), so the wall is not one colour
    # along depth as a rim pixel copied backwards would make it.
    blue = middle[:, 2]
    assert blue.max() - blue.min() > 0.3
    assert len(g) < 6 * inside.sum()  # sampled by area: front, back and walls, not a pile per pixel


@pytest.mark.parametrize("shape", ["inflate", "revolve"])
def test_a_steep_slope_gets_long_surfels_not_a_row_of_small_ones(shape):
    img, inside = disc_photo()
    g = lift(img, shape).gaussians
    # The photo holds about a pixel of detail down a slope near the outline: one surfel up to three cells
    # long covers it (a row of one-cell surfels there made about five surfels per photo pixel).
    assert len(g) < 4 * inside.sum()
    tangent = np.sort(g.scales, axis=1)[:, 1:]
    elongation = tangent[:, 1] / tangent[:, 0]
    assert 2.0 < elongation.max() < 6.0


def test_surfels_are_flat_and_face_along_the_surface_normal():
    img, inside = disc_photo()
    lifted = lift(img, "extrude")
    g = lifted.gaussians
    scales = g.scales
    assert np.all(scales.min(axis=1) <= 0.25 * np.sort(scales, axis=1)[:, 1] + 1e-12)
    # On the flat face of the extrusion the thin axis is the viewing direction (±z in the camera frame).
    _, z = lifted.camera.project(g.means)
    deep = ndimage.binary_erosion(inside, iterations=8)[lifted.pixel_of[:, 1], lifted.pixel_of[:, 0]]
    front = deep & (z < np.median(z))
    rot = quaternion_to_matrix(g.quats[front] / np.linalg.norm(g.quats[front], axis=1, keepdims=True))
    thin = rot[np.arange(front.sum()), :, np.argmin(scales[front], axis=1)]
    assert np.median(np.abs(thin[:, 2])) > 0.99
    assert np.all(np.isfinite(g.quats)) and np.allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-5)


def test_thin_parts_survive():
    img = np.zeros((SIZE, SIZE, 4), np.uint8)
    img[10:86, 47:49] = (30, 30, 30, 255)  # a bar two pixels wide
    img[10:12, 30:66] = (30, 30, 30, 255)
    for shape in ("inflate", "extrude", "revolve"):
        lifted = lift(img, shape)
        assert np.all(np.isfinite(lifted.gaussians.means)) and np.all(np.isfinite(lifted.gaussians.quats))
        alpha = render(lifted.gaussians, lifted.camera).alpha
        assert (alpha[img[..., 3] > 0] > 0.5).all()
        side = render(turned(lifted, (0, np.pi / 3, 0)), lifted.camera).alpha
        assert (side > 0.5).sum() > 0.5 * (img[..., 3] > 0).sum()


def _same_surfels(a, b):
    assert len(a) == len(b)
    np.testing.assert_allclose(a.means, b.means, rtol=0, atol=1e-6)
    np.testing.assert_allclose(a.log_scales, b.log_scales, rtol=0, atol=1e-5)
    np.testing.assert_allclose(a.sh, b.sh, rtol=0, atol=1e-5)
    # q and -q are the same rotation; both paths keep w >= 0, so compare the matrices.
    np.testing.assert_allclose(quaternion_to_matrix(a.quats), quaternion_to_matrix(b.quats), rtol=0, atol=1e-5)


@pytest.mark.parametrize("shape", ["inflate", "revolve", "extrude"])
def test_the_numba_sampler_matches_its_numpy_twin(shape, monkeypatch):
    from marionette.target import lift as lift_module
    from marionette.target import surfels

    img, _ = rectangle_photo(stripes=True)
    img[20:40, 60:70, :3] = (10, 220, 90)  # a patch of another colour, away from the outline
    fast = lift(img, shape).gaussians
    monkeypatch.setattr(lift_module, "sample_surface",
                        lambda *args, **kwargs: surfels.sample_surface(*args, **kwargs, reference=True))
    _same_surfels(fast, lift(img, shape).gaussians)


def test_the_numba_sampler_matches_its_twin_on_degenerate_patches():
    """A sheet of zero thickness: its walls have no height (their frames fall back to a perpendicular),
    and a cell squeezed to a point on the outline."""
    from marionette.target.surfels import sample_surface

    img, inside = disc_photo()
    stride = 4
    cells = inside[stride // 2::stride, stride // 2::stride].astype(np.int64)
    mid = np.full(cells.shape, 5.0)
    half = np.zeros(cells.shape)
    half[cells.shape[0] // 2:] = 0.3  # half the disc has thickness, half none
    camera = Camera.from_fov(SIZE, SIZE, 30.0)
    results = [sample_surface(img, inside, cells, mid, half, camera, stride, 0.9, 20.0, reference=reference)
               for reference in (False, True)]
    _same_surfels(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])
