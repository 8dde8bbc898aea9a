"""Frames where something in front covers the object: told from the masks, fitted only where the object shows."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.camera import Camera
from marionette.reconstruct import fit
from marionette.reconstruct._views import FitView
from marionette.reconstruct.fit import _image_loss
from marionette.reconstruct.joint import JointOptions, joint_fit
from marionette.reconstruct.occlusion import covered_frames
from marionette.synthetic import make_scene


def discs(centres_x, radii, size=(100, 160)) -> np.ndarray:
    """(T, H, W) bool discs at (x, 50)."""
    y, x = np.mgrid[:size[0], :size[1]]
    return np.array([(x - cx) ** 2 + (y - 50) ** 2 <= r ** 2 for cx, r in zip(centres_x, radii)])


def test_a_ball_behind_a_post_is_covered_where_it_dips_and_nowhere_else():
    masks = discs(np.linspace(30, 130, 12), [20] * 12)
    masks[4:7, :, 70:90] = False  # a post in front of frames 4-6
    shares = covered_frames(masks)
    assert list(shares) == [4, 5, 6] and all(0.25 <= s <= 1 for s in shares.values())
    # nearing the camera (a quarter more area each frame) is no dip, nor is leaving the frame by its border
    assert covered_frames(discs([80] * 12, 8 * 1.12 ** np.arange(12))) == {}
    out_and_back = discs([80, 100, 120, 140, 160, 175, 160, 140, 120, 100, 80, 60], [20] * 12)
    areas = out_and_back.sum(axis=(1, 2))
    assert areas[5] < 0.25 * areas[0] and covered_frames(out_and_back) == {}
    assert covered_frames(masks[4:7]) == {}  # the first and last frames have one side only


def test_a_covered_view_counts_only_where_the_object_shows():
    rng = np.random.default_rng(0)
    mask = np.zeros((20, 30), np.float32)
    mask[5:15, 5:12] = 1.0
    mask[5:15, 12] = 0.5
    target = np.where(mask[..., None] > 0, rng.uniform(0, 1, (20, 30, 3)), 1.0).astype(np.float32)
    camera = Camera(np.array([[30.0, 0, 15], [0, 30.0, 10], [0, 0, 1]]), np.eye(4), 30, 20)
    covered = FitView(0, camera, target, mask, covered=True)
    image, alpha = rng.uniform(0, 1, (20, 30, 3)), rng.uniform(0, 1, (20, 30))
    loss, d_image, d_alpha = _image_loss(image, alpha, covered, 0.5, 0.2)
    # what is drawn off the mask (behind the cover, maybe) costs nothing, nor does alpha above it
    off = mask == 0
    image2, alpha2 = image.copy(), alpha.copy()
    image2[off], alpha2[off] = rng.uniform(0, 1, (off.sum(), 3)), rng.uniform(0, 1, off.sum())
    alpha2[mask == 1] = np.maximum(alpha2[mask == 1], 1.0)
    assert _image_loss(image2, alpha, covered, 0.5, 0.2)[0] == pytest.approx(loss)
    assert _image_loss(image, alpha2, covered, 0.5, 0.2)[0] < loss
    assert not d_image[off].any() and not d_alpha[off].any()
    # gradients against central differences
    for grad, which in ((d_image, 0), (d_alpha, 1)):
        direction = rng.normal(size=grad.shape)
        step = 1e-4

        def at(offset: float) -> float:
            moved = [image, alpha]
            moved[which] = moved[which] + offset * direction
            return _image_loss(*moved, covered, 0.5, 0.2)[0]

        assert float(np.sum(grad * direction)) == pytest.approx((at(step) - at(-step)) / (2 * step), rel=1e-3)
    # the same view uncovered counts everything
    assert _image_loss(image2, alpha, FitView(0, camera, target, mask), 0.5, 0.2)[0] != pytest.approx(
        _image_loss(image, alpha, FitView(0, camera, target, mask), 0.5, 0.2)[0])


def test_a_post_in_front_of_half_the_object_does_not_pull_its_poses(monkeypatch):
    """A post covers the right half of the object on frames 5-8 (painted into the frames, cut from the masks).
    Started from the true poses, the joint fit keeps every frame's centre within 0.05 radii; its twin, told
    nothing of the post, pulls the covered frames off it (and the model with them)."""
    scene = make_scene("translation", num_frames=14, size=(192, 144), seed=0)
    truth = scene.ground_truth_prior()
    frames, masks = scene.frames.copy(), scene.masks.copy()
    xs = np.nonzero(masks[6])[1]
    post = slice(int(np.percentile(xs, 50)), int(xs.max()) + 40)
    frames[5:9, :, post], masks[5:9, :, post] = (90, 70, 50), False
    assert list(covered_frames(masks)) == [5, 6, 7, 8]

    def centre_error() -> np.ndarray:
        fitted = joint_fit(frames, masks, truth, options=JointOptions(visits=30, track_weight=0.0)).prior
        return np.linalg.norm(fitted.centroids[0] - truth.centroids[0], axis=1) / truth.radii[0]

    aware = centre_error()
    assert aware.max() < 0.05, aware.round(3)
    monkeypatch.setattr(fit, "covered_frames", lambda masks: {})
    unaware = centre_error()
    assert np.median(unaware[5:9]) > 0.07, unaware.round(3)
