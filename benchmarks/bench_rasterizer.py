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
from marionette.render.rasterizer import _bin, _blend, _depth_order, _preprocess

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
    """Median seconds of ``render`` and of its stages over ``runs`` runs, after a warm-up."""
    render(gaussians, camera)
    w, h = camera.width, camera.height
    bg = np.ones(3, np.float32)
    totals, stages = [], {"preprocess": [], "sort": [], "bin": [], "blend": []}
    for _ in range(runs):
        t0 = time.perf_counter()
        render(gaussians, camera)
        totals.append(time.perf_counter() - t0)
        # The same pipeline stage by stage, for the breakdown.
        t0 = time.perf_counter()
        params, boxes, depths, status = _preprocess(
            gaussians.means, gaussians.quats, gaussians.log_scales, gaussians.opacity_logits,
            gaussians.sh, camera.world_to_camera, camera.K, camera.center, w, h)
        t1 = time.perf_counter()
        order = _depth_order(depths, status)
        t2 = time.perf_counter()
        tile_start, tile_ids = _bin(order, boxes, w, h, 8)
        t3 = time.perf_counter()
        previous = numba.set_parallel_chunksize(1)
        _blend(tile_start, tile_ids, params, boxes, w, h, bg)
        numba.set_parallel_chunksize(previous)
        t4 = time.perf_counter()
        for key, dt in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            stages[key].append(dt)
    out = {"total": statistics.median(totals)}
    out.update({k: statistics.median(v) for k, v in stages.items()})
    out["visible"] = int((status == 1).sum())
    out["pairs"] = int(tile_ids.size)
    return out


def machine_info() -> dict[str, str]:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "CPU": cpu,
        "cores (os.cpu_count)": str(os.cpu_count()),
        "numba threads": str(numba.get_num_threads()),
        "numba threading layer": numba.threading_layer(),
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
        ref = None
        if not args.no_reference:
            t0 = time.perf_counter()
            render_reference(gaussians, camera)
            ref = time.perf_counter() - t0
        coverage = float(render(gaussians, camera).alpha.mean())
        rows.append((n, fast, ref, coverage))
        print(f"N={n}: {1 / fast['total']:.1f} fps ({1e3 * fast['total']:.1f} ms)"
              + (f", reference {ref:.1f} s" if ref else ""), flush=True)

    info = machine_info()
    lines = [
        "# Rasterizer benchmark",
        "",
        f"Produced by `python benchmarks/bench_rasterizer.py --runs {args.runs}`: "
        f"{SIZE}×{SIZE} image, a synthetic 3DGS-like object (see the script's docstring; SH degree 3), "
        f"median of {args.runs} runs after one warm-up render. The reference "
        "(`tests/reference_rasterizer.py`, NumPy, vectorised per Gaussian) is timed once on the "
        "same full scene, no extrapolation.",
        "",
        "| Gaussians | visible | tile pairs | coverage | ms / frame | fps "
        "| preprocess ms | sort ms | bin ms | blend ms | reference s | speed-up |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n, f, ref, coverage in rows:
        ref_cells = f"{ref:.1f} | {ref / f['total']:.0f}×" if ref else "– | –"
        lines.append(
            f"| {n:,} | {f['visible']:,} | {f['pairs']:,} | {coverage:.2f} | {1e3 * f['total']:.1f} "
            f"| {1 / f['total']:.1f} | {1e3 * f['preprocess']:.1f} | {1e3 * f['sort']:.1f} "
            f"| {1e3 * f['bin']:.1f} | {1e3 * f['blend']:.1f} | {ref_cells} |")
    lines += ["", "Coverage is the mean alpha of the image. Stage times are medians of separate "
              "stage-by-stage runs, so they need not sum exactly to the total.", "",
              "| machine | |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in info.items()]
    text = "\n".join(lines) + "\n"
    out = ROOT / "docs" / "benchmarks" / "rasterizer.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
