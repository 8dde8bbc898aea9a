"""A result as glTF: one node per part, keyframes that reproduce the transfer's motion, read by glTF loaders."""

import numpy as np
import pygltflib
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from marionette.cli import main
from marionette.gaussians import Gaussians
from marionette.io import write_gltf_animation
from marionette.trajectory import Trajectory

T, N = 12, 60
FLIP = np.diag([1.0, -1.0, -1.0])  # our camera axes → glTF's


@pytest.fixture(scope="module")
def moving():
    """Two rigid parts: part 0 turns about a tilted axis through its centre and drifts; part 1 stays."""
    rng = np.random.default_rng(0)
    rest = rng.normal(size=(N, 3)) + [0.0, 0.0, 5.0]
    labels = (np.arange(N) >= 40).astype(np.int32)
    turns = Rotation.from_rotvec(np.linspace(0, 1.2, T)[:, None] * np.array([0.2, 1.0, 0.1])).as_matrix()
    rotations = np.tile(np.eye(3), (T, 2, 1, 1))
    rotations[:, 0] = turns
    centre = rest[labels == 0].mean(axis=0)
    means = np.repeat(rest[None], T, axis=0)
    drift = np.linspace(0, 1, T)[:, None] * [0.5, -0.2, 0.3]
    means[:, labels == 0] = np.einsum("tij,nj->tni", turns, rest[labels == 0] - centre) + centre + drift[:, None]
    gaussians = Gaussians(rest.astype(np.float32), np.tile([1, 0, 0, 0], (N, 1)).astype(np.float32),
                          np.full((N, 3), -3, np.float32), np.zeros(N, np.float32),
                          rng.normal(0, 0.5, (N, 1, 3)).astype(np.float32))
    return gaussians, Trajectory(means, rotations, labels)


def accessor(model: pygltflib.GLTF2, index: int) -> np.ndarray:
    """The float data of accessor ``index``, (count, components)."""
    acc = model.accessors[index]
    view = model.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc.type]
    data = np.frombuffer(model.binary_blob(), np.float32, acc.count * width, view.byteOffset or 0)
    return data.reshape(acc.count, width).astype(np.float64)


def test_each_part_is_a_node_whose_keyframes_move_it_as_the_transfer_did(moving, tmp_path):
    gaussians, trajectory = moving
    write_gltf_animation(tmp_path / "parts.glb", gaussians, trajectory, fps=24.0)
    model = pygltflib.GLTF2().load(str(tmp_path / "parts.glb"))
    assert [n.name for n in model.nodes] == ["part 0", "part 1"]
    (animation,) = model.animations
    assert len(animation.channels) == 4
    for node_index, node in enumerate(model.nodes):
        part = trajectory.labels == node_index
        points = accessor(model, model.meshes[node.mesh].primitives[0].attributes.POSITION)
        keys = {c.target.path: animation.samplers[c.sampler] for c in animation.channels
                if c.target.node == node_index}
        times = accessor(model, keys["rotation"].input)[:, 0]
        assert np.allclose(times, np.arange(T) / 24.0)
        turns = Rotation.from_quat(accessor(model, keys["rotation"].output)).as_matrix()  # x, y, z, w
        shifts = accessor(model, keys["translation"].output)
        for t in range(T):
            placed = points @ turns[t].T + shifts[t]
            assert np.abs(placed - trajectory.means[t, part] @ FLIP).max() < 1e-4


def test_common_loaders_read_the_parts_and_their_colours(moving, tmp_path):
    gaussians, trajectory = moving
    write_gltf_animation(tmp_path / "parts.glb", gaussians, trajectory, fps=24.0)
    scene = trimesh.load(tmp_path / "parts.glb")
    assert sorted(scene.geometry) == ["part 0", "part 1"]
    cloud = scene.geometry["part 1"]
    assert len(cloud.vertices) == (trajectory.labels == 1).sum()
    expected = np.clip(0.5 + 0.28209479177387814 * gaussians.sh[trajectory.labels == 1, 0], 0, 1)
    assert np.abs(cloud.colors[:, :3] / 255.0 - expected).max() < 1 / 255 + 1e-6


def test_the_command_line_writes_it_next_to_the_video(tmp_path, prior_file, target_png, capsys):
    out = tmp_path / "result.glb"
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(tmp_path / "r.mp4"), "--gltf", str(out),
                 "-q"]) == 0
    model = pygltflib.GLTF2().load(str(out))
    assert len(model.nodes) >= 1 and model.animations[0].channels
    assert main(["transfer", str(prior_file), str(target_png), "-o", str(tmp_path / "s.mp4"), "--gltf",
                 str(tmp_path / "result.gltf")]) == 2
    assert "--gltf must name a .glb file" in capsys.readouterr().err
