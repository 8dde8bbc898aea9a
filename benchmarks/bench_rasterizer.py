"""Frames per second of the CPU rasterizer, and its speed-up over the NumPy reference.

Run from the repository root::

    python benchmarks/bench_rasterizer.py [--runs 15] [--no-reference]

The scene imitates a trained 3DGS object: a bumpy sphere of radius 1 seen from
2.8 units (it covers about half of a 512×512 image at a 50° field of view),
80% of the Gaussians flat splats on the surface (tangent scales sized so that
neighbours overlap, normal scale a fifth of that, log-normal spread), 20%
rounder ones inside; opacities ``sigmoid(N(1.5, 2))`` (mean about 0.7, many
near 1, some faint); SH degree 3 with small higher-order terms. The figures go
to ``docs/benchmarks/rasterizer.md`` and to stdout.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

from marionette.camera import Camera
from marionette.gaussians import Gaussians, rgb_to_sh
from marionette.geometry import make_transform, matrix_to_quaternion
from marionette.render import render
from marionette.render.rasterizer import _rasterize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from reference_rasterizer import render_reference  # noqa: E402

SIZE = 512
COUNTS = (100_000, 300_000)


def make_scene(n: int, seed: int = 0) -> tuple[Gaussians, Camera]:
    """A splat object of ``n`` Gaussians and a 512×512 camera looking at it."""
    rng = np.random.default_rng(seed)
    n_surface = int(0.8 * n)
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    bump = 1.0 + 0.08 * np.sin(5 * normal[:, 0]) * np.cos(4 * normal[:, 1])
    depth = np.where(np.arange(n) < n_surface, 1.0, rng.uniform(0.3, 0.97, n) ** (1 / 3))
    means = normal * (bump * depth)[:, None]
    # Tangent frame per Gaussian: local z along the normal.
    tangent = np.cross(normal, rng.normal(size=(n, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    rot = np.stack([tangent, np.cross(normal, tangent), normal], axis=2)
    spacing = np.sqrt(4 * np.pi / n_surface)
    tangential = 0.7 * spacing * np.exp(rng.normal(0.0, 0.4, (n, 2)))
    scales = np.concatenate([tangential, 0.2 * tangential[:, :1]], axis=1)
    scales[n_surface:] = 2.0 * spacing * np.exp(rng.normal(0.0, 0.3, (n - n_surface, 3)))
    opacity_logits = rng.normal(1.5, 2.0, n)
    rgb = 0.5 + 0.35 * np.sin(3 * means + rng.normal(0, 0.3, (n, 3)))
    sh = np.zeros((n, 16, 3), np.float32)
    sh[:, 0] = rgb_to_sh(rgb)
    sh[:, 1:] = rng.normal(0.0, 0.05, (n, 15, 3))
    gaussians = Gaussians(means, matrix_to_quaternion(rot), np.log(scales), opacity_logits, sh)
    camera = Camera.from_fov(SIZE, SIZE, 50.0, make_transform(np.eye(3), [0.0, 0.0, 2.8]))
    return gaussians, camera


def time_stages(gaussians: Gaussians, camera: Camera, runs: int) -> dict[str, float]:
    """Median seconds per frame (wall, and CPU summed over threads) and per stage (wall)
    over ``runs`` renders after a warm-up."""
    render(gaussians, camera)
    background = np.ones(3, np.float32)
    totals, stages = [], {}

    def lap(stage: str) -> None:
        nonlocal last
        now = time.perf_counter()
        stages.setdefault(stage, []).append(now - last)
        last = now

    cpu = []
    for _ in range(runs):
        cpu_start = time.process_time()
        start = last = time.perf_counter()
        _rasterize(gaussians, camera, background, lap)
        totals.append(time.perf_counter() - start)
        cpu.append(time.process_time() - cpu_start)
    out = {"total": statistics.median(totals), "best": min(totals), "cpu": statistics.median(cpu)}
    out.update({k: statistics.median(v) for k, v in stages.items()})
    return out


def cpu_name() -> str:
    """The CPU's model name (Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, str]:
    return {
        "CPU": cpu_name(),
        "cores (os.cpu_count)": str(os.cpu_count()),
        "threads (numba.get_num_threads, marionette.parallel)": str(numba.get_num_threads()),
        "numba / numpy / python": f"{numba.__version__} / {np.__version__} / {platform.python_version()}",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15, help="timed runs per scene (median reported)")
    parser.add_argument("--no-reference", action="store_true", help="skip timing the slow reference")
    args = parser.parse_args()

    rows = []
    for n in COUNTS:
        gaussians, camera = make_scene(n)
        fast = time_stages(gaussians, camera, args.runs)
        out = render(gaussians, camera)
        ref = psnr = None
        if not args.no_reference:
            t0 = time.perf_counter()
            ref_image, _, _ = render_reference(gaussians, camera)
            ref = time.perf_counter() - t0
            psnr = 10 * np.log10(1.0 / np.mean((out.image - ref_image) ** 2))
        rows.append((n, fast, ref, psnr, float(out.alpha.mean())))
        print(f"N={n}: {1 / fast['total']:.1f} fps ({1e3 * fast['total']:.1f} ms)"
              + (f", reference {ref:.1f} s, PSNR {psnr:.1f} dB" if ref else ""), flush=True)

    info = machine_info()
    info["load average during the run (1 min)"] = f"{os.getloadavg()[0]:.2f}"
    lines = [
        "# Rasterizer benchmark",
        "",
        f"Produced by `python benchmarks/bench_rasterizer.py --runs {args.runs}`: "
        f"{SIZE}×{SIZE} image, a synthetic 3DGS-like object (see the script's docstring; SH degree 3), "
        f"median of {args.runs} renders after one warm-up render. The reference "
        "(`tests/reference_rasterizer.py`, NumPy, vectorised per Gaussian) is timed once on the "
        "same full scene: no extrapolation.",
        "",
        "| Gaussians | coverage | ms / frame | fps | best ms | CPU ms / frame "
        "| preprocess | sort | bin | blend | reference s | speed-up | PSNR vs reference |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n, f, ref, psnr, coverage in rows:
        ref_cells = f"{ref:.1f} | {ref / f['total']:.0f}× | {psnr:.0f} dB" if ref else "– | – | –"
        lines.append(
            f"| {n:,} | {coverage:.2f} | {1e3 * f['total']:.1f} | {1 / f['total']:.1f} "
            f"| {1e3 * f['best']:.1f} | {1e3 * f['cpu']:.1f} | {1e3 * f['preprocess']:.1f} "
            f"| {1e3 * f['sort']:.1f} | {1e3 * f['bin']:.1f} | {1e3 * f['blend']:.1f} | {ref_cells} |")
    lines += [
        "",
        "Coverage: mean alpha of the image. ms / frame and fps: medians; best ms: the fastest "
        "render. Stage columns: median wall milliseconds "
        "(sort includes gathering the tables in depth order). CPU ms / frame sums both threads; "
        "wall figures depend on what else the machine runs (load average below). Speed-up: "
        "reference seconds over the median frame time. PSNR compares the two images of the full "
        "scene.",
    ]
    write_page("rasterizer.md", lines, info)


def write_page(name: str, lines: list[str], info: dict[str, str]) -> None:
    """``lines`` and the machine table ``info`` → ``docs/benchmarks/<name>`` and stdout."""
    lines = lines + ["", "| machine | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in info.items()]
    text = "\n".join(lines) + "\n"
    doc = ROOT / "docs" / "benchmarks" / name
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
