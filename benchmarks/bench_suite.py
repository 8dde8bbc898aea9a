"""The test suite as a new user gets it, under the OpenCV releases and BLAS kernels it must not depend on.

Run from the root of a clean clone (the suite runs against the working tree)::

    python benchmarks/bench_suite.py [--opencv 5.1.0.95,5.0.0.93,4.14.0.94] [--coretype Haswell] [--skip-suite]

For each OpenCV release, a fresh virtual environment gets the README's
``pip install -e ".[test]"`` with that release pinned over the default, and
the README's ``pytest -q`` runs in it twice: with ``OPENBLAS_CORETYPE`` unset
and set (to ``--coretype``). numba's cache starts empty, as on a fresh clone:
the first run compiles the kernels, the second reads them. Then the determinism table (issue 14): the same
``extract --parts auto`` of a one-part turn and of the synthetic hinge under 1
and 2 threads and three OpenBLAS kernels (the machine's own, Haswell,
Sandybridge), compared with the first. Figures go to
``docs/benchmarks/suite.md`` and stdout. Several minutes per suite run: run
nothing else meanwhile.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_rasterizer import cpu_name  # noqa: E402

PAGE = ROOT / "docs" / "benchmarks" / "suite.md"
SUMMARY = re.compile(r"^=*\s*(\d+ (?:passed|failed).*) in ([\d.]+)s", re.M)

ONE_THREAD = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
#: (label, environment) of each determinism run; the first is the reference.
CONFIGS = [("2 threads, own kernel", {}), ("1 thread, own kernel", ONE_THREAD),
           ("2 threads, Haswell", {"OPENBLAS_CORETYPE": "Haswell"}),
           ("1 thread, Haswell", {**ONE_THREAD, "OPENBLAS_CORETYPE": "Haswell"}),
           ("2 threads, Sandybridge", {"OPENBLAS_CORETYPE": "Sandybridge"}),
           ("1 thread, Sandybridge", {**ONE_THREAD, "OPENBLAS_CORETYPE": "Sandybridge"})]
#: (motion, frames, size) as test_determinism uses them.
MOTIONS = [("outofplane", 16, (160, 120)), ("hinge", 20, (200, 150))]


def run_suite(opencv: str, coretype: str) -> list[dict]:
    """Install into a fresh venv with ``opencv`` pinned; run pytest with OPENBLAS_CORETYPE unset (on an empty
    numba cache), then set (on the cache the first run filled)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        py = str(venv / "bin" / "python")
        pip = [py, "-m", "pip", "install", "-q"]
        subprocess.run([*pip, "-e", ".[test]"], cwd=ROOT, check=True)
        subprocess.run([*pip, f"opencv-contrib-python-headless=={opencv}"], cwd=ROOT, check=True)
        versions = subprocess.run([py, "-c", "import cv2, numpy, scipy, numba; print(cv2.__version__, "
                                   "numpy.__version__, scipy.__version__, numba.__version__)"],
                                  capture_output=True, text=True, check=True).stdout.split()
        for core, cache in (("", "cold"), (coretype, "warm")):
            env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
            env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "numba-cache")
            if core:
                env["OPENBLAS_CORETYPE"] = core
            print(f"OpenCV {versions[0]}, OPENBLAS_CORETYPE={core or 'unset'}, {cache} numba cache: pytest -q ...",
                  flush=True)
            t0 = time.perf_counter()
            proc = subprocess.run([py, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=ROOT, env=env,
                                  capture_output=True, text=True)
            wall = time.perf_counter() - t0
            found = SUMMARY.findall(proc.stdout)
            failed = re.findall(r"^FAILED (\S+)", proc.stdout, re.M)
            rows.append({"opencv": versions[0], "numpy": versions[1], "scipy": versions[2], "numba": versions[3],
                         "coretype": core or "unset", "cache": cache, "exit": proc.returncode,
                         "result": found[-1][0] if found else proc.stdout[-300:].strip(),
                         "pytest_s": float(found[-1][1]) if found else None, "wall_s": wall, "failed": failed})
            print(f"  {rows[-1]['result']} ({wall:.0f} s)", flush=True)
    return rows


def determinism(work: Path) -> list[dict]:
    """``extract --parts auto`` under every configuration of CONFIGS, for each motion of MOTIONS."""
    from marionette.geometry import rotation_angle_deg
    from marionette.io import write_video
    from marionette.synthetic import make_scene

    rows = []
    for motion, frames, size in MOTIONS:
        scene = make_scene(motion, seed=0, num_frames=frames, size=size)
        clip = work / motion
        clip.mkdir()
        write_video(clip / "frames", scene.frames, scene.fps)
        (clip / "masks").mkdir()
        for i, m in enumerate(scene.masks):
            cv2.imwrite(str(clip / "masks" / f"{i:05d}.png"), m.astype(np.uint8) * 255)
        reference = None
        for label, extra in CONFIGS:
            out = clip / f"{len(rows)}.npz"
            env = {**{k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}, **extra}
            subprocess.run([sys.executable, "-m", "marionette.cli", "extract", str(clip / "frames"), "--masks",
                            str(clip / "masks"), "--parts", "auto", "-o", str(out), "-q"], env=env, check=True)
            with np.load(out) as f:
                poses, meta = f["poses"], json.loads(f["metadata"].item())
            if reference is None:
                reference = poses
            # the part that turns most is the hinge's lid; the rest must agree to 0.05° (test_determinism)
            turn = [float(rotation_angle_deg(poses[k, :, :3, :3]).max()) for k in range(poses.shape[0])]
            still = [k for k in range(poses.shape[0]) if k != int(np.argmax(turn))] if motion == "hinge" else None
            gaps = [float(rotation_angle_deg(np.swapaxes(reference[k, :, :3, :3], -1, -2) @ poses[k, :, :3, :3]).max())
                    if k < reference.shape[0] else float("nan") for k in range(poses.shape[0])]
            rows.append({"motion": motion, "config": label, "parts": meta["num_parts"],
                         "note": meta.get("part_selection_note", ""),
                         "gap": max(gaps) if still is None else max(gaps[k] for k in still),
                         "lid_gap": None if still is None else max(gaps)})
            print(f"{motion} {label}: {rows[-1]['parts']} parts, pose gap {rows[-1]['gap']:.4f}°", flush=True)
    return rows


def write_page(suite: list[dict], det: list[dict], coretype: str) -> str:
    lines = ["# The suite on a fresh install, and determinism", "",
             f"`python benchmarks/bench_suite.py` on {platform.machine()}, {os.cpu_count()} cores "
             f"({cpu_name()}), Python {platform.python_version()}. Each OpenCV "
             "release in a fresh virtual environment (the README's `pip install -e \".[test]\"`, that release "
             f"pinned over it); the README's `pytest -q` with `OPENBLAS_CORETYPE` unset and set to {coretype}, the "
             "first on an empty numba cache (as a fresh clone has: it compiles the kernels), the second on the "
             "cache the first filled.", ""]
    if suite:
        lines += ["| OpenCV | numpy / scipy / numba | OPENBLAS_CORETYPE | numba cache | result | pytest s | failed |",
                  "|---|---|---|---|---|---:|---|"]
        for r in suite:
            pytest_s = f"{r['pytest_s']:.0f}" if r["pytest_s"] is not None else "–"
            lines.append(f"| {r['opencv']} | {r['numpy']} / {r['scipy']} / {r['numba']} | {r['coretype']} | "
                         f"{r['cache']} | {r['result']} | {pytest_s} | {', '.join(r['failed']) or '–'} |")
        lines.append("")
    lines += ["Determinism: `extract --parts auto` (masks given) of the synthetic one-part turn (`outofplane`, 16 "
              "frames, 160x120) and hinge (20 frames, 200x150), each configuration in a fresh process, against the "
              "first. Pose gap: the largest rotation difference over frames and parts (for the hinge, its still "
              "body; the lid's, whose fit has several minima, is shown apart). The hinge's "
              "parts: its moving lid and the static group its still body forms (the note counts the moving "
              "ones).", "",
              "| motion | threads, BLAS kernel | parts | part_selection_note | pose gap (°) | lid gap (°) |",
              "|---|---|---:|---|---:|---:|"]
    for r in det:
        lid = "–" if r["lid_gap"] is None else f"{r['lid_gap']:.2f}"
        lines.append(f"| {r['motion']} | {r['config']} | {r['parts']} | {r['note']} | {r['gap']:.4f} | {lid} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--opencv", default="5.1.0.95,5.0.0.93,4.14.0.94", help="OpenCV releases, comma-separated")
    parser.add_argument("--coretype", default="Haswell", help="OPENBLAS_CORETYPE of the second run")
    parser.add_argument("--skip-suite", action="store_true", help="only the determinism table")
    args = parser.parse_args()
    suite = [] if args.skip_suite else [row for v in args.opencv.split(",") for row in run_suite(v, args.coretype)]
    with tempfile.TemporaryDirectory() as tmp:
        det = determinism(Path(tmp))
    page = write_page(suite, det, args.coretype)
    PAGE.write_text(page)
    print(page)


if __name__ == "__main__":
    main()
