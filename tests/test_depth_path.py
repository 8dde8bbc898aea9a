"""The depth-map path: reading depth folders, and poses from tracks lifted with depth (paper Eq. 1, 3-4)."""

import cv2
import numpy as np
import pytest

from marionette.errors import InputError
from marionette.geometry import rotation_angle_deg
from marionette.source.depth import _sample_depth, poses_from_depth, read_depths
from marionette.source.tracks import track
from marionette.synthetic import make_scene

SIZE = (240, 180)


@pytest.fixture(scope="module")
def cases():
    out = {}
    for motion in ("outofplane", "oscillation"):
        sc = make_scene(motion, num_frames=32, size=SIZE, seed=0)
        out[motion] = sc, track(sc.frames, sc.masks)
    return out


def _errors(poses, sc):
    """Rotation error (T,) in degrees and centroid error (T,) as a fraction of the object's size."""
    gt = sc.poses[0]
    rot = rotation_angle_deg(poses[:, :3, :3] @ np.swapaxes(gt[:, :3, :3], 1, 2))
    c0 = sc.part_points[0].mean(axis=0)
    gap = (poses[:, :3, :3] - gt[:, :3, :3]) @ c0 + poses[:, :3, 3] - gt[:, :3, 3]
    return rot, np.linalg.norm(gap, axis=1) / sc.radii()[0]


@pytest.mark.parametrize("motion", ["outofplane", "oscillation"])
def test_poses_from_exact_depth(cases, motion):
    sc, tracks = cases[motion]
    poses = poses_from_depth(tracks, sc.depths, sc.camera.K)
    assert poses.shape == (32, 4, 4)
    np.testing.assert_allclose(poses[0], np.eye(4))
    rot, centre = _errors(poses, sc)
    assert np.median(rot[1:]) <= 0.5
    assert rot.max() < 1.5
    assert np.median(centre[1:]) < 0.01


def test_robust_to_bad_depth(cases):
    """Wrong depth on a fifth of the pixels and on a blob in half the frames changes little."""
    sc, tracks = cases["oscillation"]
    rng = np.random.default_rng(0)
    depths = sc.depths.copy()
    bad = rng.random(depths.shape) < 0.2
    depths[bad] *= rng.uniform(0.3, 3.0, bad.sum()).astype(np.float32)
    v, u = np.argwhere(sc.masks[0]).mean(axis=0).astype(int)
    depths[::2, v - 8:v + 8, u - 8:u + 8] *= 0.8  # something in front of the object
    rot, centre = _errors(poses_from_depth(tracks, depths, sc.camera.K), sc)
    assert np.median(rot[1:]) <= 0.5
    assert np.median(centre[1:]) < 0.01


def test_sample_depth_is_exact_on_planes():
    """Inverse depth is linear in the image over a plane: interpolating it is exact, and depth edges give NaN."""
    k = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(64.0), np.arange(48.0))
    normal, offset = np.array([0.3, -0.2, 1.0]), 5.0  # the plane normal . X = offset

    def plane(u, v):
        return offset / (normal @ np.linalg.inv(k) @ np.stack([u, v, np.ones_like(u)]))

    depth = plane(u.ravel(), v.ravel()).reshape(48, 64)
    uv = np.random.default_rng(1).uniform([0, 0], [62.9, 46.9], (200, 2))
    np.testing.assert_allclose(_sample_depth(depth, uv, 0.05), plane(uv[:, 0], uv[:, 1]), rtol=1e-9)
    stepped = depth.copy()
    stepped[:, 32:] *= 1.5
    samples = _sample_depth(stepped, np.array([[31.5, 20.0], [20.0, 20.0], [-0.5, 3.0]]), 0.05)
    assert np.isnan(samples[0]) and np.isfinite(samples[1]) and np.isnan(samples[2])
    assert np.isnan(_sample_depth(np.where(u < 10, np.inf, depth), np.array([[9.5, 5.0]]), 0.05)[0])


def _write_png(path, depth_mm):
    cv2.imwrite(str(path), depth_mm.astype(np.uint16))


def test_read_depths_formats(tmp_path):
    rng = np.random.default_rng(2)
    maps = rng.uniform(0.5, 6.0, (3, 12, 16)).astype(np.float32)
    pngs = tmp_path / "png"
    pngs.mkdir()
    for t, m in enumerate(maps):
        mm = np.rint(m * 1000)
        mm[0, 0] = 0  # unknown
        _write_png(pngs / f"{t + 1}.png", mm)
    out = read_depths(pngs, count=3, size=(16, 12))
    assert out.shape == (3, 12, 16) and out.dtype == np.float32
    assert np.isnan(out[:, 0, 0]).all()
    np.testing.assert_allclose(out[:, 1:], maps[:, 1:], atol=6e-4)

    arrays = tmp_path / "npy"
    arrays.mkdir()
    np.save(arrays / "f10.npy", maps[2])  # natural order: f2 < f10
    np.save(arrays / "f2.npy", maps[1])
    np.savez(arrays / "f1.npz", depth=maps[0], other=np.zeros(3))
    np.testing.assert_array_equal(read_depths(arrays, count=3, size=(16, 12)), maps)
    # A frame range picks its maps from a full folder; maps of the original size are resized.
    np.testing.assert_array_equal(read_depths(arrays, count=2, size=(16, 12), indices=[0, 2]), maps[[0, 2]])
    half = read_depths(arrays, count=3, size=(8, 6))
    np.testing.assert_array_equal(half[0], cv2.resize(maps[0], (8, 6), interpolation=cv2.INTER_NEAREST))


@pytest.mark.parametrize("problem", ["missing", "file", "count", "size", "corrupt", "8bit", "inf", "empty",
                                     "npz-keys", "3d"])
def test_read_depths_errors(tmp_path, problem):
    folder = tmp_path / "depth"
    folder.mkdir()
    for t in range(2):
        np.save(folder / f"{t}.npy", np.ones((12, 16), np.float32))
    if problem == "missing":
        folder = tmp_path / "nowhere"
    elif problem == "file":
        folder = folder / "0.npy"
    elif problem == "count":
        np.save(folder / "2.npy", np.ones((12, 16), np.float32))
    elif problem == "size":
        np.save(folder / "1.npy", np.ones((12, 15), np.float32))
    elif problem == "corrupt":
        (folder / "1.npy").write_bytes(b"not a numpy file")
    elif problem == "8bit":
        (folder / "1.npy").unlink()
        cv2.imwrite(str(folder / "1.png"), np.full((12, 16), 7, np.uint8))
    elif problem == "inf":
        np.save(folder / "1.npy", np.full((12, 16), np.inf, np.float32))
    elif problem == "empty":
        np.save(folder / "1.npy", np.zeros((12, 16), np.float32))
    elif problem == "npz-keys":
        (folder / "1.npy").unlink()
        np.savez(folder / "1.npz", a=np.ones((12, 16)), b=np.ones((12, 16)))
    elif problem == "3d":
        np.save(folder / "1.npy", np.ones((12, 16, 3), np.float32))
    with pytest.raises(InputError):
        read_depths(folder, count=2, size=(16, 12))


def test_poses_from_depth_bad_inputs(cases):
    sc, tracks = cases["oscillation"]
    with pytest.raises(InputError):
        poses_from_depth(tracks, sc.depths[:5], sc.camera.K)
    with pytest.raises(InputError):
        poses_from_depth(tracks, sc.depths, np.zeros((3, 3)))
