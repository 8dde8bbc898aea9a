import numpy as np
import pytest

from marionette.errors import InputError
from marionette.geometry import axis_angle_to_matrix, make_transform
from marionette.io.prior import read_prior, write_prior
from marionette.prior import SpatPrior


def turning_prior(t=6, parts=2):
    poses = np.stack([
        np.stack([make_transform(axis_angle_to_matrix([0, 0.2 * i * (k + 1), 0]), [0.1 * i, 0, 0]) for i in range(t)])
        for k in range(parts)
    ])
    cents = np.zeros((parts, t, 3))
    cents[..., 2] = 4.0
    return SpatPrior.from_poses(poses, cents, np.ones(parts), fps=25.0, image_size=(64, 48),
                                intrinsics=np.eye(3), extras={"labels": np.zeros((48, 64), np.int16)},
                                metadata={"method": "test"})


def test_steps_compose_to_poses():
    p = turning_prior()
    acc = np.tile(np.eye(4), (p.num_parts, 1, 1))
    for t in range(p.num_frames - 1):
        acc = make_transform(p.rotations[:, t], p.translations[:, t]) @ acc
    assert np.allclose(acc, p.poses[:, -1])


def test_round_trip(tmp_path):
    p = turning_prior()
    write_prior(tmp_path / "p.npz", p)
    q = read_prior(tmp_path / "p.npz")
    for key in ("poses", "rotations", "translations", "centroids", "radii", "intrinsics", "image_size"):
        assert np.array_equal(getattr(p, key), getattr(q, key)), key
    assert q.fps == 25.0 and q.metadata == {"method": "test"}
    assert q.extras["labels"].shape == (48, 64)


def rewrite(tmp_path, **changes):
    p = turning_prior()
    write_prior(tmp_path / "p.npz", p)
    with np.load(tmp_path / "p.npz") as d:
        data = dict(d)
    data.update(changes)
    for k, v in list(data.items()):
        if v is None:
            del data[k]
    np.savez(tmp_path / "bad.npz", **data)
    return tmp_path / "bad.npz"


@pytest.mark.parametrize("changes, words", [
    ({"format": np.array("other")}, "'format'"),
    ({"version": np.array(2)}, "'version' is 2"),
    ({"radii": None}, "lacks key 'radii'"),
    ({"rotations": np.zeros((2, 3, 3, 3))}, "'rotations' must have shape"),
    ({"centroids": np.full((2, 6, 3), np.nan)}, "'centroids' contains NaN"),
    ({"fps": np.array(-1.0)}, "'fps'"),
])
def test_bad_prior_names_the_key(tmp_path, changes, words):
    with pytest.raises(InputError, match=words):
        read_prior(rewrite(tmp_path, **changes))


def test_pickled_objects_are_refused(tmp_path):
    path = rewrite(tmp_path, labels=np.array([{"a": 1}], dtype=object))
    with pytest.raises(InputError, match="pickle"):
        read_prior(path)


def test_not_a_zip(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"hello")
    with pytest.raises(InputError, match="not a readable"):
        read_prior(tmp_path / "x.npz")


def test_in_view_conjugates_the_motion():
    p = turning_prior()
    turn = axis_angle_to_matrix([0.1, -0.3, 0.05])
    q = p.in_view(turn)
    pts = np.random.default_rng(0).normal(size=(10, 3))
    for t in range(p.num_frames):
        moved = pts @ p.poses[0, t, :3, :3].T + p.poses[0, t, :3, 3]
        seen = (pts @ turn.T) @ q.poses[0, t, :3, :3].T + q.poses[0, t, :3, 3]
        assert np.allclose(seen, moved @ turn.T)
    assert np.allclose(q.centroids, p.centroids @ turn.T)


def test_aimed_at_object_puts_the_first_centroid_on_the_axis():
    p = turning_prior()
    cents = p.centroids.copy()
    cents[:, :, 0] = 3.0  # off to the right
    off_axis = SpatPrior.from_poses(p.poses, cents, p.radii, fps=p.fps, image_size=(64, 48), intrinsics=np.eye(3))
    aimed = off_axis.aimed_at_object()
    c0 = aimed.centroids[:, 0].mean(axis=0)
    assert np.allclose(c0[:2], 0, atol=1e-9) and c0[2] == pytest.approx(5.0)
    # A pure turn: relative motion (angles, distances) is unchanged.
    assert np.allclose(np.linalg.norm(aimed.translations, axis=-1), np.linalg.norm(off_axis.translations, axis=-1))


def test_motion_in_puts_the_removed_camera_back_or_leaves_it_out(tmp_path):
    from dataclasses import replace

    from marionette.prior import CAMERA_EXTRA

    p = turning_prior()
    cameras = np.stack([make_transform(axis_angle_to_matrix([0, -0.15 * i, 0.02 * i]), [0.3 * i, 0, -0.1 * i])
                        for i in range(p.num_frames)])
    with_camera = replace(p, extras={**p.extras, CAMERA_EXTRA: cameras})
    write_prior(tmp_path / "p.npz", with_camera)
    loaded = read_prior(tmp_path / "p.npz")
    filmed, world = loaded.motion_in("filmed"), loaded.motion_in("world")
    pts = np.random.default_rng(1).normal(size=(10, 3))
    for t in range(p.num_frames):  # a frame-0 point where camera t sees it
        seen = (pts @ p.poses[1, t, :3, :3].T + p.poses[1, t, :3, 3]) @ cameras[t, :3, :3].T + cameras[t, :3, 3]
        assert np.allclose(pts @ filmed.poses[1, t, :3, :3].T + filmed.poses[1, t, :3, 3], seen)
        assert np.allclose(filmed.centroids[:, t], p.centroids[:, t] @ cameras[t, :3, :3].T + cameras[t, :3, 3])
    np.testing.assert_array_equal(world.poses, p.poses)
    assert CAMERA_EXTRA not in filmed.extras and CAMERA_EXTRA not in world.extras and "labels" in filmed.extras
    assert p.motion_in("filmed") is p  # a still camera: nothing to put back
    with pytest.raises(InputError, match="motion must be one of"):
        p.motion_in("camera")
    with pytest.raises(InputError, match=CAMERA_EXTRA):
        replace(p, extras={CAMERA_EXTRA: cameras[:3]}).motion_in("filmed")
