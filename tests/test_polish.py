import numpy as np
import pytest

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.render import render
from marionette.target.lift import LiftOptions, lift_image
from marionette.target.polish import polish_reference

SIZE = 64


def checker_photo():
    """A disc with a two-pixel checker: detail the splats blur."""
    img = np.zeros((SIZE, SIZE, 4), np.uint8)
    yy, xx = np.mgrid[:SIZE, :SIZE]
    inside = (xx - 31.5) ** 2 + (yy - 31.5) ** 2 < 22**2
    img[inside] = (60, 60, 200, 255)
    img[inside & ((xx // 2 + yy // 2) % 2 == 0), :3] = (230, 200, 40)
    return img, inside


def psnr(a, b, mask):
    return 10 * np.log10(1.0 / ((a - b) ** 2)[mask].mean())


def test_polish_brings_the_reference_view_closer_and_leaves_the_shape_alone():
    img, inside = checker_photo()
    camera = Camera.from_fov(SIZE, SIZE, 40.0)
    lifted = lift_image(img, camera=camera, options=LiftOptions(shape="inflate"))
    polished, losses = polish_reference(lifted.gaussians, camera, img, inside, 8)
    assert len(losses) == 9 and losses[-1] < 0.8 * losses[0]
    before, after = render(lifted.gaussians, camera).image, render(polished, camera).image
    ref = img[..., :3] / 255.0
    assert psnr(after, ref, inside) > psnr(before, ref, inside) + 2.0
    g, p = lifted.gaussians, polished
    for name in ("means", "quats", "log_scales"):
        assert np.array_equal(getattr(g, name), getattr(p, name))
    # The back, unseen from the reference view, keeps its colours and opacities.
    _, z = camera.project(g.means)
    back = z > np.percentile(z, 80)
    assert np.array_equal(g.sh[back], p.sh[back]) and np.array_equal(g.opacity_logits[back], p.opacity_logits[back])
    assert p.opacities.min() >= min(0.3, g.opacities.min()) - 1e-6  # no surfel turns into a hole


def test_polish_through_the_lift_options():
    img, inside = checker_photo()
    plain = lift_image(img)
    polished = lift_image(img, options=LiftOptions(polish=3))
    assert len(plain.gaussians) == len(polished.gaussians)
    assert not np.array_equal(plain.gaussians.sh, polished.gaussians.sh)
    assert polish_reference(plain.gaussians, plain.camera, img, inside, 0)[0] is plain.gaussians
    with pytest.raises(InputError, match="polish"):
        lift_image(img, options=LiftOptions(polish=-1))
