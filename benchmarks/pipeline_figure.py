"""Make the pipeline picture of ``docs/how_it_works.md``: one panel per stage of a real run.

Needs ``../shared/data`` (DAVIS train with its masks, the RealFusion teapot).
Runs the library's own stages at quick settings (a 480 px source, 48 output
frames; about a minute on two cores) and writes ``docs/images/pipeline.png``:
the source side (frames and masks, tracks, parts, the SpaT prior's poses),
the target side (photo, mask, shape, surfels) and the output (the velocity
field, result frames).

    flock /tmp/marionette-bench.lock python benchmarks/pipeline_figure.py
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

import marionette as mm
from marionette.geometry import axis_angle_to_matrix, make_transform, rotation_angle_deg
from marionette.gaussians import rgb_to_sh

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
OUT = Path(__file__).resolve().parents[1] / "docs" / "images" / "pipeline.png"
#: Part colours (tab10), as matplotlib draws the pose plot.
COLOURS = np.array([(0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
                    (0.58, 0.4, 0.74), (0.55, 0.34, 0.29)])


def part_colours(labels: np.ndarray) -> np.ndarray:
    """(N,) part labels (-1: none) → (N, 3) RGB in [0, 1], grey for none."""
    return np.where(labels[:, None] >= 0, COLOURS[np.maximum(labels, 0) % len(COLOURS)], 0.6)


def project(camera: mm.Camera, points: np.ndarray) -> np.ndarray:
    """(N, 3) world points → (N, 2) pixels."""
    cam = points @ camera.world_to_camera[:3, :3].T + camera.world_to_camera[:3, 3]
    uv = cam @ camera.K.T
    return uv[:, :2] / uv[:, 2:]


def turned(camera: mm.Camera, centre: np.ndarray, degrees: float) -> mm.Camera:
    """``camera`` orbited about the vertical axis through ``centre`` (3,) (world) by ``degrees``."""
    w2c = camera.world_to_camera
    c = w2c[:3, :3] @ centre + w2c[:3, 3]
    turn = axis_angle_to_matrix([0.0, np.radians(degrees), 0.0])
    return camera.with_pose(make_transform(turn, c - turn @ c) @ w2c)


def show(ax, image: np.ndarray, title: str, module: str) -> None:
    """An image panel titled with the stage and the module that does it."""
    ax.imshow(image)
    ax.set_title(f"{title}\n{module}", fontsize=9, family="sans-serif")
    ax.set_xticks([])
    ax.set_yticks([])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default="davis_train")
    parser.add_argument("--parts", default="3", help="as extract's --parts: a count or auto")
    parser.add_argument("--target", default="realfusion15_colorful_teapot/image.png")
    parser.add_argument("--output", type=Path, default=OUT)
    args = parser.parse_args()
    parts = args.parts if args.parts == "auto" else int(args.parts)
    fig = draw(*run(DATA / "videos" / args.source, DATA / "images" / args.target, parts))
    fig.suptitle(f"{args.source} onto a photo: the source (top), the target (middle), the output (bottom)")
    fig.tight_layout()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    # 256 colours: a third of the size, no visible loss on flat panels.
    Image.open(buffer).convert("RGB").quantize(256).save(args.output, optimize=True)
    print(f"wrote {args.output}")


def run(clip: Path, photo: Path, parts: int | str) -> tuple:
    """The stages on a clip (frame folder with masks) and a photo: prior, target, trajectory, output camera,
    result frames, source frames and masks."""
    prior = mm.extract(clip / "frames", masks=clip / "masks", max_side=480,
                       options=mm.ExtractOptions(parts=parts))
    target = mm.lift_target(photo, prior=prior)
    trajectory = mm.transfer(prior, target, frames=48)
    camera = mm.fit_view(target.camera, trajectory)
    frames = list(mm.render_frames(target.gaussians, trajectory, camera))
    source = mm.read_video(clip / "frames", max_side=480).frames
    masks = mm.read_video(clip / "masks", max_side=480).frames[..., 0] > 127
    return prior, target, trajectory, camera, frames, source, masks


def draw(prior, target, trajectory, camera, frames, source, masks) -> Figure:
    """The figure: a row of panels each for the source, the target and the output."""
    fig = Figure(figsize=(13, 9.6), dpi=80)
    axes = fig.subplots(3, 4)
    # The source: frames and masks → tracks → parts → the SpaT prior.
    t_mid = len(source) // 2
    overlay = source[t_mid].copy()
    overlay[~masks[t_mid]] = overlay[~masks[t_mid]] // 3
    show(axes[0, 0], overlay, "frames & masks", "marionette.io, source.foreground")
    uv, visible = prior.extras["tracks_uv"], prior.extras["tracks_visible"]  # (T, M, 2), (T, M)
    labels = np.asarray(prior.extras["track_labels"])  # (M,)
    colours = part_colours(labels)
    show(axes[0, 1], source[t_mid], "tracks", "source.tracks")
    for m in np.flatnonzero(visible[t_mid])[::3]:
        seen = np.flatnonzero(visible[max(0, t_mid - 12):t_mid + 1, m]) + max(0, t_mid - 12)
        axes[0, 1].plot(uv[seen, m, 0], uv[seen, m, 1], color=colours[m], linewidth=0.8)
    show(axes[0, 2], source[t_mid], f"{prior.num_parts} rigid parts & poses", "source.parts, source.rigid")
    on = visible[t_mid]
    axes[0, 2].scatter(uv[t_mid, on, 0], uv[t_mid, on, 1], s=4, c=colours[on])
    ax = axes[0, 3]
    seconds = np.arange(prior.num_frames) / prior.fps
    for k, angle in enumerate(rotation_angle_deg(prior.poses[..., :3, :3])):
        ax.plot(seconds, angle, color=COLOURS[k % len(COLOURS)], label=f"part {k}")
    ax.set_title("SpaT prior: each part's turn\nmarionette.prior", fontsize=9)
    ax.set_xlabel("time (s)", fontsize=8)
    ax.set_ylabel("rotation from frame 0 (°)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    # The target: photo → mask → shape → surfels.
    image = np.asarray(target.image)[..., :3]
    show(axes[1, 0], image, "target photo", "")
    cut = np.where(target.mask[..., None], image, 255)
    show(axes[1, 1], cut, "mask", "target.lift")
    side = turned(target.camera, target.gaussians.means.mean(axis=0), 90.0)
    view = mm.render(target.gaussians, side)
    show(axes[1, 2], np.where(view.alpha > 0.5, view.depth, np.nan), "shape: depth, seen from the side",
         "target.shapes")
    axes[1, 2].images[0].set_cmap("viridis")
    by_part = target.gaussians.with_sh(rgb_to_sh(part_colours(trajectory.labels))[:, None])
    show(axes[1, 3], np.clip(mm.render(by_part, target.camera).image, 0, 1), "surfels, by the part they follow",
         "target.surfels, transfer")
    # The output: velocity field → refinement → rasterizer → video.
    t0, step = len(frames) // 2, 4
    show(axes[2, 0], frames[t0], "velocity field", "transfer, transfer.refine")
    pick = np.random.default_rng(0).choice(trajectory.means.shape[1], 200, replace=False)
    start = project(camera, trajectory.means[t0, pick])
    end = project(camera, trajectory.means[min(t0 + step, len(frames) - 1), pick])
    axes[2, 0].quiver(start[:, 0], start[:, 1], *(end - start).T, color=part_colours(trajectory.labels[pick]),
                      angles="xy", scale_units="xy", scale=0.5, width=0.004)
    for ax, t in zip(axes[2, 1:], np.linspace(0, len(frames) - 1, 3).round().astype(int)):
        show(ax, frames[t], f"video, frame {t}", "render (rasterizer)")
    return fig


if __name__ == "__main__":
    main()
