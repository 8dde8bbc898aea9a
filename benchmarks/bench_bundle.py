"""The rigid bundle adjustment (``marionette.source.bundle``) against the clip's length.

A synthetic body turns 300° about a vertical axis over T frames at 854x480;
400 tracked points, 50 seen from frame 0 and the others born at random
frames, each tracked for 60 frames (as re-seeded tracks are), with 0.5 px of
noise; every pose starts 0.6° and 2 % of the radius off. One call as
``fit_rigid``'s final refinement makes it (all frames free, 30 cost
evaluations at most). Up to ``_DENSE_FRAMES`` free frames the reduced system
is solved dense, beyond as a sparse matrix; ``--dense-frames`` overrides
the switch to time one path on every length (printed only). Writes
``docs/benchmarks/bundle.md``.

    python benchmarks/bench_bundle.py [--runs 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from marionette.geometry import axis_angle_to_matrix, make_transform, rotation_angle_deg
from marionette.source import bundle

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "bundle.md"
K = np.array([[500.0, 0.0, 427.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
CENTRE = np.array([0.0, 0.0, 5.0])


def problem(frames: int, points: int = 400, length: int = 60, seed: int = 0):
    """Arguments of ``bundle_adjust`` and the true poses (T, 4, 4)."""
    rng = np.random.default_rng(seed)
    rot = axis_angle_to_matrix(np.radians(300.0) * np.linspace(0, 1, frames)[:, None] * [0.0, 1.0, 0.0])
    truth = make_transform(rot, CENTRE - rot @ CENTRE)
    unit = rng.normal(size=(points, 3))
    xyz = unit / np.linalg.norm(unit, axis=1, keepdims=True) + CENTRE
    cam = np.einsum("tij,nj->tni", truth[:, :3, :3], xyz) + truth[:, None, :3, 3]
    uv = cam[..., :2] / cam[..., 2:3] * 500.0 + [427.0, 240.0] + rng.normal(scale=0.5, size=(frames, points, 2))
    born = rng.integers(0, frames, points)
    born[:50] = 0
    t = np.arange(frames)[:, None]
    observed = (t >= born) & (t < born + length)
    start = truth.copy()
    for i in range(1, frames):
        start[i] = make_transform(axis_angle_to_matrix(rng.normal(scale=0.006, size=3)) @ truth[i, :3, :3],
                                  truth[i, :3, 3] + rng.normal(scale=0.012, size=3))
    lifted = xyz + rng.normal(scale=0.02, size=xyz.shape)
    directions = lifted / np.linalg.norm(lifted, axis=1, keepdims=True)
    return (observed, uv, K, start, lifted, directions, np.arange(1, frames), 0.1, 1.0, 30), truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--frames", default="50,100,200,400,800")
    parser.add_argument("--dense-frames", type=int, help="override bundle._DENSE_FRAMES")
    args = parser.parse_args()
    if args.dense_frames is not None:
        bundle._DENSE_FRAMES = args.dense_frames
    rows = []
    for frames in map(int, args.frames.split(",")):
        arguments, truth = problem(frames)
        times = []
        for _ in range(args.runs):
            tic = time.perf_counter()
            poses, _ = bundle.bundle_adjust(*arguments)
            times.append(time.perf_counter() - tic)
        before = np.median(rotation_angle_deg(np.swapaxes(arguments[3][:, :3, :3], -1, -2) @ truth[:, :3, :3]))
        after = np.median(rotation_angle_deg(np.swapaxes(poses[:, :3, :3], -1, -2) @ truth[:, :3, :3]))
        path = "dense" if frames - 1 <= bundle._DENSE_FRAMES else "sparse"
        rows.append((frames, int(arguments[0].sum()), path, statistics.median(times), before, after))
        print(f"{frames} frames ({path}): {statistics.median(times):.2f} s, "
              f"rotation error {before:.2f} -> {after:.2f}°")
    if args.dense_frames is not None:
        return  # the page shows the default switch
    lines = ["# Bundle adjustment against the clip's length", "",
             f"`python benchmarks/bench_bundle.py --runs {args.runs}` on {platform.machine()}, {os.cpu_count()} cores, "
             f"Python {platform.python_version()}: one call of `marionette.source.bundle.bundle_adjust` as "
             "`fit_rigid`'s final refinement makes it (all frames free, at most 30 cost evaluations), on a synthetic "
             "turn with 400 tracks of 60 frames (see the script's docstring). Median wall time of the runs; the "
             "solver runs BLAS on one thread. Rotation error: median over frames, degrees, of the start and of the "
             "result.", "",
             "| frames | observations | reduced system | s per call | rotation error before | after |",
             "|---:|---:|---|---:|---:|---:|"]
    lines += [f"| {f} | {o:,} | {p} | {s:.2f} | {b:.2f} | {a:.3f} |" for f, o, p, s, b, a in rows]
    DOC.write_text("\n".join(lines) + "\n")
    print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
