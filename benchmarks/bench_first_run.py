"""The first run after installing: `marionette demo` on an empty numba cache, then on the cache it filled.

    python benchmarks/bench_first_run.py [--runs 3]

Each run gives numba an empty cache folder (NUMBA_CACHE_DIR), as a fresh
install has, and times ``marionette demo`` twice in fresh processes: the first
compiles the kernels, the second reads them. Then ``marionette --help`` (the
start-up: imports only). Medians go to ``docs/benchmarks/first_run.md``. Run
nothing else meanwhile.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_rasterizer import cpu_name  # noqa: E402

PAGE = ROOT / "docs" / "benchmarks" / "first_run.md"
MARIONETTE = [sys.executable, "-m", "marionette"]


def timed(args: list[str], env: dict[str, str]) -> float:
    """Wall seconds of one command in a fresh process (it must succeed)."""
    start = time.perf_counter()
    subprocess.run(args, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def one_run() -> dict[str, float]:
    """Seconds of the demo on an empty numba cache, again on the filled one, and of ``--help``."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba")}
        out = Path(tmp) / "demo"
        first = timed([*MARIONETTE, "demo", "-o", str(out), "-q"], env)
        shutil.rmtree(out)
        again = timed([*MARIONETTE, "demo", "-o", str(out), "-q"], env)
        start_up = timed([*MARIONETTE, "--help"], env)
    return {"first": first, "again": again, "help": start_up}


#: (command, numba cache, key of one_run's result, decimals) of each row.
ROWS = [("`marionette demo`", "empty (first run)", "first", 1), ("`marionette demo`", "filled", "again", 1),
        ("`marionette --help`", "filled", "help", 2)]


def write_page(runs: list[dict[str, float]]) -> str:
    """The page's markdown: the medians of the runs, and each run."""
    lines = [
        "# The first run after installing", "",
        f"`python benchmarks/bench_first_run.py --runs {len(runs)}` on {platform.machine()}, {os.cpu_count()} cores "
        f"({cpu_name()}), Python {platform.python_version()}. `marionette demo` in a fresh process on an empty "
        "numba cache (as a fresh install has: it compiles the rasterizer's, the tracker's and the part fits' "
        "kernels), then again on the cache it filled; then `marionette --help` (start-up and imports). Medians "
        f"of {len(runs)} runs, each on its own empty cache.", "",
        "| command | numba cache | seconds (median) | runs |", "|---|---|---:|---|"]
    for command, cache, key, digits in ROWS:
        lines.append(f"| {command} | {cache} | {statistics.median(r[key] for r in runs):.{digits}f} | "
                     + ", ".join(f"{r[key]:.{digits}f}" for r in runs) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs (each on its own empty cache)")
    args = parser.parse_args()
    runs = []
    for i in range(args.runs):
        runs.append(one_run())
        print(f"run {i + 1}: " + ", ".join(f"{k} {v:.1f} s" for k, v in runs[-1].items()), flush=True)
    page = write_page(runs)
    PAGE.write_text(page)
    print(page)


if __name__ == "__main__":
    main()
