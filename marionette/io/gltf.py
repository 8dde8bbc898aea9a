"""An animated result as binary glTF (``.glb``): one node per rigid part, its motion as keyframes.

Each part is a node holding its Gaussians' centres at rest as a point cloud
(coloured by their base colour); the node's translation and rotation per
output frame move it as the transfer moved the part, so any glTF player
(Blender, three.js, a browser viewer) plays the motion. glTF is y-up with the
camera looking down -z; our frames are y-down, z-forward, so every position
and rotation is turned half a turn about x (``F = diag(1, -1, -1)``).
A part's motion is the rigid one that best fits its Gaussians: its rotation,
and the mean of what is left as its translation (exact for a rigid part).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..gaussians import Gaussians, sh_to_rgb
from ..geometry import matrix_to_quaternion
from ..trajectory import Trajectory
from .atomic import atomic_path

__all__ = ["write_gltf_animation", "part_motions"]

_FLIP = np.diag([1.0, -1.0, -1.0])


def part_motions(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Each part's rigid motion from frame 0: rotations (T, P, 3, 3) and translations (T, P, 3), float64,
    with ``means[t, i] ≈ R[t, p] means[0, i] + d[t, p]`` for the Gaussians ``i`` of part ``p``."""
    rotations = trajectory.part_rotations.astype(np.float64)
    means = trajectory.means.astype(np.float64)
    t, p = rotations.shape[:2]
    translations = np.zeros((t, p, 3))
    for k in range(p):
        members = trajectory.labels == k
        if members.any():
            rest = means[0, members]  # (M, 3)
            translations[:, k] = (means[:, members] - np.einsum("tij,mj->tmi", rotations[:, k], rest)).mean(axis=1)
    return rotations, translations


def write_gltf_animation(path: str | Path, gaussians: Gaussians, trajectory: Trajectory, fps: float) -> None:
    """Write the parts of ``gaussians`` moving along ``trajectory`` at ``fps`` as a ``.glb``, atomically."""
    import pygltflib as gl  # here: only this output needs it

    rotations, translations = part_motions(trajectory)
    frames, parts = rotations.shape[:2]
    times = (np.arange(frames) / float(fps)).astype(np.float32)
    rgb = np.clip(sh_to_rgb(gaussians.sh[:, 0]), 0.0, 1.0).astype(np.float32)
    rest = (trajectory.means[0].astype(np.float64) @ _FLIP).astype(np.float32)
    blob = bytearray()
    views, accessors = [], []

    def add(array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        """Append ``array`` (float32) to the buffer as one accessor of ``kind`` (SCALAR, VEC3, VEC4); its index."""
        data = np.ascontiguousarray(array, dtype=np.float32)
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=data.nbytes, target=target))
        blob.extend(data.tobytes())
        flat = data.reshape(len(data), -1)
        accessors.append(gl.Accessor(bufferView=len(views) - 1, componentType=gl.FLOAT, count=len(data), type=kind,
                                     min=flat.min(axis=0).tolist() if bounds else None,
                                     max=flat.max(axis=0).tolist() if bounds else None))
        return len(accessors) - 1

    time_input = add(times, gl.SCALAR, bounds=True)  # glTF requires the input's bounds
    nodes, meshes, samplers, channels = [], [], [], []
    for k in range(parts):
        members = trajectory.labels == k
        if not members.any():
            continue
        position = add(rest[members], gl.VEC3, gl.ARRAY_BUFFER, bounds=True)
        colour = add(rgb[members], gl.VEC3, gl.ARRAY_BUFFER)
        meshes.append(gl.Mesh(name=f"part {k}", primitives=[gl.Primitive(
            attributes=gl.Attributes(POSITION=position, COLOR_0=colour), mode=gl.POINTS)]))
        turned = _FLIP @ rotations[:, k] @ _FLIP  # (T, 3, 3) in glTF's axes
        quats = matrix_to_quaternion(turned)[:, [1, 2, 3, 0]]  # w, x, y, z → glTF's x, y, z, w
        moved = translations[:, k] @ _FLIP
        node = len(nodes)
        nodes.append(gl.Node(name=f"part {k}", mesh=len(meshes) - 1, translation=moved[0].tolist(),
                             rotation=quats[0].tolist()))
        for path_name, values, kind in (("translation", moved, gl.VEC3), ("rotation", quats, gl.VEC4)):
            samplers.append(gl.AnimationSampler(input=time_input, output=add(values, kind), interpolation="LINEAR"))
            channels.append(gl.AnimationChannel(sampler=len(samplers) - 1,
                                                target=gl.AnimationChannelTarget(node=node, path=path_name)))
    model = gl.GLTF2(asset=gl.Asset(generator="motion-marionette"), scene=0,
                     scenes=[gl.Scene(nodes=list(range(len(nodes))))], nodes=nodes, meshes=meshes,
                     accessors=accessors, bufferViews=views, buffers=[gl.Buffer(byteLength=len(blob))],
                     animations=[gl.Animation(name="motion", samplers=samplers, channels=channels)])
    model.set_binary_blob(bytes(blob))
    with atomic_path(Path(path)) as tmp:
        model.save_binary(str(tmp))
