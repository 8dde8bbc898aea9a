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
