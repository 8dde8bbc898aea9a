"""Ablation of the transfer refinement: none / kinematic / + topological / + propagation / + shape matching / + joints.

Two cases: the synthetic hinge (ground-truth two-part prior onto a lifted
hinged target image, parts matched from the source layout) and a real clip
(davis_train extracted with ``--parts 4`` onto the realfusion15 teapot;
skipped when /work/shared/data is absent). Each row adds one step to the
previous; the last row turns on joints (ours), which the earlier rows leave
off. Writes ``docs/benchmarks/ablation.md`` and contact sheets
``docs/images/ablation_<case>.png`` (one row of frames per ablation row).

    python benchmarks/bench_ablation.py [--prior /tmp/ablation_train_prior.npz]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from marionette import pipeline
from marionette.io import read_prior
from marionette.render import render
from marionette.synthetic import make_scene, render_object_image
from marionette.target.lift import LiftOptions, lift_image
from marionette.transfer.metrics import trajectory_quality
from marionette.transfer.parts import labels_from_seeds, seeds_from_layout
from marionette.transfer.refine import RefineOptions
from marionette.transfer.velocity import integrate

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "ablation.md"
DATA = Path("/work/shared/data")
OFF = {"kinematic": False, "topological": False, "propagation": False, "shape_matching": False, "joints": False}
ROWS = [
    ("none", None),
    ("kinematic", RefineOptions(**{**OFF, "kinematic": True})),
    ("+ topological", RefineOptions(**{**OFF, "kinematic": True, "topological": True})),
    ("+ propagation", RefineOptions(**{**OFF, "kinematic": True, "topological": True, "propagation": True})),
    ("+ shape matching", RefineOptions(joints=False)),
    ("+ joints (default)", RefineOptions()),
    ("joints only", RefineOptions(**{**OFF, "joints": True})),
]


def hinge_case():
    scene = make_scene("hinge", object="hinge", num_frames=50, size=(320, 240), seed=0)
    prior = scene.ground_truth_prior().aimed_at_object()
    target = lift_image(render_object_image("hinge", size=(256, 256), seed=1),
                        options=LiftOptions(relative_depth=pipeline.relative_depth(prior)))
    seeds = seeds_from_layout(scene.part_masks[0], target.mask)
    return prior, target, seeds


def train_case(prior_path: Path):
    clip = DATA / "videos" / "davis_train"
    if not prior_path.exists():
        subprocess.run([sys.executable, "-m", "marionette", "extract", str(clip / "frames"), "--masks",
                        str(clip / "masks"), "--parts", "4", "-o", str(prior_path)], check=True)
    prior = read_prior(prior_path).aimed_at_object()
    target = pipeline.load_target(DATA / "images" / "realfusion15_colorful_teapot" / "image_rgba.png",
                                  prior=prior, options=LiftOptions(stride=2))
    seeds = seeds_from_layout(np.asarray(prior.extras["labels"]), target.mask)
    return prior, target, seeds


def contact_sheet(target, trajectories, path: Path, frames=(0, 16, 33, 49), side=112) -> None:
    """Rows of frames (one row per ablation row), all from one camera framing every row."""
    camera = target.camera.framing(np.concatenate([t.means[:, ::50].reshape(-1, 3) for t in trajectories]), 0.06)
    rows = []
    for trajectory in trajectories:
        tiles = [render(trajectory.frame(target.gaussians, min(t, trajectory.num_frames - 1)), camera).image
                 for t in frames]
        rows.append(np.concatenate([cv2.resize(np.clip(tile, 0, 1), (side, side), interpolation=cv2.INTER_AREA)
                                    for tile in tiles], axis=1))
    sheet = (np.concatenate(rows, axis=0) * 255 + 0.5).astype(np.uint8)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])


def run_case(name, prior, target, seeds):
    labels = labels_from_seeds(target.gaussians.means, target.pixel_of, seeds)
    lines = [(f"### {name}: {len(labels):,} Gaussians, {np.bincount(labels).tolist()} per part, "
              f"{prior.num_frames} frames"), "",
             "| refinement | rigidity error | boundary separation | detached seam | jerk | time s |",
             "|---|---:|---:|---:|---:|---:|"]
    trajectories = []
    integrate(target.gaussians.means, labels, prior, refine=RefineOptions())  # warm-up: numba compilation
    for row, options in ROWS:
        start = time.perf_counter()
        trajectory = integrate(target.gaussians.means, labels, prior, refine=options)
        elapsed = time.perf_counter() - start
        q = trajectory_quality(trajectory)
        trajectories.append(trajectory)
        lines.append(f"| {row} | {100 * q.rigidity_error:.3f} % | {100 * q.boundary_separation:.1f} % | "
                     f"{100 * q.detached_seam:.1f} % | {q.jerk:.2e} | {elapsed:.2f} |")
        print(lines[-1], flush=True)
    sheet = ROOT / "docs" / "images" / f"ablation_{name}.png"
    contact_sheet(target, trajectories, sheet)
    caption = f"![{name}](../images/{sheet.name}) rows top to bottom as in the table; frames 0, 16, 33, 49."
    return [*lines, "", caption, ""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--prior", type=Path, default=Path("/tmp/ablation_train_prior.npz"),
                        help="davis_train prior with 4 parts (extracted once when missing)")
    args = parser.parse_args()
    intro = ("`python benchmarks/bench_ablation.py`. Metrics from `trajectory_quality`: rigidity error (mean "
             "relative change of within-part kNN edge lengths), boundary separation (share of across-part kNN edges "
             "stretched by more than 50 % at some frame, issue 4's definition), detached seam (ours: share of "
             "across-part edges that tear while their two parts keep no contact at all), jerk (object radii per "
             "frame³). Each row adds one step; joints (ours) are off until the row that adds them. Time is "
             "`integrate` alone (2 shared cores, so +-30 %).")
    reading = ("Reading: the kinematic sweeps smooth the residual from each part's rigid motion, so alone they "
               "change nothing (rigid fields have none); the topological term bends the band (rigidity error up) "
               "without closing a seam whose parts turn about different centres; shape matching takes most of "
               "that bend back out. What keeps parts attached is turning each part about its joint: with joints "
               "the hinge keeps its hinge line and no seam detaches. Boundary separation stays high all the same, "
               "and no rigid refinement can lower it: as the lid opens, every seam edge off the hinge line "
               "stretches (the open side gapes, as a real box's does); only bending the band until both sides of "
               "the seam move together would pass it, which moves the tear one row inwards instead of removing "
               "it. Issue 4's target of <= 1 % is therefore missed on the hinge. Joints form a tree (the maximum "
               "spanning tree of the seams): in a cycle of parts, as on the teapot, the shortest seam may "
               "detach.")
    lines = ["# Refinement ablation", "", intro, "", reading, ""]
    lines += run_case("hinge", *hinge_case())
    if DATA.exists():
        lines += run_case("train_teapot", *train_case(args.prior))
    OUT.write_text("\n".join(lines))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
