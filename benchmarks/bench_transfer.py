"""Transfer and render speed: 50 frames at 512x512 with about 150k Gaussians (issue 4's setting).

Synthetic inputs only (no data needed): the demo's turning-box prior, 50
frames, and a 512x512 target of the hinge object lifted at stride 1 (about
340k Gaussians) of which a random 150k are kept. The
median of ``--runs`` runs after one warm-up; peak memory from ``ru_maxrss``.
Writes ``docs/benchmarks/transfer.md``.

    python benchmarks/bench_transfer.py [--runs 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from marionette import pipeline
from marionette.source import extract_prior
from marionette.synthetic import make_scene, render_object_image
from marionette.target.lift import LiftOptions, lift_image
from marionette.transfer.metrics import trajectory_quality

OUT = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "transfer.md"


def time_transfer_render(prior, target) -> tuple[float, float]:
    """Seconds to transfer ``prior`` onto the lifted ``target`` and to render every frame (not written)."""
    start = time.perf_counter()
    trajectory = pipeline.transfer(prior, target)
    camera = pipeline.fit_view(target.camera, trajectory)
    middle = time.perf_counter()
    for _ in pipeline.render_frames(target.gaussians, trajectory, camera):
        pass
    return middle - start, time.perf_counter() - middle


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--gaussians", type=int, default=150_000, help="random subset of the lifted target")
    args = parser.parse_args()
    scene = make_scene("outofplane", num_frames=50, size=(320, 240), seed=0)
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps)
    image = render_object_image("hinge", size=(512, 512), seed=1)
    target = lift_image(image, options=LiftOptions(relative_depth=pipeline.relative_depth(prior)))
    keep = np.sort(np.random.default_rng(0).choice(len(target.gaussians), args.gaussians, replace=False))
    target = replace(target, gaussians=target.gaussians.subset(keep), pixel_of=target.pixel_of[keep])
    count = len(target.gaussians)

    time_transfer_render(prior, target)  # warm-up: numba compilation
    runs = [time_transfer_render(prior, target) for _ in range(args.runs)]
    transfer_s = statistics.median(r[0] for r in runs)
    render_s = statistics.median(r[1] for r in runs)
    total = statistics.median(r[0] + r[1] for r in runs)
    quality = trajectory_quality(pipeline.transfer(prior, target))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    lines = [
        "# Transfer and render speed", "",
        f"`python benchmarks/bench_transfer.py --runs {args.runs}` on {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}: the synthetic out-of-plane prior (50 frames) applied to a 512x512 "
        f"target lifted at stride 1, {count:,} Gaussians kept at random, rendered at 512x512. Median of {args.runs} runs after "
        "a warm-up. Target (issue 4): <= 5 s, <= 2 GB; the paper reports 2.2 minutes on an RTX A6000.", "",
        "| Gaussians | frames | transfer s | render s | total s | fps | peak MB | rigidity error |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
        f"| {count:,} | {prior.num_frames} | {transfer_s:.2f} | {render_s:.2f} | {total:.2f} | "
        f"{prior.num_frames / total:.1f} | {peak:.0f} | {100 * quality.rigidity_error:.4f} % |",
    ]
    OUT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines[-3:]))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
