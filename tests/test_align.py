"""Photometric pose refinement (marionette.reconstruct.align) on frames rendered from a known model.

The frames are rendered from the very Gaussians the aligner is given, so the
true poses are the loss's minimum and a perturbed pose must come back to them.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from marionette.camera import Camera
from marionette.errors import InputError
from marionette.gaussians import Gaussians
from marionette.geometry import axis_angle_to_matrix, invert_transform, make_transform, rotation_angle_deg
from marionette.reconstruct._init import pose_gaussians
from marionette.reconstruct.align import (
    AlignOptions,
    align_poses,
    joint_gradient,
    move_joints,
    move_parts,
    twist_gradient,
    twist_loss,
)
from marionette.reconstruct.joints import Hinge, check_hinges, hinges_from_metadata, snap_to_hinges
from marionette.reconstruct.shading import Lighting, Shading, unit_rows
from marionette.render import render

pytestmark = pytest.mark.heavy

W, H = 192, 160
K = np.array([[190.0, 0, W / 2], [0, 190.0, H / 2], [0, 0, 1]])


def _box_surface(rng, n: int, half: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """n points (n, 3) on the faces of a box with half-sizes ``half`` (3,) around ``centre``."""
    pts = rng.uniform(-1, 1, size=(n, 3)) * half
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = np.sign(rng.uniform(-1, 1, n)) * half[face]
    return pts + centre


def textured_object(seed: int = 0, two_parts: bool = False) -> tuple[Gaussians, np.ndarray]:
    """A textured box (and a lid on it) 5 units in front of the camera: Gaussians (N) and their parts (N,).

    Small (0.7 px) opaque Gaussians: the silhouette is sharp, as in a model fitted to binary masks.
    """
    rng = np.random.default_rng(seed)
    body = _box_surface(rng, 2500, np.array([0.9, 0.5, 0.6]), np.array([0.0, 0.2, 5.0]))
    means, parts = body, np.zeros(len(body), np.int32)
    if two_parts:
        lid = _box_surface(rng, 1000, np.array([0.9, 0.08, 0.6]), np.array([0.0, -0.42, 5.0]))
        means, parts = np.concatenate([body, lid]), np.concatenate([parts, np.ones(len(lid), np.int32)])
    n = len(means)
    colours = rng.uniform(-0.45, 0.45, size=(n, 1, 3))  # SH DC: a random texture
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    return Gaussians(means.astype(np.float32), quats.astype(np.float32),
                     np.full((n, 3), np.log(0.035), np.float32), np.full(n, 4.0, np.float32),
                     colours.astype(np.float32)), parts


def frame_of(gaussians, parts, poses) -> tuple[np.ndarray, np.ndarray]:
    """The object moved by poses (K, 4, 4) rendered on white: a uint8 frame (H, W, 3) and its mask (H, W)."""
    out = render(pose_gaussians(gaussians, parts, poses), Camera(K, np.eye(4), W, H), (1.0, 1.0, 1.0))
    return np.round(out.image * 255).astype(np.uint8), out.alpha > 0.5


def turn(axis, degrees: float, shift=(0.0, 0.0, 0.0), about=(0.0, 0.2, 5.0)) -> np.ndarray:
    """A 4x4 rotation by ``degrees`` about ``axis`` through the point ``about``, then a shift."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    rot = axis_angle_to_matrix(np.radians(degrees) * axis)
    about = np.asarray(about)
    return make_transform(rot, about - rot @ about + np.asarray(shift))


def errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Rotation (degrees) and translation differences of two poses (4, 4)."""
    diff = invert_transform(truth) @ estimate
    return float(rotation_angle_deg(diff[:3, :3])), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))


def align_one(gaussians, parts, truth: np.ndarray, start: np.ndarray, frame=None, mask=None, **kw):
    """Align frame 1 (rendered at ``truth`` (K, 4, 4) unless given) from ``start`` (K, 4, 4)."""
    if frame is None:
        frame, mask = frame_of(gaussians, parts, truth)
    k = len(truth)
    frames = np.stack([frame_of(gaussians, parts, np.tile(np.eye(4), (k, 1, 1)))[0], frame])
    masks = np.stack([np.ones((H, W), bool), mask])
    poses = np.stack([np.tile(np.eye(4), (k, 1, 1)), start], axis=1)  # (K, 2, 4, 4)
    return align_poses(gaussians, parts, frames, masks, K, poses, options=AlignOptions(max_side=W), **kw)


def test_a_perturbed_pose_comes_back():
    g, parts = textured_object()
    truth = turn([0.3, 1, 0.2], 25)[None]
    start = turn([1, -0.5, 0.3], 3, shift=(0.04, -0.03, 0.05)) @ truth
    assert errors(start[0], truth[0])[0] > 2.9
    result = align_one(g, parts, truth, start)
    rot, trans = errors(result.poses[0, 1], truth[0])
    assert rot < 0.05 and trans < 0.005
    assert result.loss_after[1] < 0.2 * result.loss_before[1]
    assert result.frames == [1] and np.array_equal(result.poses[:, 0], np.eye(4)[None])


@pytest.mark.xfail(strict=True, reason="known: from 2° / 5° off, the two-part box's body settles 0.22° and its thin "
                   "lid 0.72° off the true poses (session note of 2026-12-01)")
def test_each_part_of_two_comes_back():
    g, parts = textured_object(two_parts=True)
    truth = np.stack([turn([0, 1, 0], 10), turn([1, 0, 0], -20, about=(0.0, -0.35, 4.4))])
    start = np.stack([turn([0, 0, 1], 2) @ truth[0], turn([1, 0.2, 0], 5, shift=(0.0, 0.03, 0.0)) @ truth[1]])
    result = align_one(g, parts, truth, start)
    for k in range(2):
        assert errors(result.poses[k, 1], truth[k])[0] < 0.05


def test_a_part_held_fixed_keeps_its_pose_and_the_other_still_moves():
    g, parts = textured_object(two_parts=True)
    truth = np.stack([turn([0, 1, 0], 10), turn([1, 0, 0], -20, about=(0.0, -0.35, 4.4))])
    start = np.stack([truth[0], turn([1, 0.2, 0], 5, shift=(0.0, 0.03, 0.0)) @ truth[1]])
    held = align_one(g, parts, truth, start, movable=np.array([False, True]))
    np.testing.assert_array_equal(held.poses[0, 1], start[0])
    assert errors(held.poses[1, 1], truth[1])[0] < 0.25 * errors(start[1], truth[1])[0]


def test_a_half_visible_object_still_aligns():
    g, parts = textured_object()
    truth = turn([0, 1, 0.3], 15, shift=(2.4, 0.0, 0.0))
    frame, mask = frame_of(g, parts, truth[None])
    assert mask[:, -1].any() and 0.2 < mask.sum() / frame_of(g, parts, turn([0, 1, 0.3], 15)[None])[1].sum() < 0.7
    start = turn([0.2, 1, 0], 3, shift=(-0.05, 0.03, 0.0)) @ truth
    result = align_one(g, parts, truth[None], start[None], frame, mask)
    assert errors(result.poses[0, 1], truth)[0] < 0.1


def test_an_occluder_does_not_drag_the_pose():
    g, parts = textured_object()
    truth = turn([0.3, 1, 0.2], 25)
    frame, mask = frame_of(g, parts, truth[None])
    ys, xs = np.nonzero(mask)
    x0, y0 = int(np.percentile(xs, 60)), int(np.percentile(ys, 40))
    frame[y0:, x0:] = (90, 60, 50)  # a hand over a corner; the segmentation leaves it out
    mask[y0:, x0:] = False
    assert mask.sum() > 0.7 * (frame_of(g, parts, truth[None])[1]).sum()
    start = turn([1, 0.4, 0], 3, shift=(0.03, 0.0, 0.0)) @ truth
    result = align_one(g, parts, truth[None], start[None], frame, mask)
    # A quarter of the box's bounding box hidden: measured 0.44° (23° with the colour term off the mask and a
    # squared silhouette on the finest level).
    assert errors(result.poses[0, 1], truth)[0] < 1.0


def test_a_shaded_model_aligns_to_a_frame_lit_as_it_turned():
    """A fit with shading: the frame shows the faces lit as they face the light after the turn."""
    g, parts = textured_object()
    rel = (g.means - np.array([0.0, 0.2, 5.0])) / np.array([0.9, 0.5, 0.6])
    face = np.argmax(np.abs(rel), axis=1)
    normals = np.zeros((len(rel), 3))
    normals[np.arange(len(rel)), face] = np.sign(rel[np.arange(len(rel)), face])
    shading = Shading(g.sh, normals, Lighting(unit_rows(np.array([0.6, -0.5, -0.6])), 0.7))
    truth = turn([0.3, 1, 0.2], 25)[None]
    frame, mask = frame_of(shading.lit(g, parts, truth[:, :3, :3]), parts, truth)
    start = turn([1, -0.5, 0.3], 3, shift=(0.04, -0.03, 0.05)) @ truth
    shaded = align_one(g, parts, truth, start, frame, mask, shading=shading)
    unshaded = align_one(g, parts, truth, start, frame, mask)
    error = errors(shaded.poses[0, 1], truth[0])[0]
    assert error < 0.05  # measured 0.015° (0.16° with the colours at rest)
    assert errors(unshaded.poses[0, 1], truth[0])[0] > 3 * error
    assert shaded.loss_after[1] < 0.5 * unshaded.loss_after[1]


def test_already_aligned_poses_stay():
    g, parts = textured_object()
    truth = turn([0.3, 1, 0.2], 25)[None]
    result = align_one(g, parts, truth, truth)
    assert errors(result.poses[0, 1], truth[0])[0] < 0.05
    assert result.loss_after[1] <= result.loss_before[1]


def test_twist_gradient_is_the_chain_rule_of_move_parts():
    """twist_gradient maps a left-perturbation gradient to the twists' one: checked on a smooth function of the
    moved points, L = Σ wᵢ·μᵢ', whose left gradient about a pivot c is [Σ (μᵢ' - c) × wᵢ, Σ wᵢ], against central
    differences in float64 (the rasterizer's own pose gradient is checked in test_rasterizer_grad)."""
    rng = np.random.default_rng(3)
    poses = np.stack([turn([0, 1, 0], 10), turn([1, 0.3, 0], -35, about=(0.0, -0.35, 4.4))])
    points = [rng.normal(size=(20, 3)) + [0, 0, 5], rng.normal(size=(15, 3)) + [0, -0.4, 5]]
    weights = [rng.normal(size=(20, 3)), rng.normal(size=(15, 3))]
    centres, radius = np.array([[0.0, 0.2, 5.0], [0.0, -0.4, 5.0]]), 1.7
    x = np.array([[0.2, -0.3, 0.1, 0.2, 0.1, -0.2], [0.5, 0.2, -0.4, -0.1, 0.3, 0.2]])

    def moved(x):
        m = move_parts(poses, x, centres, radius)
        return [p @ m[k, :3, :3].T + m[k, :3, 3] for k, p in enumerate(points)]

    def loss(x):
        return sum(float((w * mu).sum()) for w, mu in zip(weights, moved(x)))

    pivots = centres + x[:, 3:] * radius
    left = np.array([np.r_[np.cross(mu - c, w).sum(axis=0), w.sum(axis=0)]
                     for mu, w, c in zip(moved(x), weights, pivots)])
    fd = np.zeros_like(x)
    for k in range(2):
        for i in range(6):
            step = np.zeros_like(x)
            step[k, i] = 1e-6
            fd[k, i] = (loss(x + step) - loss(x - step)) / 2e-6
    np.testing.assert_allclose(twist_gradient(left, x, radius), fd, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(move_parts(poses, np.zeros((2, 6)), centres, radius), poses)


#: The two-part box's lid hinged on the body's back top edge (body frame-0 coordinates).
LID_HINGE = Hinge(1, 0, np.array([1.0, 0.0, 0.0]), np.array([0.0, -0.34, 5.6]))


def on_hinge(body: np.ndarray, lid: np.ndarray, hinge: Hinge) -> bool:
    """Whether the lid's pose (4, 4) is its body's (4, 4) turned about the hinge's axis."""
    relative = invert_transform(body) @ lid
    rotvec = Rotation.from_matrix(relative[:3, :3]).as_rotvec()
    return (np.linalg.norm(np.cross(rotvec, hinge.axis)) < 1e-9
            and np.allclose(relative[:3, :3] @ hinge.point + relative[:3, 3], hinge.point, atol=1e-9))


def test_joint_gradient_is_the_chain_rule_of_move_joints():
    """As above, with part 1 hinged on part 0: it moves with the body and turns by x[1, 0] about the axis."""
    rng = np.random.default_rng(5)
    hinge = LID_HINGE
    body = turn([0, 1, 0], 10)
    poses = np.stack([body, body @ turn(hinge.axis, -20, about=hinge.point)])
    points = [rng.normal(size=(20, 3)) + [0, 0, 5], rng.normal(size=(15, 3)) + [0, -0.4, 5]]
    weights = [rng.normal(size=(20, 3)), rng.normal(size=(15, 3))]
    centres, radius = np.array([[0.0, 0.2, 5.0], [0.0, -0.4, 5.0]]), 1.7
    x = np.array([[0.2, -0.3, 0.1, 0.2, 0.1, -0.2], [0.4, 0, 0, 0, 0, 0]])

    def moved(x):
        m = move_joints(poses, x, centres, radius, [hinge])[0]
        return [p @ m[k, :3, :3].T + m[k, :3, 3] for k, p in enumerate(points)]

    def loss(x):
        return sum(float((w * mu).sum()) for w, mu in zip(weights, moved(x)))

    poses_x, pivots = move_joints(poses, x, centres, radius, [hinge])
    assert on_hinge(poses_x[0], poses_x[1], hinge)
    left = np.array([np.r_[np.cross(mu - c, w).sum(axis=0), w.sum(axis=0)]
                     for mu, w, c in zip(moved(x), weights, pivots)])
    fd = np.zeros_like(x)
    for k, i in [(0, i) for i in range(6)] + [(1, 0)]:
        step = np.zeros_like(x)
        step[k, i] = 1e-6
        fd[k, i] = (loss(x + step) - loss(x - step)) / 2e-6
    np.testing.assert_allclose(joint_gradient(left, x, radius, poses_x, pivots, [hinge]), fd, rtol=1e-6, atol=1e-6)


def test_a_hinged_lid_comes_back_on_its_hinge():
    """The two-part box of the xfail above with its lid on a hinge: from the body 2° and the lid 5° off about the
    hinge, both come back, and the lid stays on its hinge."""
    g, parts = textured_object(two_parts=True)
    body = turn([0, 1, 0], 10)
    truth = np.stack([body, body @ turn(LID_HINGE.axis, -20, about=LID_HINGE.point)])
    start_body = turn([0, 0, 1], 2) @ body
    start = np.stack([start_body, start_body @ turn(LID_HINGE.axis, -15, about=LID_HINGE.point)])
    result = align_one(g, parts, truth, start, hinges=[LID_HINGE])
    # Measured 0.04° / 0.06° (free: 0.19° / 0.10°, the lid off its hinge); the loss's own minimum is a few
    # hundredths of a degree off the truth (a binary mask against soft edges, 8-bit colours).
    assert errors(result.poses[0, 1], truth[0])[0] < 0.1
    assert errors(result.poses[1, 1], truth[1])[0] < 0.1
    assert on_hinge(result.poses[0, 1], result.poses[1, 1], LID_HINGE)


def test_hinges_are_read_from_the_metadata_checked_and_snapped_onto():
    joints = {"1": {"model": "hinge", "on_part": 0, "axis": [2.0, 0.0, 0.0], "point": [0.0, -0.34, 5.6]},
              "2": {"model": "free", "reason": "it barely turns"}}
    hinges = check_hinges(hinges_from_metadata(joints), 3)
    assert len(hinges) == 1 and hinges[0].part == 1 and hinges[0].body == 0
    np.testing.assert_allclose(hinges[0].axis, [1, 0, 0])
    for bad in ([Hinge(1, 1, np.ones(3), np.zeros(3))], [Hinge(1, 0, np.ones(3), np.zeros(3)),
                                                         Hinge(2, 1, np.ones(3), np.zeros(3))],
                [Hinge(3, 0, np.ones(3), np.zeros(3))], [Hinge(1, 0, np.zeros(3), np.zeros(3))],
                [Hinge(1, 0, np.ones(3), np.zeros(3)), Hinge(1, 2, np.ones(3), np.zeros(3))]):
        with pytest.raises(InputError):
            check_hinges(bad, 3)
    # A lid pose nudged off its axis (as smoothing leaves it) is put back on it, with the turn about the axis kept.
    body = turn([0, 1, 0], 10)
    lid = body @ turn([1, 0.05, 0], -20, about=(0.0, -0.34, 5.62))
    snapped = snap_to_hinges(np.stack([body, lid])[:, None], hinges)[:, 0]
    np.testing.assert_array_equal(snapped[0], body)
    assert on_hinge(snapped[0], snapped[1], hinges[0]) and errors(snapped[1], lid)[0] < 20 * 0.05  # turn x tilt
    assert abs(errors(snapped[1], body)[0] - 20.0) < 0.05


def test_bad_inputs_raise():
    g, parts = textured_object()
    frames = np.zeros((2, H, W, 3), np.uint8)
    masks = np.ones((2, H, W), bool)
    with pytest.raises(InputError):
        align_poses(g, parts, frames, masks, K, np.tile(np.eye(4), (1, 3, 1, 1))[..., :3, :])
    with pytest.raises(InputError):
        align_poses(g, parts + 1, frames, masks, K, np.tile(np.eye(4), (1, 2, 1, 1)))
    with pytest.raises(InputError):
        align_poses(g, parts, frames, masks, K, np.tile(np.eye(4), (1, 2, 1, 1)), options=AlignOptions(levels=0))


def test_line_searches_stay_within_the_evaluation_budget(monkeypatch):
    """Where the loss is rough (a model that barely overlaps the frame) its gradient misleads the line
    searches, which then take up to 20 evaluations per iteration; each stage of the coarse-to-fine alignment
    still renders at most 3 × iterations times. A random gradient stands in for the misleading one."""
    import marionette.reconstruct.align as align

    g, parts = textured_object()
    rng = np.random.default_rng(4)
    calls = []

    def misleading(*args, **kwargs):
        calls.append(1)
        loss, grad = twist_loss(*args, **kwargs)
        return loss, rng.normal(size=grad.shape)

    monkeypatch.setattr(align, "twist_loss", misleading)
    options = AlignOptions(max_side=W, iterations=4)
    truth = turn([0.3, 1, 0.2], 25)[None]
    start = turn([1, -0.5, 0.3], 3) @ truth
    frame, mask = frame_of(g, parts, truth)
    frames = np.stack([frame_of(g, parts, np.eye(4)[None])[0], frame])
    poses = np.stack([np.eye(4)[None], start], axis=1)
    align_poses(g, parts, frames, np.stack([np.ones((H, W), bool), mask]), K, poses, options=options)
    stages = options.levels + np.isfinite(options.silhouette_scale)
    assert 0 < len(calls) <= stages * 3 * options.iterations
