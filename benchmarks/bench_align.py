"""Photometric pose refinement (issue 16 §1): what :func:`marionette.reconstruct.align_poses` does to the
tracker's poses, against a model reconstructed under those poses and against one reconstructed under the
exact poses (an oracle: what the refinement can do once the model is right).

Scenes from ``make_scene`` (seed 0, 320x240): a one-part out-of-plane turn and the hinge. For each: the
tracker's prior (``extract_prior``, ``parts=1`` or ``"auto"``), a reconstruction (300 iterations, 240 px,
at most 6000 Gaussians) under the tracker's poses and one under the exact poses (with the true part
layout), and ``align_poses`` (default :class:`~marionette.reconstruct.AlignOptions`) from the tracker's
poses with each, and for the hinge also with the lid kept on its hinge (``hinges`` from the prior's metadata).
Rotation error per part against the true part it follows best (median and max over
frames 1..T-1), alignment seconds per frame. Writes ``docs/benchmarks/align.md``.

    flock /tmp/marionette-bench.lock python benchmarks/bench_align.py [--frames 32]
"""

from __future__ import annotations

import argparse
import platform
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "align.md"


def part_errors(poses: np.ndarray, truth: np.ndarray) -> list[tuple[int, float, float]]:
    """Per estimated part (K, T, 4, 4): (true part it follows best, median, max rotation error in degrees)."""
    from marionette.geometry import invert_transform, rotation_angle_deg

    out = []
    for p in poses:
        errs = [rotation_angle_deg((invert_transform(t) @ p)[1:, :3, :3]) for t in truth]
        best = int(np.argmin([np.median(e) for e in errs]))
        out.append((best, float(np.median(errs[best])), float(errs[best].max())))
    return out


def run_scene(motion: str, frames: int) -> list[tuple[str, list, float]]:
    """Rows (label, per-part errors, align seconds per frame) for one scene."""
    from marionette.prior import SpatPrior
    from marionette.reconstruct import (
        AlignOptions,
        ReconstructOptions,
        align_poses,
        hinges_from_metadata,
        reconstruct_object,
    )
    from marionette.source import ExtractOptions, extract_prior
    from marionette.synthetic import make_scene

    scene = make_scene(motion, seed=0, num_frames=frames, size=(320, 240))
    parts = "auto" if scene.num_parts > 1 else 1
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts=parts))
    rec_options = ReconstructOptions(iterations=300, max_side=240, max_gaussians=6000)
    rows = [("tracker", part_errors(prior.poses, scene.poses), float("nan"))]

    def aligned(label: str, rec, start: np.ndarray, hinges=()) -> None:
        t0 = time.perf_counter()
        result = align_poses(rec.gaussians, rec.parts, scene.frames, scene.masks, prior.intrinsics, start,
                             shading=rec.shading, hinges=hinges, options=AlignOptions())
        seconds = (time.perf_counter() - t0) / max(len(result.frames), 1)
        rows.append((label, part_errors(result.poses, scene.poses), seconds))

    tracked = reconstruct_object(scene.frames, scene.masks, prior, options=rec_options)
    aligned("aligned, model under the tracker's poses", tracked, prior.poses)
    hinges = hinges_from_metadata(prior.metadata.get("joints"))
    if hinges:
        aligned("aligned on the hinge, model under the tracker's poses", tracked, prior.poses, hinges)
    # The oracle model has the true parts; each starts from the tracker part that covers most of it at frame 0.
    layout = scene.part_masks[0] if scene.num_parts > 1 else np.where(scene.masks[0], 0, -1)
    labels = np.asarray(prior.extras["labels"])
    start = np.stack([prior.poses[np.bincount(labels[(layout == k) & (labels >= 0)],
                                              minlength=prior.num_parts).argmax()] for k in range(scene.num_parts)])
    exact = SpatPrior.from_poses(scene.poses, scene.centroids(), scene.radii(), fps=scene.fps,
                                 image_size=prior.image_size, intrinsics=prior.intrinsics,
                                 extras={"labels": layout.astype(np.int16)})
    aligned("aligned, model under the exact poses (oracle)",
            reconstruct_object(scene.frames, scene.masks, exact, options=rec_options), start)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=32)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    lines = ["# Photometric pose refinement", "",
             f"`python benchmarks/bench_align.py --frames {args.frames}`; {platform.processor() or platform.machine()}, "
             "2 cores. Scenes from `make_scene` (seed 0, 320x240). Rotation error per estimated part against the "
             "true part it follows best, median / max over frames 1..T-1, degrees.", "",
             "| scene | poses | per part: true part, median / max error | align s/frame |", "|---|---|---|---|"]
    for motion in ("outofplane", "hinge"):
        for label, errors, seconds in run_scene(motion, args.frames):
            parts = "; ".join(f"{k}: {med:.2f} / {mx:.2f}" for k, med, mx in errors)
            lines.append(f"| {motion} {args.frames}f | {label} | {parts} | "
                         f"{'–' if np.isnan(seconds) else f'{seconds:.2f}'} |")
            print(lines[-1], flush=True)
    lines += ["", "The oracle rows are what the refinement does once the model is right. The rows with the model "
              "reconstructed under the tracker's own poses are the open problem of issue 16: that model absorbs "
              "the poses' error (its relief trades against rotation; carving under a wrong lid pose removes the "
              "lid), so aligning to it gives the tracker's poses back. Alternating reconstruction and alignment, "
              "windows of 8 frames grown in time and Adam on the poses inside the reconstruction were tried and "
              "did not break that circle (closing notes of 2026-12-01 and 2026-12-04). The hinge's tracker row is "
              "its lid fitted as a hinge on the body (`marionette/source/hinge.py`, on by default since "
              "2026-12-04; 14.0° median free, 1.55° hinged). The free per-part alignment takes the lid off its "
              "hinge; aligned on the hinge (`align_poses(..., hinges=...)`: the lid moves with the box and turns "
              "by one angle per frame) it stays on it, and the model still holds it near where the tracker put it "
              "(grown in windows of 8 frames, each aligned on the hinge to a model of the frames before it, the "
              "lid came to 1.07° median, 2.48° max, in ~60 s; a session script, not kept).",
              ""]
    OUT.write_text("\n".join(lines))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
