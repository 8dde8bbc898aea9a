"""Cost of the rasterizer's backward pass: forward alone against forward + backward.

Run from the repository root::

    python benchmarks/bench_rasterizer_grad.py [--runs 15]

Same scene as ``benchmarks/bench_rasterizer.py`` (a synthetic 3DGS-like object
of SH degree 3 covering about half of a 512×512 image). One iteration of a
photometric fit is ``render_with_grad`` (the forward, also keeping per pixel
the final transmittance and the last Gaussian) followed by ``backward`` with
an L2 loss against a target image and a pose gradient for a third of the
Gaussians; it is compared with :func:`marionette.render.render`. The two are
timed alternately, after one warm-up each, so that load on the machine hits
both alike. The figures go to ``docs/benchmarks/rasterizer_grad.md`` and to
stdout.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from marionette.render import render
from marionette.render.backward import render_with_grad

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_rasterizer import SIZE, machine_info, make_scene, write_page  # noqa: E402

COUNTS = (10_000, 100_000, 300_000)


def time_scene(n: int, runs: int) -> dict[str, float]:
    """Median wall and CPU seconds of the forward alone and of forward + backward."""
    gaussians, camera = make_scene(n)
    rng = np.random.default_rng(1)
    # float32, as the fitting code keeps its target frames.
    target = np.clip(render(gaussians, camera).image + rng.normal(0.0, 0.05, (SIZE, SIZE, 3)), 0, 1
                     ).astype(np.float32)
    group = np.arange(n) % 3 == 0

    def forward() -> None:
        render(gaussians, camera)

    laps: dict[str, list[float]] = {"save": [], "backward": []}

    def forward_backward() -> None:
        t0 = time.perf_counter()
        view = render_with_grad(gaussians, camera)
        t1 = time.perf_counter()
        view.backward(2.0 * (view.output.image - target), groups=group)
        t2 = time.perf_counter()
        laps["save"].append(t1 - t0)
        laps["backward"].append(t2 - t1)

    forward()
    forward_backward()
    laps = {k: [] for k in laps}
    wall = {"fwd": [], "both": []}
    cpu = {"fwd": [], "both": []}
    for _ in range(runs):
        for name, fn in (("fwd", forward), ("both", forward_backward)):
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    out = {f"{k}_wall": statistics.median(v) for k, v in wall.items()}
    out.update({f"{k}_cpu": statistics.median(v) for k, v in cpu.items()})
    out.update({f"{k}_best": min(v) for k, v in wall.items()})
    out.update({k: statistics.median(v) for k, v in laps.items()})
    # Ratio per alternating pair, then the median: robust to load that changes during the run.
    out["ratio"] = statistics.median(b / f for f, b in zip(wall["fwd"], wall["both"]))
    out["ratio_cpu"] = statistics.median(b / f for f, b in zip(cpu["fwd"], cpu["both"]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15, help="timed runs per scene (median reported)")
    args = parser.parse_args()

    load_before = os.getloadavg()[0]
    rows = []
    for n in COUNTS:
        f = time_scene(n, args.runs)
        rows.append((n, f))
        print(f"N={n}: forward {1e3 * f['fwd_wall']:.1f} ms, forward + backward {1e3 * f['both_wall']:.1f} ms "
              f"({f['ratio']:.2f}×, CPU {f['ratio_cpu']:.2f}×)", flush=True)

    info = machine_info()
    info["load average (1 min) before / after the run"] = f"{load_before:.2f} / {os.getloadavg()[0]:.2f}"
    lines = [
        "# Rasterizer gradient benchmark",
        "",
        f"Produced by `python benchmarks/bench_rasterizer_grad.py --runs {args.runs}`: {SIZE}×{SIZE} image, "
        "the synthetic 3DGS-like object of `bench_rasterizer.py` (SH degree 3). *Forward* is "
        "`render`; *forward + backward* is one fitting iteration: `render_with_grad` then `backward` "
        "of an L2 loss against a float32 target image, with the SE(3) gradient of a group holding a third of "
        f"the Gaussians. Medians of {args.runs} runs, the two timed alternately after a warm-up.",
        "",
        "| Gaussians | forward ms | forward + backward ms | ratio | CPU ratio | best forward ms "
        "| best forward + backward ms | render_with_grad ms | backward ms |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n, f in rows:
        lines.append(
            f"| {n:,} | {1e3 * f['fwd_wall']:.1f} | {1e3 * f['both_wall']:.1f} | {f['ratio']:.2f}× "
            f"| {f['ratio_cpu']:.2f}× | {1e3 * f['fwd_best']:.1f} | {1e3 * f['both_best']:.1f} "
            f"| {1e3 * f['save']:.1f} | {1e3 * f['backward']:.1f} |")
    lines += [
        "",
        "Ratio: median over the alternating runs of (forward + backward) / forward wall time; CPU "
        "ratio: the same with CPU time summed over threads, less sensitive to other processes. "
        "render_with_grad and backward: median wall milliseconds of the two halves of an iteration "
        "(backward includes checking the upstream gradient, the tile pass and the projection pass). "
        "Wall figures depend on what else the machine runs (load average below).",
    ]
    write_page("rasterizer_grad.md", lines, info)


if __name__ == "__main__":
    main()
