"""The result inside the photo's scene: the clean plate, the compositor, the command line."""

import cv2
import numpy as np
import pytest

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.scene import SceneCompositor, clean_plate
from marionette.scene.composite import _plane_homography
from marionette.target.lift import LiftOptions, lift_image
from marionette.trajectory import Trajectory

pytestmark = pytest.mark.heavy

SIZE = 96


def psnr(a, b, where=None):
    diff = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    mse = diff[where].mean() if where is not None else diff.mean()
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


def scene_photo():
    """(SIZE, SIZE, 3) photo of a checkered disc in front of a striped, shaded wall, and the disc's mask."""
    yy, xx = np.mgrid[:SIZE, :SIZE].astype(np.float64)
    stripes = 0.5 + 0.5 * np.sin(2 * np.pi * xx / 12.0)
    wall = np.stack([60 + 120 * stripes, 90 + 0.8 * yy, 150 - 80 * stripes], axis=2)
    mask = (xx - 48) ** 2 + (yy - 50) ** 2 < 22**2
    checker = ((xx // 6 + yy // 6) % 2).astype(bool)
    disc = np.where(checker[..., None], [230, 200, 40], [40, 60, 200])
    photo = np.where(mask[..., None], disc, wall)
    return np.clip(photo, 0, 255).astype(np.uint8), mask, np.clip(wall, 0, 255).astype(np.uint8)


def test_the_plate_keeps_the_photo_outside_the_object_and_continues_the_scene_inside():
    photo, mask, wall = scene_photo()
    for method in ("fsr", "telea"):
        plate = clean_plate(photo, mask, method)
        assert plate.shape == photo.shape and plate.dtype == np.uint8
        grown = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
        np.testing.assert_array_equal(plate[~grown], photo[~grown])
        # Nothing of the object is left: the disc's yellow and blue are gone.
        assert np.abs(plate[mask].astype(float) - wall[mask]).mean() < 45
    # Texture-continuing fill: the stripes run on through the hole, better than diffusion fills them.
    core = cv2.erode(mask.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    errors = {m: np.abs(clean_plate(photo, mask, m)[core].astype(float) - wall[core]).mean() for m in ("fsr", "telea")}
    assert errors["fsr"] < errors["telea"]


@pytest.mark.parametrize("method", ["fsr", "patch", "telea"])
def test_the_fill_does_not_depend_on_the_hidden_objects_colours(method):
    """At a size the fill works on scaled down: recolouring the object changes nothing of the plate."""
    photo, mask, _ = scene_photo()
    photo = cv2.resize(photo, (300, 300), interpolation=cv2.INTER_NEAREST)
    mask = cv2.resize(mask.astype(np.uint8), (300, 300), interpolation=cv2.INTER_NEAREST) > 0
    recoloured = photo.copy()
    recoloured[mask] = (250, 0, 250)
    np.testing.assert_array_equal(clean_plate(photo, mask, method), clean_plate(recoloured, mask, method))


@pytest.mark.parametrize("bad, message", [("everything", "covers the whole photo"), ("method", "inpainting method")])
def test_the_plate_refuses_what_it_cannot_do(bad, message):
    photo, mask, _ = scene_photo()
    with pytest.raises(InputError, match=message):
        if bad == "everything":
            clean_plate(photo, np.ones_like(mask))
        else:
            clean_plate(photo, mask, "flat")


def lifted_scene(detail=True):
    photo, mask, _ = scene_photo()
    camera = Camera.from_fov(SIZE, SIZE, 40.0)
    lifted = lift_image(photo, mask=mask, camera=camera, options=LiftOptions(shape="revolve"))
    compositor = SceneCompositor.from_lift(lifted.gaussians, camera, lifted.pixel_of, photo,
                                           clean_plate(photo, mask), detail=detail)
    return photo, mask, lifted, compositor


def moved(lifted, shift, turn_deg=0.0):
    """A two-frame trajectory: at rest, then turned about its centre and shifted by ``shift`` (3,) world units."""
    g = lifted.gaussians
    centre = g.means.mean(axis=0).astype(np.float64)
    r = axis_angle_to_matrix([0.0, np.radians(turn_deg), 0.0])
    pose = make_transform(r, centre + np.asarray(shift) - r @ centre)
    means = np.stack([g.means, g.means @ pose[:3, :3].T.astype(np.float32) + pose[:3, 3].astype(np.float32)])
    return Trajectory(means, np.stack([np.eye(3), r])[:, None].astype(np.float32), np.zeros(len(g), np.int32))


def frames(compositor, lifted, trajectory, camera=None):
    camera = camera or lifted.camera
    return [compositor.frame(trajectory.frame(lifted.gaussians, t), trajectory.frame(compositor.features, t), camera)
            for t in range(trajectory.num_frames)]


def test_frame_0_reproduces_the_photo_and_the_untouched_scene_stays_put():
    photo, mask, lifted, compositor = lifted_scene()
    depth = compositor.depth
    trajectory = moved(lifted, [0.45 * depth * np.tan(np.radians(20)), 0, 0])  # far to the right
    first, later = frames(compositor, lifted, trajectory)
    assert psnr(first, photo) >= 35
    # Without the photo's detail, frame 0 is the lift's own render: worse.
    _, _, _, plain = lifted_scene(detail=False)
    assert psnr(frames(plain, lifted, trajectory)[0], photo) < psnr(first, photo) - 3
    # Later: away from where the object was and is, the photo is untouched.
    from marionette.render import render

    alpha = render(trajectory.frame(lifted.gaussians, 1), lifted.camera).alpha > 1 / 255
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    never = ~alpha & ~grown
    assert never.sum() > 0.3 * never.size
    np.testing.assert_array_equal(later[never], photo[never])
    # The spot it left shows the wall again, not the disc: no yellow or blue checker left there.
    vacated = mask & ~alpha
    assert vacated.sum() > 200
    plate = clean_plate(photo, mask)
    assert psnr(later, plate, vacated) > 40


def test_the_object_keeps_the_photos_texture_when_it_moves():
    """Shifted sideways, the disc carries its checker: compared with the photo's disc moved by the same
    pixels, the detail layer makes it closer than the lift's own render."""
    photo, mask, lifted, compositor = lifted_scene()
    _, _, _, plain = lifted_scene(detail=False)
    from marionette.render import render

    front = render(lifted.gaussians, lifted.camera).depth[50, 48]  # the disc's centre moves by shift_px
    shift_px = 12
    trajectory = moved(lifted, [shift_px * front / lifted.camera.fx, 0, 0])
    shifted_photo = np.roll(photo, shift_px, axis=1)
    inner = np.roll(cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool), shift_px, axis=1)
    with_detail, without = frames(compositor, lifted, trajectory)[1], frames(plain, lifted, trajectory)[1]
    assert psnr(with_detail, shifted_photo, inner) > psnr(without, shifted_photo, inner) + 2


def test_the_plate_is_a_plane_at_the_objects_depth():
    reference = Camera.from_fov(SIZE, SIZE, 40.0)
    assert _plane_homography(reference, reference, 5.0) is None  # the same camera copies the plate
    turn = make_transform(axis_angle_to_matrix([0.0, np.radians(10), 0.0]), [0.3, -0.1, 0.2])
    moved_camera = reference.with_pose(turn)
    homography = _plane_homography(reference, moved_camera, 5.0)
    # A point on the plane, seen by the moved camera, maps to where the reference camera sees it.
    point = np.array([0.4, -0.3, 5.0])
    uv_ref, _ = reference.project(point[None])
    uv_new, _ = moved_camera.project(point[None])
    mapped = homography @ np.r_[uv_new[0], 1.0]
    np.testing.assert_allclose(mapped[:2] / mapped[2], uv_ref[0], atol=1e-3)


@pytest.fixture
def scene_png(tmp_path):
    photo, _, _ = scene_photo()
    path = tmp_path / "scene.png"
    cv2.imwrite(str(path), cv2.cvtColor(photo, cv2.COLOR_RGB2BGR))
    return path, photo


def test_the_command_line_puts_the_result_in_the_photo(tmp_path, prior_file, scene_png):
    from marionette.cli import main
    from marionette.io import read_video

    path, photo = scene_png
    out = tmp_path / "frames"  # a PNG folder: no compression between us and the pixels
    assert main(["transfer", str(prior_file), str(path), "-o", str(out), "--background", "scene", "-q"]) == 0
    frames = read_video(out).frames
    assert frames.shape == (8, SIZE, SIZE, 3)
    assert psnr(frames[0], photo) > 45
    assert psnr(frames[-1], photo) < 30  # the disc turned in the image plane


def test_the_command_line_scene_size_follows_size(tmp_path, prior_file, scene_png):
    from marionette.cli import main
    from marionette.io import read_video

    path, _ = scene_png
    out = tmp_path / "out.mp4"
    assert main(["transfer", str(prior_file), str(path), "-o", str(out), "--background", "scene", "--size", "48x40",
                 "--camera", "orbit", "-q"]) == 0
    assert read_video(out).frames.shape[1:3] == (40, 48)


@pytest.mark.parametrize("background, message", [("scene", "needs an image target"),
                                                 ("sky", "R,G,B within 0-1 or 0-255, or 'scene'")])
def test_the_command_line_refuses_a_scene_it_cannot_have(tmp_path, prior_file, capsys, background, message):
    from marionette.cli import main
    from marionette.gaussians import Gaussians
    from marionette.io import write_ply

    ply = tmp_path / "target.ply"
    write_ply(ply, Gaussians.from_rgb(np.random.default_rng(0).normal(size=(50, 3)), np.full((50, 3), 0.5),
                                      np.full(50, 0.1)))
    out = tmp_path / "out.mp4"
    assert main(["transfer", str(prior_file), str(ply), "-o", str(out), "--background", background, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists()


def test_a_transparent_photo_is_warned_about(tmp_path, prior_file, target_png, capsys):
    from marionette.cli import main

    out = tmp_path / "out.mp4"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(out), "--background", "scene", "-q"]) == 0
    assert "transparent around its object" in capsys.readouterr().err
