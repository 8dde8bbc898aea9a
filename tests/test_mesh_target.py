"""A textured mesh as the target: sampled into surfels that look like the mesh from its front."""

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image

from marionette import pipeline
from marionette.cli import main
from marionette.errors import InputError
from marionette.io import read_video, write_ply
from marionette.render import render
from marionette.target.mesh import is_mesh_file, mesh_gaussians

FRONT, BACK, SIDE, TOP = (220, 30, 30), (30, 30, 220), (30, 200, 30), (230, 230, 30)


def coloured_box() -> trimesh.Trimesh:
    """A 2 x 1 x 0.5 box, y up, a colour per side: its front (+z) red."""
    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.unmerge_vertices()  # a colour per face survives formats that store vertex colours
    n = box.face_normals
    colours = np.zeros((len(box.faces), 4), np.uint8)
    colours[:, 3] = 255
    colours[n[:, 2] > 0.5, :3] = FRONT
    colours[n[:, 2] < -0.5, :3] = BACK
    colours[np.abs(n[:, 0]) > 0.5, :3] = SIDE
    colours[np.abs(n[:, 1]) > 0.5, :3] = TOP
    box.visual.face_colors = colours
    return box


@pytest.mark.parametrize("suffix", [".glb", ".obj", ".ply"])
def test_a_coloured_box_is_seen_from_its_front_with_its_outline(tmp_path, suffix):
    path = tmp_path / f"box{suffix}"
    coloured_box().export(path)
    assert is_mesh_file(path)
    lifted = pipeline.load_target(path, size=(256, 192))
    out = render(lifted.gaussians, lifted.camera, (1.0, 1.0, 1.0))
    assert np.abs(out.image[96, 128] * 255 - FRONT).max() <= 3  # the front face, not the back one
    # the silhouette is the convex hull of the box's corners, seen through the same camera
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-0.5, 0.5) for z in (-0.25, 0.25)]) @ np.diag([1, -1, -1])
    uv, _ = lifted.camera.project(corners)
    hull = np.zeros((192, 256), np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.rint(uv).astype(np.int32)), 1)
    silhouette, hull = out.alpha >= 0.5, hull.astype(bool)
    assert (silhouette & hull).sum() / (silhouette | hull).sum() > 0.95


def test_a_texture_is_read_at_each_surfels_uv_unmirrored(tmp_path):
    texture = np.zeros((64, 64, 3), np.uint8)
    texture[:, :32] = (255, 0, 0)
    texture[:, 32:] = (0, 0, 255)
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]],
                             visual=trimesh.visual.TextureVisuals(
                                 uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                 material=trimesh.visual.material.PBRMaterial(
                                     baseColorTexture=Image.fromarray(texture))), process=False)
    square.export(tmp_path / "square.glb")
    lifted = pipeline.load_target(tmp_path / "square.glb", size=(128, 128))
    out = render(lifted.gaussians, lifted.camera, (1.0, 1.0, 1.0)).image
    assert np.abs(out[64, 40] - (1, 0, 0)).max() < 0.02 and np.abs(out[64, 88] - (0, 0, 1)).max() < 0.02


def test_surfels_lie_on_the_surface_flat_in_their_faces(tmp_path):
    from marionette.geometry import quaternion_to_matrix

    g = mesh_gaussians_of(tmp_path, count=2000)
    points = g.means.astype(np.float64) @ np.diag([1, -1, -1])  # back to the mesh's own axes
    half = np.array([1.0, 0.5, 0.25])
    on_face = np.abs(np.abs(points) - half) < 1e-5  # (N, 3): which side each lies on
    assert on_face.any(axis=1).all() and (np.abs(points) <= half + 1e-5).all()
    axes = quaternion_to_matrix(g.quats.astype(np.float64))  # (N, 3, 3): columns are the Gaussian's axes
    thin = axes[np.arange(len(g.means)), :, np.argmin(g.log_scales, axis=1)]
    side = np.argmax(on_face, axis=1)
    assert np.allclose(np.abs(thin[np.arange(len(side)), side]), 1.0, atol=1e-5)  # the flat axis is the normal
    # sampled by area: the sides hold surfels in proportion to their areas (2 x 1, 2 x 0.5, 1 x 0.5)
    share = np.bincount(side, minlength=3) / len(side)
    assert np.allclose(share, np.array([0.5, 1.0, 2.0]) / 3.5, atol=0.03)


def test_a_3dgs_ply_is_not_taken_for_a_mesh(tmp_path):
    gaussians = mesh_gaussians_of(tmp_path)
    write_ply(tmp_path / "splats.ply", gaussians)
    assert not is_mesh_file(tmp_path / "splats.ply")
    assert len(pipeline.load_target(tmp_path / "splats.ply").gaussians) == len(gaussians)


def mesh_gaussians_of(tmp_path, count=500):
    coloured_box().export(tmp_path / "box.glb")
    return mesh_gaussians(tmp_path / "box.glb", count=count)


def test_unreadable_meshes_are_one_line_errors(tmp_path, capsys, prior_file):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF not really")
    with pytest.raises(InputError, match="bad.glb"):
        pipeline.load_target(bad)
    assert main(["transfer", str(prior_file), str(bad), "-o", str(tmp_path / "o.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "bad.glb" in err[0]
    assert not (tmp_path / "o.mp4").exists()


def test_a_mesh_target_moves_on_the_command_line_but_has_no_scene(tmp_path, capsys, prior_file):
    coloured_box().export(tmp_path / "box.glb")
    out = tmp_path / "box.mp4"
    assert main(["transfer", str(prior_file), str(tmp_path / "box.glb"), "-o", str(out), "--size", "96x64",
                 "-q"]) == 0
    frames = read_video(out).frames
    assert frames.shape[1:3] == (64, 96) and frames[0].min() < 200  # the box is drawn
    assert main(["transfer", str(prior_file), str(tmp_path / "box.glb"), "-o", str(tmp_path / "s.mp4"),
                 "--background", "scene"]) == 2
    assert "has no scene around it" in capsys.readouterr().err
