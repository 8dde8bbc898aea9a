"""A textured mesh as the target: its surface sampled into flat Gaussians (surfels).

A mesh from an image-to-3D tool or a scan (``.glb``, ``.gltf``, ``.obj``, or a
``.ply`` with faces) is read with trimesh. Points are drawn on the surface by
area, each the centre of a flat Gaussian lying in its face, coloured from the
texture at its UV coordinates (or from the vertex or face colours). Meshes are
y-up with their front towards +z (glTF's convention); they are turned half a
turn about x into the camera convention (y down, z forward), so the front view
of :func:`marionette.pipeline.load_target` sees their front.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..gaussians import Gaussians, rgb_to_sh
from ..geometry import matrix_to_quaternion
from ._solid import surfel_frames

__all__ = ["MESH_SUFFIXES", "is_mesh_file", "mesh_gaussians"]

#: Suffixes of mesh files; a ``.ply`` is a mesh when it has faces and no 3DGS properties.
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")
#: Surfels drawn on a mesh.
DEFAULT_SURFELS = 60_000


def is_mesh_file(path: str | Path) -> bool:
    """Whether ``path`` names a mesh: a ``.glb``, ``.gltf`` or ``.obj``, or a ``.ply`` with faces and no 3DGS
    colour properties (``f_dc_0``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".glb", ".gltf", ".obj"):
        return True
    if suffix != ".ply" or not path.is_file():
        return False
    with open(path, "rb") as f:  # the header is text up to end_header
        header = f.read(65536).split(b"end_header")[0]
    return b"element face" in header and b"f_dc_0" not in header


def mesh_gaussians(path: str | Path, count: int = DEFAULT_SURFELS, seed: int = 0) -> Gaussians:
    """``count`` flat Gaussians on the surface of the mesh in ``path``, in the camera convention.

    Each lies in its face (normal axis a twentieth of the others), about as wide as the area per surfel, so
    that together they cover the surface; opacity 0.95; colour (SH degree 0) from the texture or the
    vertex or face colours, grey when the mesh has none.
    """
    import trimesh  # here: only a mesh target needs it

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist" if not path.exists() else f"{path} is not a file")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types on bad files; all mean the same to the user
        raise InputError(f"{path.name} is not a mesh trimesh can read: {str(e).splitlines()[0] if str(e) else e}") \
            from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or not mesh.area > 0:
        raise InputError(f"{path.name} holds no surface (no faces with area)")
    if not np.isfinite(mesh.vertices).all():
        raise InputError(f"{path.name} has vertices that are not finite numbers")
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    colours = _surface_colours(mesh, np.asarray(points), np.asarray(faces))
    flip = np.diag([1.0, -1.0, -1.0])  # y-up, front +z → y down, z forward
    means = np.asarray(points, np.float64) @ flip
    normals = np.asarray(mesh.face_normals[faces], np.float64) @ flip
    frames = surfel_frames(normals)  # the normal as the third axis: the Gaussian's flat direction
    width = 0.6 * np.sqrt(mesh.area / count)
    log_scales = np.log(np.tile([width, width, width / 20], (len(points), 1)))
    rgb = colours
    return Gaussians(means.astype(np.float32), matrix_to_quaternion(frames).astype(np.float32),
                     log_scales.astype(np.float32), np.full(len(points), np.log(0.95 / 0.05), np.float32),
                     rgb_to_sh(rgb).astype(np.float32)[:, None])


def _surface_colours(mesh, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) colours in [0, 1] of ``points`` (N, 3) on the mesh's ``faces`` (N,): the texture at their UV
    coordinates (times a PBR base colour factor), else the vertex colours interpolated, else the face colours,
    else grey."""
    import trimesh

    visual = mesh.visual
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[faces], points)  # (N, 3)
    if visual.kind == "texture" and getattr(visual, "uv", None) is not None:
        material = visual.material
        image = getattr(material, "image", None)
        image = getattr(material, "baseColorTexture", None) if image is None else image
        factor = getattr(material, "baseColorFactor", None)  # PBR: multiplies the texture
        factor = np.ones(3) if factor is None else np.asarray(factor, np.float64)[:3]
        factor = factor / 255.0 if factor.max() > 1 else factor
        if image is None:
            return np.tile(factor, (len(points), 1))
        uv = np.einsum("nk,nkj->nj", bary, np.asarray(visual.uv)[mesh.faces[faces]])
        return np.asarray(trimesh.visual.uv_to_color(uv, image), np.float64)[:, :3] / 255.0 * factor
    if visual.kind == "vertex":
        vertex = np.asarray(visual.vertex_colors, np.float64)[:, :3] / 255.0
        return np.einsum("nk,nkj->nj", bary, vertex[mesh.faces[faces]])
    if visual.kind == "face":
        return np.asarray(visual.face_colors, np.float64)[faces, :3] / 255.0
    return np.full((len(points), 3), 0.63)
