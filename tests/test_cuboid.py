import cv2
import numpy as np
import pytest

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
from marionette.render import render
from marionette.target.cuboid import Cuboid, box_depth, cuboid_surfels, fit_cuboid
from marionette.target.lift import LiftOptions, lift_image

SIZE = 128
# Solid colours of the faces (axis k, side -1 / +1): each pair alike in hue, so a mirror image is told apart.
COLOURS = {(0, -1): (220, 40, 40), (0, 1): (40, 200, 60), (1, -1): (40, 70, 220), (1, 1): (230, 200, 40),
           (2, -1): (200, 60, 200), (2, 1): (60, 200, 210)}


def random_box(rng: np.random.Generator, camera: Camera) -> Cuboid:
    """A box 2-3 units across, turned at random but showing three faces, 7-9 units in front of the camera."""
    turn = (axis_angle_to_matrix([np.radians(rng.uniform(15, 35)), 0.0, 0.0])
            @ axis_angle_to_matrix([0.0, np.radians(rng.uniform(20, 70)), 0.0]))
    return Cuboid(np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(7, 9)]), turn.T,
                  rng.uniform(0.8, 1.5, 3))


def box_photo(box: Cuboid, camera: Camera, texture: bool = False) -> np.ndarray:
    """(H, W, 4) RGBA photo of the box's faces that face the camera (a convex box hides nothing else)."""
    img = np.zeros((camera.height, camera.width, 4), np.uint8)
    for (k, s), colour in COLOURS.items():
        centre = box.centre + s * box.half[k] * box.axes[k]
        if (s * box.axes[k]) @ centre >= 0:
            continue
        i, j = [m for m in range(3) if m != k]
        quad = [centre + a * box.half[i] * box.axes[i] + b * box.half[j] * box.axes[j]
                for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        uv, _ = camera.project(np.array(quad))
        cv2.fillConvexPoly(img, np.rint(uv * 16).astype(np.int32), (*colour, 255), cv2.LINE_8, shift=4)
    if texture:  # fine stripes across the image, for synthesis to copy
        img[..., :3] = np.where((np.arange(camera.width) // 3 % 2 == 0)[None, :, None], img[..., :3] * 0.7,
                                img[..., :3]).astype(np.uint8)
    return img


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two boxes' frames (3, 3), up to each axis' sign (a box has no front)."""
    return float(np.degrees(max(np.arccos(min(abs(a[k] @ b[k]), 1.0)) for k in range(3))))


def test_a_box_is_fitted_from_its_outline_in_perspective():
    camera = Camera.from_fov(SIZE, SIZE, 60.0)  # wide: the orthographic reading alone is some degrees off
    rng = np.random.default_rng(0)
    for _ in range(6):
        truth = random_box(rng, camera)
        mask = box_photo(truth, camera)[..., 3] > 0
        box = fit_cuboid(mask, camera, float(truth.centre[2]))
        assert box is not None and box.iou > 0.97
        # Its edges may come in another order: match each true edge to the fitted one along it.
        order = [int(np.argmax(np.abs(box.axes @ axis))) for axis in truth.axes]
        assert sorted(order) == [0, 1, 2]
        assert angle_between(box.axes[order], truth.axes) < 4.0
        assert box.half[order] == pytest.approx(truth.half, rel=0.08)
        assert box.centre == pytest.approx(truth.centre, abs=0.1)


def test_box_depth_is_the_nearest_face_along_each_ray():
    """Against a slow twin: each pixel's ray marched in small steps until it enters the box."""
    camera = Camera.from_fov(SIZE, SIZE, 60.0)
    box = random_box(np.random.default_rng(3), camera)
    mask = box_photo(box, camera)[..., 3] > 0
    depth = box_depth(box, camera.K, mask)
    assert np.isfinite(depth[mask]).all() and np.isnan(depth[~mask]).all()
    rng = np.random.default_rng(4)
    vv, uu = np.nonzero(mask)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)  # rays that surely hit
    for i in rng.choice(np.flatnonzero(inner[vv, uu]), 20, replace=False):
        ray = np.linalg.solve(camera.K, [uu[i], vv[i], 1.0])
        steps = np.arange(5.0, 12.0, 1e-4)
        inside = np.all(np.abs((steps[:, None] * ray - box.centre) @ box.axes.T) <= box.half, axis=1)
        assert depth[vv[i], uu[i]] == pytest.approx(steps[np.argmax(inside)], abs=2e-4)


def test_no_box_in_a_round_outline():
    camera = Camera.from_fov(SIZE, SIZE, 30.0)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    assert fit_cuboid((xx - 64) ** 2 + (yy - 64) ** 2 < 40**2, camera, 5.0) is None


def face_colours(gaussians, box: Cuboid) -> dict[tuple[int, int], np.ndarray]:
    """The mean colour (3,) in [0, 255] of the Gaussians on each face (k, s)."""
    local = (gaussians.means - box.centre) @ box.axes.T / box.half  # on a face, one coordinate is ±1
    colour = gaussians.rgb * 255
    out = {}
    for k, s in COLOURS:
        on = np.abs(local[:, k] - s) < 1e-3
        out[(k, s)] = colour[on].mean(axis=0)
    return out


def test_seen_faces_keep_their_colours_and_hidden_ones_mirror_their_opposites():
    camera = Camera.from_fov(SIZE, SIZE, 40.0)
    truth = random_box(np.random.default_rng(1), camera)
    photo = box_photo(truth, camera)
    mask = photo[..., 3] > 0
    box = Cuboid(truth.centre, truth.axes, truth.half)
    gaussians, pixel_of = cuboid_surfels(box, photo, mask, camera, 1, 0.98, 30.0)
    colours = face_colours(gaussians, box)
    for (k, s), colour in colours.items():
        seen = (s * box.axes[k]) @ (box.centre + s * box.half[k] * box.axes[k]) < 0
        expected = COLOURS[(k, s)] if seen else COLOURS[(k, -s)]  # a hidden face shows its opposite, mirrored
        assert colour == pytest.approx(expected, abs=12)
    assert pixel_of.shape == (len(gaussians), 2) and mask[pixel_of[:, 1], pixel_of[:, 0]].mean() > 0.97


def test_faces_no_view_shows_are_synthesised_from_a_seen_face_not_streaked():
    camera = Camera.from_fov(SIZE, SIZE, 40.0)
    turn = axis_angle_to_matrix([0.0, np.radians(35), 0.0])  # seen level: neither top nor bottom shows
    box = Cuboid(np.array([0.0, 0.0, 8.0]), turn.T, np.array([1.4, 1.0, 1.2]))
    photo = box_photo(box, camera, texture=True)
    gaussians, _ = cuboid_surfels(box, photo, photo[..., 3] > 0, camera, 1, 0.98, 30.0)
    local = (gaussians.means - box.centre) @ box.axes.T / box.half
    colour = gaussians.rgb * 255
    seen = np.concatenate([COLOURS[(0, 1)], COLOURS[(2, -1)], COLOURS[(0, -1)], COLOURS[(2, 1)]]).reshape(-1, 3)
    for s in (-1, 1):
        on = np.abs(local[:, 1] - s) < 1e-3
        top = colour[on]
        # Its colours are the seen faces' (none of the top's or bottom's own, which no view shows)...
        nearest = np.linalg.norm(top.mean(axis=0) - seen, axis=1).min()
        assert nearest < 45
        # ... with their stripes, in patches across the face both ways: no streaks along one direction.
        x, z = local[on, 0], local[on, 2]
        grid = colour[on].sum(axis=1)
        assert grid.std() > 10
        along_x = np.abs(np.diff(grid[np.lexsort((x, z))])).mean()
        along_z = np.abs(np.diff(grid[np.lexsort((z, x))])).mean()
        assert 0.2 < along_x / along_z < 5.0


def blurred_psnr(truth: np.ndarray, image: np.ndarray, alpha: np.ndarray) -> float:
    """PSNR over the silhouettes' union of both images on grey, blurred (σ = 3 px): colours in the right places."""
    true_mask, mask = truth[..., 3] > 0, alpha > 0.5
    a = cv2.GaussianBlur(np.where(true_mask[..., None], truth[..., :3], 128).astype(np.float32), (0, 0), 3)
    b = cv2.GaussianBlur(np.where(mask[..., None], image, 128).astype(np.float32), (0, 0), 3)
    return float(10 * np.log10(255**2 / ((a - b) ** 2)[true_mask | mask].mean()))


@pytest.mark.parametrize("pitch", [20, 0])  # from above; level (perspective alone bends the outline)
def test_a_photographed_box_turns_as_a_box(pitch):
    from marionette.synthetic import object_view

    def view(yaw):
        return object_view("box", size=(SIZE, SIZE), seed=0, yaw_deg=yaw, pitch_deg=pitch, fov_deg=30)

    photo, camera, centre = view(30)
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    assert lifted.shape.name == "cuboid" and lifted.shape.solid_iou > 0.97
    up = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    # Measured (pitch 20 / 0): IoU 0.975 / 0.951 and 23.8 / 16.9 dB at 45°, 0.982 / 0.967 and 16.1 / 12.3 dB at
    # 90°; the sheets over the silhouette gave 0.915 / 0.961 and 0.921 / 0.949.
    for turn, least in ((45, 16.0), (90, 11.5)):
        r = axis_angle_to_matrix(up * np.radians(turn))
        g = lifted.gaussians
        out = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)), camera)
        seen, truth = out.alpha > 0.5, view(30 + turn)[0]
        assert (seen & (truth[..., 3] > 0)).sum() / (seen | (truth[..., 3] > 0)).sum() > 0.94
        image = np.clip(np.rint(out.image * 255), 0, 255).astype(np.uint8)
        assert blurred_psnr(truth, image, out.alpha) > least


def test_cuboid_forced_on_a_round_outline_is_an_input_error():
    yy, xx = np.mgrid[:SIZE, :SIZE]
    img = np.zeros((SIZE, SIZE, 4), np.uint8)
    img[(xx - 64) ** 2 + (yy - 64) ** 2 < 40**2] = (200, 100, 50, 255)
    with pytest.raises(InputError, match="no box"):
        lift_image(img, options=LiftOptions(shape="cuboid"))


def test_a_box_seen_square_on_from_above_is_fitted_from_generic_starts():
    from marionette.synthetic import object_view

    def view(yaw):
        return object_view("box", size=(256, 256), seed=0, yaw_deg=yaw, pitch_deg=25)

    photo, camera, centre = view(0)  # front and top only: the outline is no box's hexagon read orthographically
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    assert lifted.shape.name == "cuboid" and lifted.shape.solid_iou > 0.97
    sheets = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2]), solids=False))
    assert sheets.shape.name == lifted.shape.fallback  # the sheets' own choice, as before boxes were built
    up = axis_angle_to_matrix([np.radians(25), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    r = axis_angle_to_matrix(up * np.pi / 2)
    g = lifted.gaussians
    seen = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)), camera).alpha > 0.5
    truth = view(90)[0][..., 3] > 0
    assert (seen & truth).sum() / (seen | truth).sum() > 0.95  # measured 0.98; the sheets 0.71


def test_every_box_from_random_views_is_rebuilt_as_a_box():
    """Including those seen nearly level, whose outline's hexagon loses a corner to a straight line (five)."""
    from marionette.synthetic import object_view

    rng = np.random.default_rng(7)
    corners = set()
    for _ in range(12):
        yaw, pitch, seed, fov = rng.uniform(0, 90), rng.uniform(0, 35), int(rng.integers(0, 50)), rng.uniform(30, 70)
        photo, camera, centre = object_view("box", yaw_deg=yaw, pitch_deg=pitch, size=(160, 160), seed=seed,
                                            fov_deg=fov)
        lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2]), relight=False))
        assert lifted.shape.name == "cuboid" and lifted.shape.solid_iou >= 0.93, (yaw, pitch, lifted.shape)
        corners.add(lifted.shape.corners)
    assert 5 in corners
