"""``marionette demo``: the whole method on a synthetic source and target, no data needed."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .io import write_image, write_prior, write_video
from .pipeline import fit_view, relative_depth, render_frames, side_by_side, transfer
from .progress import Reporter
from .render import render
from .source import extract_prior
from .synthetic import SyntheticScene, make_scene, render_object_image
from .target.lift import LiftOptions, lift_image

__all__ = ["run_demo", "write_demo_inputs"]


def _inputs(seed: int) -> tuple[SyntheticScene, np.ndarray]:
    """The demo's source (a box turning out of plane, 48 frames of 320x240) and (256, 256, 4) RGBA target."""
    return (make_scene("outofplane", num_frames=48, size=(320, 240), seed=seed),
            render_object_image("hinge", size=(256, 256), seed=seed + 1))


def _write_inputs(folder: Path, scene: SyntheticScene, target: np.ndarray) -> dict[str, Path]:
    paths = {"source": folder / "source.mp4", "target": folder / "target.png"}
    write_video(paths["source"], scene.frames, scene.fps)
    write_image(paths["target"], target)
    return paths


def write_demo_inputs(folder: str | Path = ".", *, seed: int = 0) -> dict[str, Path]:
    """Write the demo's synthetic inputs, ``source.mp4`` and ``target.png``, into ``folder``; their paths.

    Something to try the library on without data: the source is a textured
    box turning out of plane, the target an object with a lid on a
    transparent background.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return _write_inputs(folder, *_inputs(seed))


def run_demo(out_dir: str | Path, *, reporter: Reporter | None = None, seed: int = 0) -> dict[str, Path]:
    """Extract the motion of a synthetic turning box and transfer it onto another object.

    Writes ``source.mp4``, ``target.png``, ``prior.npz``, ``result.mp4`` and
    ``side_by_side.mp4`` into ``out_dir`` (created if missing) and returns
    their paths.
    """
    reporter = reporter or Reporter(quiet=True)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {name: out / f"{name}{ext}" for name, ext in
             (("prior", ".npz"), ("result", ".mp4"), ("side_by_side", ".mp4"))}
    start = time.perf_counter()

    with reporter.stage("synthetic source", 1) as progress:
        scene, target_rgba = _inputs(seed)
        progress(1, 1)
    paths = _write_inputs(out, scene, target_rgba) | paths

    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, reporter=reporter)
    write_prior(paths["prior"], prior)

    with reporter.stage("lifting target", 1) as progress:
        target = lift_image(target_rgba, options=LiftOptions(relative_depth=relative_depth(prior)))
        progress(1, 1)
    # Warm the rasterizer's compiled kernels before the timed loop shows its bar.
    render(target.gaussians.subset(np.arange(1)), target.camera)
    trajectory = transfer(prior, target)
    with reporter.stage("rendering", trajectory.num_frames) as progress:
        frames = list(render_frames(target.gaussians, trajectory, fit_view(target.camera, trajectory),
                                    progress=progress))
    write_video(paths["result"], frames, prior.fps)
    write_video(paths["side_by_side"], side_by_side(scene.frames, frames), prior.fps)
    reporter.message(f"demo finished in {time.perf_counter() - start:.1f} s")
    return paths
