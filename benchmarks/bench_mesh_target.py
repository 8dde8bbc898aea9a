"""Time to load a textured mesh as the target: a textured sphere of about 200,000 faces (.glb and .obj) into surfels.

``pipeline.load_target`` on the file: reading it with trimesh, sampling 60,000 surfels by area, their texture
colours and the front camera; median of ``--runs`` runs after one warm-up. Writes
``docs/benchmarks/mesh_target.md``.

    python benchmarks/bench_mesh_target.py [--runs 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks" / "mesh_target.md"


def textured_sphere(rows: int = 224):
    """A UV sphere of about 4 x rows² faces with a 1024² noise texture on spherical coordinates."""
    import trimesh
    from PIL import Image

    sphere = trimesh.creation.uv_sphere(count=[rows, rows])
    v = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    uv = np.stack([0.5 + np.arctan2(v[:, 0], v[:, 2]) / (2 * np.pi), 0.5 + np.arcsin(np.clip(v[:, 1], -1, 1)) / np.pi],
                  axis=1)
    texture = (np.random.default_rng(0).random((1024, 1024, 3)) * 255).astype(np.uint8)
    sphere.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(texture))
    return sphere


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    from marionette import pipeline

    sphere = textured_sphere()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".glb", ".obj"):
            path = Path(tmp) / f"sphere{suffix}"
            sphere.export(path)
            pipeline.load_target(path)  # warm-up: imports, caches
            seconds = []
            for _ in range(args.runs):
                start = time.perf_counter()
                lifted = pipeline.load_target(path)
                seconds.append(time.perf_counter() - start)
            rows.append((suffix, len(sphere.faces), path.stat().st_size, len(lifted.gaussians), seconds))
    lines = ["# A textured mesh as the target: load time", "",
             f"`python benchmarks/bench_mesh_target.py` on {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}: `pipeline.load_target` on a UV sphere with a 1024² texture (trimesh "
             f"reads it, 60,000 surfels sampled by area and coloured from the texture, the front camera); median of "
             f"{args.runs} runs after a warm-up. Target (issue 53): a 100k-face mesh in ≤ 3 s.", "",
             "| file | faces | size (MB) | surfels | load (s, median) | runs (s) |", "|---|---:|---:|---:|---:|---|"]
    for suffix, faces, size, count, seconds in rows:
        lines.append(f"| {suffix} | {faces} | {size / 1e6:.1f} | {count} | {statistics.median(seconds):.2f} "
                     f"| {', '.join(f'{s:.2f}' for s in seconds)} |")
    DOC.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(DOC.read_text())


if __name__ == "__main__":
    main()
