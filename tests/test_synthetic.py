"""Synthetic scenes: shapes, exact ground truth against the rendered masks, determinism."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial import ConvexHull, Delaunay

from marionette.errors import InputError
from marionette.geometry import invert_transform, rotation_angle_deg, transform_points
from marionette.synthetic import MOTIONS, OBJECTS, TARGET_OBJECTS, make_scene, object_view, render_object_image
from marionette.synthetic._objects import POINT_SPACING
from marionette.synthetic._render import SUPERSAMPLE, render_shape

SIZE = (320, 240)
FRAMES = 6


def _cases():
    needs = {"hinge": ("hinge", "door", "screen"), "slide": ("drawer",)}  # the joint motions need jointed objects
    for motion in MOTIONS:
        for obj in OBJECTS:
            if obj in needs.get(motion, (obj,)):
                yield motion, obj


@pytest.fixture(scope="module")
def scenes():
    """One short scene per (motion, object), built once for the module."""
    return {case: make_scene(case[0], object=case[1], num_frames=FRAMES, size=SIZE, seed=3) for case in _cases()}


def _hull_mask(scene, t: int) -> np.ndarray:
    """(H, W) bool: pixels whose centre lies in the convex hull of some part's projected points at frame t."""
    h, w = scene.camera.height, scene.camera.width
    centres = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1).reshape(-1, 2)
    out = np.zeros(h * w, bool)
    for k, pts in enumerate(scene.part_points):
        uv, _ = scene.camera.project(transform_points(scene.poses[k, t], pts))
        out |= Delaunay(uv[ConvexHull(uv).vertices]).find_simplex(centres) >= 0
    return out.reshape(h, w)


@pytest.mark.parametrize("case", list(_cases()))
def test_shapes_and_dtypes(scenes, case):
    sc = scenes[case]
    w, h = SIZE
    p = 2 if sc.object in ("hinge", "door", "drawer", "screen") else 1
    assert (sc.motion, sc.object) == case
    assert sc.frames.shape == (FRAMES, h, w, 3) and sc.frames.dtype == np.uint8
    assert sc.masks.shape == (FRAMES, h, w) and sc.masks.dtype == bool
    assert sc.part_masks.shape == (FRAMES, h, w) and sc.part_masks.dtype == np.int8
    assert sc.poses.shape == (p, FRAMES, 4, 4) and sc.poses.dtype == np.float64
    assert len(sc.part_points) == p and all(q.ndim == 2 and q.shape[1] == 3 for q in sc.part_points)
    assert (sc.camera.width, sc.camera.height) == SIZE
    np.testing.assert_allclose(sc.camera.K[0, 0], w / 2 / np.tan(np.radians(30)))
    np.testing.assert_array_equal(sc.camera.world_to_camera, np.eye(4))
    assert sc.centroids().shape == (p, FRAMES, 3) and sc.radii().shape == (p,)
    # part_masks agrees with masks, and part 0 (the body) is the largest part but for a screen's stand.
    np.testing.assert_array_equal(sc.part_masks >= 0, sc.masks)
    assert set(np.unique(sc.part_masks)) <= set(range(-1, p))
    assert np.argmax([len(q) for q in sc.part_points]) == (1 if sc.object == "screen" else 0)


@pytest.mark.parametrize("case", list(_cases()))
def test_poses_start_at_identity_and_are_rigid(scenes, case):
    poses = scenes[case].poses
    np.testing.assert_array_equal(poses[:, 0], np.broadcast_to(np.eye(4), poses[:, 0].shape))
    r = poses[..., :3, :3]
    np.testing.assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)
    np.testing.assert_array_equal(poses[..., 3, :], np.broadcast_to([0, 0, 0, 1.0], poses[..., 3, :].shape))


@pytest.mark.parametrize("case", [case for case in _cases() if case[1] != "screen"])  # a stand is no convex part
def test_mask_matches_projected_ground_truth(scenes, case):
    """Each part is convex, so its silhouette is the hull of its projected surface points (box corners included).

    IoU > 0.995: the mask is a 3x3-sample majority vote, so it can differ from
    the pixel-centre test only where an edge passes within ~1/3 px of a
    centre; measured IoUs are above 0.999 on objects of ~10^4 px.
    """
    sc = scenes[case]
    for t in range(FRAMES):
        hull = _hull_mask(sc, t)
        iou = (hull & sc.masks[t]).sum() / (hull | sc.masks[t]).sum()
        assert iou > 0.995, f"frame {t}: IoU {iou:.4f}"


@pytest.mark.parametrize("motion", MOTIONS)
@pytest.mark.parametrize("seed", [0, 1])
def test_object_visible_and_inside_image(motion, seed):
    sc = make_scene(motion, num_frames=8, size=SIZE, seed=seed)
    area = sc.masks.mean(axis=(1, 2))
    assert np.all(area > 0.05), area
    edges = np.concatenate([sc.masks[:, 0], sc.masks[:, -1], sc.masks[:, :, 0], sc.masks[:, :, -1]], axis=1)
    assert not edges.any()
    # The object covers roughly 30-50 % of the width at frame 0.
    cols = np.nonzero(sc.masks[0].any(axis=0))[0]
    assert 0.25 < (cols[-1] - cols[0] + 1) / SIZE[0] < 0.6
    # Ground truth: 3-5 units in front of the camera.
    assert np.all((sc.centroids()[..., 2] > 3) & (sc.centroids()[..., 2] < 5))


def _near_object(masks: np.ndarray) -> np.ndarray:
    """(T, H, W) bool: masks grown by one pixel, to cover the anti-aliased edge pixels the masks leave out."""
    return np.stack([cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)) for m in masks]) > 0


def _axis_angle_deg(mask: np.ndarray) -> float:
    m = cv2.moments(mask.astype(np.uint8), binaryImage=True)
    return np.degrees(0.5 * np.arctan2(2 * m["mu11"], m["mu20"] - m["mu02"]))


def test_inplane_rotates_mask_principal_axis():
    """About the optical axis, the image turns rigidly: the mask's axis turns by the pose's angle (mod 180°)."""
    sc = make_scene("inplane", num_frames=9, size=SIZE, seed=5)
    r = sc.poses[0, :, :3, :3]
    np.testing.assert_allclose(r[:, 2], np.broadcast_to([0, 0, 1.0], r[:, 2].shape), atol=1e-12)
    gt = np.degrees(np.arctan2(r[:, 1, 0], r[:, 0, 0]))  # y down: positive turns x towards y in the image too
    assert 75 <= abs(gt[-1]) <= 105
    a0 = _axis_angle_deg(sc.masks[0])
    for t in range(1, sc.num_frames):
        diff = (_axis_angle_deg(sc.masks[t]) - a0 - gt[t] + 90) % 180 - 90
        assert abs(diff) < 1.0, f"frame {t}: off by {diff:.2f} deg"


def test_motion_magnitudes():
    """Each motion has the kind and size of movement its name promises."""
    ang = {m: rotation_angle_deg(make_scene(m, num_frames=25, size=(64, 48), seed=2).poses[0, 1:, :3, :3])
           for m in MOTIONS}
    trans = make_scene("translation", num_frames=5, size=(64, 48), seed=2).poses[0]
    np.testing.assert_allclose(trans[:, :3, :3], np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-15)
    assert np.linalg.norm(trans[-1, :3, 3]) > 0.5
    assert 75 <= ang["inplane"][-1] <= 105
    assert 80 <= ang["outofplane"][-1] <= 100
    assert 15 <= ang["oscillation"].max() <= 30
    # Two periods or so: the swing passes back through the start pose at least twice.
    assert (ang["oscillation"] < 0.3 * ang["oscillation"].max()).sum() >= 2
    assert ang["hinge"][-1] <= 12  # the body is static or turns slowly


def test_hinge_lid_turns_about_hinge_line():
    sc = make_scene("hinge", num_frames=10, size=SIZE, seed=1)
    assert sc.object == "hinge" and sc.num_parts == 2
    # Both parts are visible, the body larger, once the lid is open.
    counts = [(sc.part_masks[-1] == k).sum() for k in range(2)]
    assert counts[0] > counts[1] > 500
    assert (sc.part_masks[0] == 1).sum() > 200
    body, lid = sc.part_points
    rel = invert_transform(sc.poses[0]) @ sc.poses[1]  # lid relative to body
    assert 60 <= rotation_angle_deg(rel[-1, :3, :3]) <= 80
    # The lid points that stay put relative to the body form a line: the hinge.
    moved = np.max([np.linalg.norm(transform_points(m, lid) - lid, axis=1) for m in rel], axis=0)
    fixed = lid[moved < 1e-9]
    assert len(fixed) >= 10
    centred = fixed - fixed.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    assert sv[1] < 1e-9 * sv[0]
    direction = np.linalg.svd(centred)[2][0]
    axis = rel[-1, :3, :3] - rel[-1, :3, :3].T
    axis = np.array([axis[2, 1], axis[0, 2], axis[1, 0]])
    assert abs(direction @ axis / np.linalg.norm(axis)) > 1 - 1e-9
    # The hinge runs along an edge of the body: every hinge point lies on it.
    dist = np.min(np.linalg.norm(fixed[:, None] - body[None], axis=2), axis=1)
    assert dist.max() < POINT_SPACING
    # Other points of the lid do move.
    assert moved.max() > 0.5


def test_the_drawer_slides_out_of_its_cabinet_without_turning():
    sc = make_scene("slide", num_frames=10, size=SIZE, seed=2)
    assert sc.object == "drawer" and sc.num_parts == 2
    rel = invert_transform(sc.poses[0]) @ sc.poses[1]  # the drawer relative to the cabinet
    assert rotation_angle_deg(rel[:, :3, :3]).max() < 1e-9
    cabinet, drawer = sc.part_points
    depth = np.ptp(drawer @ rel[-1, :3, 3] / np.linalg.norm(rel[-1, :3, 3]))
    assert 0.45 * depth < np.linalg.norm(rel[-1, :3, 3]) < 0.85 * depth
    # Its front shows at first; pulled out, its top and sides show too.
    assert 300 < (sc.part_masks[0] == 1).sum() < (sc.part_masks[-1] == 1).sum() / 2
    with pytest.raises(InputError, match="drawer"):
        make_scene("slide", object="box", num_frames=4, size=(64, 48))


def test_the_door_swings_out_about_its_upright_edge_and_plain_faces_are_one_colour():
    textured = make_scene("hinge", object="door", num_frames=8, size=SIZE, seed=4)
    sc = make_scene("hinge", object="door", num_frames=8, size=SIZE, seed=4, plain=True)
    np.testing.assert_array_equal(sc.part_masks, textured.part_masks)  # the same object, only its paint differs
    rel = invert_transform(sc.poses[0]) @ sc.poses[1]
    rotvec = rel[-1, :3, :3] - rel[-1, :3, :3].T
    axis = np.array([rotvec[2, 1], rotvec[0, 2], rotvec[1, 0]])
    up = sc.poses[0][0, :3, :3] @ np.array([0.0, 1.0, 0.0])  # the cabinet is still or turns about its upright
    assert 60 <= rotation_angle_deg(rel[-1, :3, :3]) <= 80 and abs(axis @ up) / np.linalg.norm(axis) > 0.7
    door = cv2.erode((sc.part_masks[0] == 1).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # its face, no edge
    spread = [sc.frames[0][door].std(axis=0).max(), textured.frames[0][door].std(axis=0).max()]
    assert spread[0] < 8 < spread[1]  # shading alone (the door is flat) against its texture


def test_the_screen_swivels_on_its_post():
    """The screen turns 60-80° about an upright axis: along the panel's height, across its width and face."""
    sc = make_scene("hinge", object="screen", num_frames=8, size=SIZE, seed=5)
    rel = invert_transform(sc.poses[0]) @ sc.poses[1]
    rotvec = rel[-1, :3, :3] - rel[-1, :3, :3].T
    axis = np.array([rotvec[2, 1], rotvec[0, 2], rotvec[1, 0]])
    axis /= np.linalg.norm(axis)
    screen = sc.part_points[1]
    width, height, normal = np.linalg.svd(screen - screen.mean(axis=0), full_matrices=False)[2]
    assert 60 <= rotation_angle_deg(rel[-1, :3, :3]) <= 80 and abs(axis @ height) > 0.99
    assert 0 < (sc.part_masks[0] == 0).sum() < (sc.part_masks[0] == 1).sum()  # a small stand, a large screen


def test_hinge_object_with_other_motion_moves_as_one():
    sc = make_scene("oscillation", object="hinge", num_frames=5, size=(64, 48))
    np.testing.assert_array_equal(sc.poses[0], sc.poses[1])


def test_deterministic_and_seed_dependent():
    a = make_scene("outofplane", num_frames=4, size=(96, 72), seed=7)
    b = make_scene("outofplane", num_frames=4, size=(96, 72), seed=7)
    c = make_scene("outofplane", num_frames=4, size=(96, 72), seed=8)
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.masks, b.masks)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert np.abs(a.frames.astype(int) - c.frames).mean() > 5
    assert not np.allclose(a.poses, c.poses)


def test_plain_background_and_noise():
    clean = make_scene("translation", num_frames=3, size=(96, 72), background="plain")
    noisy = make_scene("translation", num_frames=3, size=(96, 72), background="plain", noise=4.0)
    np.testing.assert_array_equal(clean.masks, noisy.masks)
    np.testing.assert_array_equal(clean.poses, noisy.poses)
    assert np.ptp(clean.frames[~_near_object(clean.masks)], axis=0).max() == 0  # plain: one colour
    diff = noisy.frames.astype(float) - clean.frames
    assert abs(diff.std() - 4.0) < 0.2  # no clipping: the colours sit far from 0 and 255


def test_textured_background_is_static_and_low_contrast():
    sc = make_scene("translation", num_frames=4, size=(96, 72))
    near = _near_object(sc.masks)
    both = ~near[0] & ~near[-1]
    np.testing.assert_array_equal(sc.frames[0][both], sc.frames[-1][both])
    gray = sc.frames[0].astype(float).mean(axis=2)
    assert 2 < gray[~sc.masks[0]].std() < gray[sc.masks[0]].std()


def test_object_texture_is_trackable():
    """Lucas–Kanade corners: plenty of them on the object at frame 0."""
    sc = make_scene("translation", num_frames=2, size=SIZE, seed=0)
    gray = cv2.cvtColor(sc.frames[0], cv2.COLOR_RGB2GRAY)
    inner = cv2.erode(sc.masks[0].astype(np.uint8), np.ones((7, 7), np.uint8))
    corners = cv2.goodFeaturesToTrack(gray, 500, 0.01, 5, mask=inner)
    assert corners is not None and len(corners) > 80


def _lifted_and_moved(scene, start, seeds, t):
    """Camera points (M, 3) at frame t of the surface seen at ``seeds`` (frame ``start``), one point at a time."""
    k = scene.camera.K
    out = np.empty((len(seeds), 3))
    for m, (s, (u, v)) in enumerate(zip(start, np.rint(seeds).astype(int))):
        part = max(scene.part_masks[s, v, u], 0)
        seen = np.array([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], 1.0]) * scene.depths[s, v, u]
        to_t = scene.camera_poses[t] @ scene.poses[part, t] @ invert_transform(
            scene.camera_poses[s] @ scene.poses[part, s])
        out[m] = transform_points(to_t, seen[None])[0]
    return out


@pytest.mark.parametrize("motion,camera", [("hinge", "static"), ("outofplane", "pan")])
def test_track_truth_follows_the_rendered_surface(motion, camera):
    scene = make_scene(motion, num_frames=FRAMES, size=SIZE, seed=1, camera_motion=camera)
    rows, cols = np.nonzero(scene.masks[0][::9, ::9] & scene.masks[3][::9, ::9])
    seeds = np.concatenate([np.column_stack([cols, rows]) * 9] * 2).astype(float)
    start = np.repeat([0, 3], len(rows))
    positions, valid = scene.track_truth(start, seeds)
    assert positions.shape == (FRAMES, len(seeds), 2) and valid.all()
    np.testing.assert_allclose(positions[start, np.arange(len(seeds))], seeds, atol=1e-9)
    for t in range(FRAMES):
        cam = _lifted_and_moved(scene, start, seeds, t)
        uv, _ = scene.camera.project(cam)
        np.testing.assert_allclose(positions[t], uv, atol=1e-6)
        # Where a point lands, the render sees it (its own depth) unless something hides it (the lid closed over
        # the body's top seen at frame 3 hides a quarter of the hinge's points at frame 0): the truth follows the
        # surface, each part with its own motion, through each frame's camera.
        col, row = np.rint(positions[t]).astype(int).T
        inside = (col >= 0) & (col < SIZE[0]) & (row >= 0) & (row < SIZE[1])
        agree = np.abs(scene.depths[t, row[inside], col[inside]] - cam[inside, 2]) < 0.01 * cam[inside, 2]
        assert agree.mean() > 0.7, f"frame {t}: {agree.mean():.2f}"


def test_track_truth_marks_seeds_off_the_object():
    scene = make_scene("translation", num_frames=FRAMES, size=SIZE, seed=1)
    positions, valid = scene.track_truth(np.array([0]), np.array([[0.0, 0.0]]))
    assert not valid[0] and np.isnan(positions).all()


def test_ground_truth_prior():
    sc = make_scene("hinge", num_frames=4, size=(64, 48))
    prior = sc.ground_truth_prior()
    np.testing.assert_allclose(prior.poses, sc.poses, atol=1e-12)
    np.testing.assert_allclose(prior.centroids, sc.centroids())
    np.testing.assert_allclose(prior.radii, sc.radii())
    # The centroid is the mean of the moved points, the radius their RMS spread.
    moved = transform_points(sc.poses[1, -1], sc.part_points[1])
    np.testing.assert_allclose(sc.centroids()[1, -1], moved.mean(axis=0), atol=1e-12)
    r = np.sqrt(((moved - moved.mean(axis=0)) ** 2).sum(axis=1).mean())
    np.testing.assert_allclose(sc.radii()[1], r)


def test_kernel_matches_numpy_twin():
    """The numba kernel and the NumPy reference trace the same rays in float64."""
    from marionette.synthetic import _scene

    geom = _scene._rng(0, _scene._SCENE, _scene._GEOMETRY)
    local = _scene._BUILDERS["hinge"](geom, _scene._rng(0, _scene._SCENE, _scene._TEXTURE))
    camera = _scene.Camera.from_fov(48, 36)
    placement, poses = _scene.plan_motion("hinge", local, camera, 5, geom)
    shape = local.transformed(placement)
    for t in (0, 4):
        color, ids = render_shape(shape, poses[:, t], camera)
        _color, _ids = render_shape(shape, poses[:, t], camera, reference=True)
        assert ids.shape == (36 * SUPERSAMPLE, 48 * SUPERSAMPLE)
        # Rays within rounding error of an edge may land either way.
        assert (ids != _ids).mean() < 1e-3
        same = ids == _ids
        np.testing.assert_allclose(color[same], _color[same], atol=1e-5)


@pytest.mark.parametrize("obj", TARGET_OBJECTS)
def test_render_object_image(obj):
    img = render_object_image(obj, size=(128, 96), seed=1)
    assert img.shape == (96, 128, 4) and img.dtype == np.uint8
    alpha = img[..., 3]
    assert set(np.unique(alpha)) == {0, 255}
    assert (0.02 if obj == "rod" else 0.15) < (alpha == 255).mean() < 0.8  # the rod is a thin bar
    border = np.concatenate([alpha[0], alpha[-1], alpha[:, 0], alpha[:, -1]])
    assert not border.any()
    assert img[alpha == 255, :3].astype(float).std() > 10  # textured, not flat


def test_object_view_turns_the_object_about_the_vertical_through_its_centre():
    still = render_object_image("vase", size=(96, 96), seed=2, yaw_deg=10, pitch_deg=5)
    image, camera, centre = object_view("vase", size=(96, 96), seed=2, yaw_deg=10, pitch_deg=5)
    assert np.array_equal(image, still)
    assert np.allclose(camera.project(centre[None])[0], [[camera.cx, camera.cy]])
    full_turn = object_view("vase", size=(96, 96), seed=2, yaw_deg=10, pitch_deg=5, turn_deg=360)[0]
    assert np.abs(full_turn.astype(int) - image).max() <= 1
    # A vase turned about its own axis keeps its outline when the camera is level with it.
    level = object_view("vase", size=(96, 96), seed=2, yaw_deg=0, pitch_deg=0)[0][..., 3] > 0
    turned = object_view("vase", size=(96, 96), seed=2, yaw_deg=0, pitch_deg=0, turn_deg=70)[0][..., 3] > 0
    assert (level ^ turned).sum() < 0.03 * level.sum()
    with pytest.raises(InputError, match="fov_deg"):
        object_view("box", fov_deg=0.0)


def test_target_differs_from_source_object():
    target = render_object_image("box", size=SIZE, seed=0)
    source = make_scene("outofplane", num_frames=2, size=SIZE, seed=0)
    t_mean = target[target[..., 3] == 255, :3].mean(axis=0)
    s_mean = source.frames[0][source.masks[0]].mean(axis=0)
    assert np.abs(t_mean - s_mean).max() > 20


@pytest.mark.parametrize("kwargs", [
    {"motion": "spin"},
    {"motion": "translation", "object": "sphere"},
    {"motion": "hinge", "object": "box"},
    {"motion": "translation", "num_frames": 1},
    {"motion": "translation", "size": (8, 8)},
    {"motion": "translation", "size": (320,)},
    {"motion": "translation", "seed": -1},
    {"motion": "translation", "fps": 0.0},
    {"motion": "translation", "fps": "fast"},
    {"motion": "translation", "background": "checker"},
    {"motion": "translation", "noise": -1.0},
])
def test_bad_arguments(kwargs):
    motion = kwargs.pop("motion")
    with pytest.raises(InputError):
        make_scene(motion, **kwargs)


def test_render_object_image_bad_arguments():
    with pytest.raises(InputError):
        render_object_image("teapot")
    with pytest.raises(InputError):
        render_object_image("box", size=(0, 10))


def test_the_car_is_mirror_symmetric_about_its_long_mid_plane():
    # Mirroring the car across its mid-plane (z -> -z) and the image across its vertical (x -> -x) is a half
    # turn: the silhouette at yaw φ is the one at 180° - φ flipped left to right.
    for yaw, pitch in ((30, 0), (60, 20)):
        a = object_view("car", size=(128, 128), seed=3, yaw_deg=yaw, pitch_deg=pitch)[0][..., 3] > 0
        b = object_view("car", size=(128, 128), seed=3, yaw_deg=180 - yaw, pitch_deg=pitch)[0][..., 3] > 0
        assert (a ^ b[:, ::-1]).sum() < 0.01 * a.sum()
        assert (a ^ a[:, ::-1]).sum() > 0.1 * a.sum()  # not symmetric in the image itself
