"""Run every benchmark, then assemble ``docs/RESULTS.md``: a short summary of their pages.

Each ``benchmarks/bench_*.py`` script (and ``paper_setting.py``) runs in its
own process, in a fixed order; the ones that need ``../shared/data`` are
skipped when it is absent, and a failing script does not stop the others.
Each writes its page under ``docs/benchmarks/``; :func:`assemble` then
writes the summary: the headline tables (the paper's Table 1, pose accuracy,
speed) taken from their pages, with plots, and one line and a link for every
page in ``docs/benchmarks/``. The detail stays on the pages.

    python benchmarks/run_all.py [--quick] [--only NAME,...] [--assemble-only]

``--quick`` runs small versions (a smoke test, minutes instead of an hour);
they overwrite the pages like a full run, so re-run without it for figures
worth keeping. ``--assemble-only`` runs nothing and rebuilds the summary.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH_DIR = ROOT / "docs" / "benchmarks"
RESULTS = ROOT / "docs" / "RESULTS.md"
IMAGES = ROOT / "docs" / "images" / "results"
DATA = ROOT.parent / "shared" / "data"


@dataclass(frozen=True)
class Bench:
    """One benchmark script: its page, whether it needs the real data, its arguments for ``--quick``."""

    script: str
    page: str
    needs_data: bool = False
    quick: tuple[str, ...] = ()


#: In running order.
BENCHES = (
    Bench("bench_table1.py", "table1.md", needs_data=True, quick=("--clips", "car-shadow")),
    Bench("bench_iterations.py", "iterations.md", needs_data=True, quick=("--iterations", "600")),
    Bench("bench_hard_clips.py", "hard_clips.md", needs_data=True, quick=("--clips", "drift-turn")),
    Bench("bench_joint_fit.py", "joint_fit.md", quick=("--seeds", "1", "--extract-seeds", "1", "--size", "160x120")),
    Bench("bench_extract.py", "extract.md", quick=("--seeds", "1", "--frames", "24", "--size", "160x120",
                                                   "--large", "0")),
    Bench("bench_tracks.py", "tracks.md", quick=("--seeds", "1", "--frames", "24", "--size", "160x120",
                                                 "--noise", "0")),
    Bench("bench_focal.py", "focal.md", quick=("--seeds", "1", "--frames", "24", "--size", "160x120")),
    Bench("bench_parts.py", "parts.md", quick=("--seeds", "1", "--frames", "24", "--size", "160x120")),
    Bench("bench_articulated.py", "articulated.md", quick=("--scenes", "4")),
    Bench("bench_extract_real.py", "extract_real.md", needs_data=True, quick=("--runs", "1")),
    Bench("bench_reproducibility_real.py", "reproducibility_real.md", needs_data=True),
    Bench("bench_foreground.py", "foreground.md", needs_data=True),
    Bench("bench_rasterizer.py", "rasterizer.md", quick=("--runs", "3", "--no-reference")),
    Bench("bench_mesh_target.py", "mesh_target.md", quick=("--runs", "1")),
    Bench("bench_unseen_sides.py", "unseen_sides.md", quick=("--seeds", "1", "--runs", "1")),
    Bench("bench_transfer.py", "transfer.md", quick=("--runs", "1", "--gaussians", "50000")),
    Bench("bench_ablation.py", "ablation.md", needs_data=True),
    Bench("paper_setting.py", "paper_setting.md", quick=("--runs", "1")),
    Bench("bench_memory.py", "memory.md", quick=("--frames", "100", "--cache", "/tmp/marionette-bench-memory-quick")),
    Bench("bench_scaling.py", "scaling.md", quick=("--quick",)),
)

#: The summary's headline tables: title, what it shows, page, columns that find its table, columns shown.
HEADLINES = (
    ("Table 1: self-transfer on the real clips, paper vs ours",
     "The paper's protocol (Sec. 5.2, `marionette eval-self`): the source object (*reconstruction*: fitted to"
     " every frame; *held-out*: to the even frames, scored on the odd ones; *frame0*: source frame 0 lifted"
     " alone, the paper's setting) moved by the extracted prior and rendered with the source camera, against"
     " the masked source frames on white. *Masked PSNR* scores the object's pixels only.",
     "table1.md", ("clip", "paper SpaT PSNR / SSIM / LPIPS"),
     ("category", "clip", "target", "PSNR (dB)", "masked PSNR (dB)", "SSIM", "LPIPS",
      "paper SpaT PSNR / SSIM / LPIPS")),
    ("Pose accuracy on synthetic scenes",
     "Median errors against exact ground truth over 3 seeds, per motion, without and with 1 px of noise on"
     " the tracks; the centroid error is mostly the frame-0 centre's (*true centre*: the poses' own share).",
     "extract.md", ("motion", "noise (px)", "median rotation (deg)"),
     ("motion", "noise (px)", "median rotation (deg)", "median centroid (% radius)",
      "median true centre (% radius)")),
    ("Speed in the paper's setting",
     "`marionette run` on 50 frames of car-turn (854x480) and a 512x512 photo, on two CPU cores, next to the"
     " paper's Table 2 on an RTX A6000.",
     "paper_setting.md", ("paper, RTX A6000", "ours, CPU"), None),
    ("Rasterizer throughput",
     "Median frame time of the CPU rasterizer at 512x512 against the Gaussian count.",
     "rasterizer.md", ("Gaussians", "fps"), ("Gaussians", "ms / frame", "fps")),
)

#: The summary's list of pages: group title, pages in order. A page in no group is listed under "More".
GROUPS = (
    ("Quality against the paper", ("table1.md", "hard_clips.md", "iterations.md", "coarse_to_fine.md", "ssim_loss.md",
                                   "reconstruct.md", "align.md", "align_real.md")),
    ("Motion extraction", ("extract.md", "joint_fit.md", "tracks.md", "parts.md", "focal.md", "bundle.md", "recover.md",
                           "lid_information.md", "lid_relief.md", "extract_real.md", "foreground.md", "prompt.md",
                           "reproducibility_real.md")),
    ("The target, the transfer and the scene", ("lift.md", "mesh_target.md", "scene.md", "ablation.md",
                                                 "transfer.md")),
    ("Speed and memory", ("paper_setting.md", "rasterizer.md", "rasterizer_grad.md", "scaling.md", "memory.md",
                          "first_run.md", "suite.md", "app.md")),
)


def machine() -> dict[str, str]:
    """CPU model and count, Python, OS."""
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"CPU": cpu, "cores": str(os.cpu_count()), "Python": platform.python_version(),
            "OS": f"{platform.system()} {platform.release()}"}


def markdown_tables(text: str) -> list[list[list[str]]]:
    """Every pipe table in ``text`` as a list of rows of cells (header first, the ``|---|`` rule dropped)."""
    tables, rows = [], []
    for line in text.splitlines() + [""]:
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                rows.append(cells)
        elif rows:
            tables.append(rows)
            rows = []
    return tables


def _save(fig, title: str, path: Path) -> None:
    """Title a summary figure and write it to ``path`` as PNG."""
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


#: Issue 3's targets without and with 1 px of track noise: rotation (deg), centroid (% radius).
POSE_TARGETS = {"rotation": (0.5, 1.0), "centroid": (1.0, 2.0)}


def pose_accuracy_panels(text: str) -> list[tuple[str, dict[str, dict[str, float]]]]:
    """Panels of the pose accuracy plot from ``extract.md``'s text: (y label, {noise: {motion: value}}) for the
    rotation error, the rotation error on exact tracks (when the page has that table) and the centroid error."""
    tables = markdown_tables(text)
    wanted = [("median rotation (deg)", "rotation error (deg)"),
              ("rotation, exact tracks (deg)", "rotation error, exact tracks (deg)"),
              ("median centroid (% radius)", "centroid error (% radius)")]
    panels = []
    for column, label in wanted:
        table = next((t for t in tables if column in t[0]), None)
        if table is None:
            continue
        col = {name: i for i, name in enumerate(table[0])}
        series: dict[str, dict[str, float]] = {}
        for row in table[1:]:
            series.setdefault(row[col["noise (px)"]], {})[row[col["motion"]]] = float(row[col[column]])
        panels.append((label, series))
    return panels


def plot_pose_accuracy(page: Path, path: Path) -> bool:
    """Bars of the median rotation (on the tracker's and on exact tracks) and centroid errors per motion and
    noise level, from the tables of ``extract.md``; False (nothing written) when the page has no summary table."""
    from matplotlib.figure import Figure

    panels = pose_accuracy_panels(page.read_text())
    if not panels or panels[0][0] != "rotation error (deg)":
        return False
    fig = Figure(figsize=(4.5 * len(panels), 3.6), dpi=100)
    axes = fig.subplots(1, len(panels))
    for ax, (label, series) in zip(axes, panels):
        motions = list(dict.fromkeys(m for values in series.values() for m in values))
        width = 0.8 / len(series)
        for j, (noise, values) in enumerate(series.items()):
            ax.bar([i + (j - (len(series) - 1) / 2) * width for i in range(len(motions))],
                   [values[m] for m in motions], width, label=f"track noise {noise} px")
        for target, noise in zip(POSE_TARGETS["centroid" if "centroid" in label else "rotation"], series):
            ax.axhline(target, color="0.3", linestyle="--", linewidth=0.8)
            ax.annotate(f"target, {noise} px", (len(motions) - 0.5, target), fontsize=7, color="0.3",
                        ha="right", va="bottom")
        ax.set_xticks(range(len(motions)), motions, fontsize=8)
        ax.set_ylabel(label)
        ax.grid(True, axis="y", alpha=0.3)
        ax.margins(y=0.25)  # room for the legend above the bars
        ax.legend(fontsize=8, loc="upper left")
    if len(panels) == 3:  # the two rotation panels on one scale, so the tracker's share reads off directly
        axes[1].sharey(axes[0])
        axes[0].autoscale()
    _save(fig, "Pose accuracy on the synthetic suite (median over seeds)", path)
    return True


def table1_series(text: str) -> tuple[list[str], dict[str, list[float]], dict[str, dict[str, list[float]]]] | None:
    """The bars of the Table 1 plot from ``table1.md``'s text: clips, the paper's (PSNR, SSIM, LPIPS) per clip,
    and ours per target (the ``target`` column's values in order; ``ours`` when the table has none) per clip.
    Only clips with a paper row; a target missing for a clip, or an LPIPS that is not a number, is NaN. None
    when the page has no such table."""
    paper_column = "paper SpaT PSNR / SSIM / LPIPS"
    table = next((t for t in markdown_tables(text) if {"PSNR (dB)", "SSIM", paper_column} <= set(t[0])), None)
    if table is None:
        return None
    col = {name: i for i, name in enumerate(table[0])}
    rows = [row for row in table[1:] if re.fullmatch(r"[\d.]+ / [\d.]+ / .*", row[col[paper_column]])]
    if not rows:
        return None

    def number(cell: str) -> float:
        return float(cell) if re.fullmatch(r"[\d.]+", cell) else float("nan")

    clip_of = (lambda row: row[col["clip"]]) if "clip" in col else (lambda row: row[0])
    clips = list(dict.fromkeys(clip_of(row) for row in rows))
    paper = {clip_of(row): [number(v) for v in row[col[paper_column]].split(" / ")] for row in rows}
    targets = list(dict.fromkeys(row[col["target"]] for row in rows)) if "target" in col else ["ours"]
    ours = {t: {c: [float("nan")] * 3 for c in clips} for t in targets}
    for row in rows:
        target = row[col["target"]] if "target" in col else "ours"
        lpips = number(row[col["LPIPS"]]) if "LPIPS" in col else float("nan")
        ours[target][clip_of(row)] = [float(row[col["PSNR (dB)"]]), float(row[col["SSIM"]]), lpips]
    return clips, paper, ours


def plot_table1(page: Path, path: Path) -> bool:
    """Bars of PSNR, SSIM (and LPIPS where computed), the paper's and ours (one bar per target when the table
    has a ``target`` column), per clip, from the table of ``table1.md`` (columns ``PSNR (dB)``, ``SSIM``,
    ``LPIPS`` and ``paper SpaT PSNR / SSIM / LPIPS``); False when it has none."""
    import math

    from matplotlib.figure import Figure

    series = table1_series(page.read_text())
    if series is None:
        return False
    clips, paper, ours = series
    panels = [("PSNR (dB)", 0, "higher"), ("SSIM", 1, "higher")]
    if any(not math.isnan(v[2]) for values in ours.values() for v in values.values()):
        panels.append(("LPIPS", 2, "lower"))
    colours = ["#3b75af", "#e08a2c", "#5aa05a", "#9467bd"]
    width = 0.8 / (1 + len(ours))
    fig = Figure(figsize=(max(4.5, 1.5 + 0.3 * len(clips) * (1 + len(ours))) * len(panels), 3.8), dpi=100)
    for ax, (metric, index, better) in zip(fig.subplots(1, len(panels)), panels):
        heights = [("paper (SpaT prior)", [paper[c][index] for c in clips], "#bbbbbb")]
        heights += [(f"ours, {t}" if t != "ours" else "ours", [ours[t][c][index] for c in clips],
                     colours[j % len(colours)]) for j, t in enumerate(ours)]
        for j, (label, values, colour) in enumerate(heights):
            offset = (j - (len(heights) - 1) / 2) * width
            ax.bar([i + offset for i in range(len(clips))], values, width, label=label, color=colour)
        top = max(v for _, values, _ in heights for v in values if not math.isnan(v))
        ax.set_xticks(list(range(len(clips))), clips, fontsize=8)
        ax.set_ylim(0, 1.4 * top)  # room for the legend
        ax.set_ylabel(f"{metric}, {better} is better")
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    _save(fig, "Table 1: self-transfer on the real clips, paper vs ours", path)
    return True


def markdown_table(rows: list[list[str]]) -> list[str]:
    """Rows of cells (header first) → the lines of a pipe table."""
    return [f"| {' | '.join(rows[0])} |", "|" + "---|" * len(rows[0]), *[f"| {' | '.join(r)} |" for r in rows[1:]]]


def headline_table(text: str, find: tuple[str, ...], show: tuple[str, ...] | None) -> list[str] | None:
    """The first table of ``text`` whose header has the ``find`` columns, cut to the ``show`` columns (None:
    all), as pipe-table lines; None when the page has no such table."""
    table = next((t for t in markdown_tables(text) if set(find) <= set(t[0])), None)
    if table is None:
        return None
    keep = [table[0].index(c) for c in show if c in table[0]] if show else range(len(table[0]))
    return markdown_table([[row[i] if i < len(row) else "" for i in keep] for row in table])


def page_title(path: Path) -> str:
    """A page's first ``# `` heading, else its file name."""
    first = path.read_text().lstrip().partition("\n")[0]
    return first[2:].strip() if first.startswith("# ") else path.name


def assemble(bench_dir: Path, out: Path, images: Path, *, info: dict[str, str], date: str,
             skipped: dict[str, str] | None = None) -> str:
    """Write ``out`` (RESULTS.md), a summary of the pages in ``bench_dir``, and its plots to ``images``; its text.

    Parameters
    ----------
    bench_dir : Path
        Folder of the benchmark pages (``table1.md``, ``extract.md``, …); every ``*.md`` in it is linked.
    out : Path
        The summary to write; links are relative to it.
    images : Path
        Folder for the plots drawn from the pages' tables.
    info : dict
        Machine description (name → value), shown as a table.
    date : str
        When the summary was assembled.
    skipped : dict, optional
        Script → reason, for scripts skipped or failed in this run.
    """
    skipped = skipped or {}
    bench_dir, out, images = bench_dir.resolve(), out.resolve(), images.resolve()
    pages = sorted(p.name for p in bench_dir.glob("*.md"))
    script_of = {b.page: b.script for b in BENCHES}
    missing = [b.page for b in BENCHES if b.page not in pages]

    def link(page: str) -> str:
        return os.path.relpath(bench_dir / page, out.parent)

    lines = ["# Results", "",
             f"A summary of the benchmark pages in `docs/benchmarks/`, assembled by `python benchmarks/run_all.py"
             f" --assemble-only` on {date}: the headline tables, then one line and a link per page. Every page"
             " starts with the command that reproduces it; wall times come from a shared machine and vary from"
             " run to run.", "",
             "| machine | |", "|---|---|", *[f"| {k} | {v} |" for k, v in info.items()], ""]
    stale = [script for script in skipped if script not in (script_of[page] for page in missing)]
    if missing or stale:
        lines += ["Not run:", ""]
        lines += [f"- `{page}` (`benchmarks/{script_of[page]}`): {skipped.get(script_of[page], 'no page yet')}"
                  for page in missing]
        lines += [f"- `benchmarks/{script}`: {skipped[script]}; its page is from an earlier run" for script in stale]
        lines.append("")
    plots = {}  # page → a plot drawn from its table
    for page, draw, name in (("table1.md", plot_table1, "table1.png"),
                             ("extract.md", plot_pose_accuracy, "pose_accuracy.png")):
        if page in pages and draw(bench_dir / page, images / name):
            plots[page] = images / name
    for title, summary, page, find, show in HEADLINES:
        lines += [f"## {title}", ""]
        table = headline_table((bench_dir / page).read_text(), find, show) if page in pages else None
        if table is None:
            lines += [f"_Not run: `{page}` is missing or has no such table"
                      f" (`python benchmarks/{script_of.get(page, page)}`)._", ""]
            continue
        lines += [summary, ""]
        if page in plots:
            lines += [f"![{title}]({os.path.relpath(plots[page], out.parent)})", ""]
        lines += [*table, "", f"Details: [`{page}`]({link(page)}).", ""]
    lines += ["## Every benchmark page", ""]
    grouped = {page for _, group in GROUPS for page in group}
    for title, group in (*GROUPS, ("More", tuple(p for p in pages if p not in grouped))):
        listed = [page for page in group if page in pages]
        if listed:
            lines += [f"**{title}**", ""]
            lines += [f"- [`{page}`]({link(page)}): {page_title(bench_dir / page)}" for page in listed]
            lines.append("")
    text = "\n".join(lines).rstrip() + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return text


def run_benches(benches: list[Bench], quick: bool) -> dict[str, str]:
    """Run the scripts in turn; script → reason for those skipped or failed."""
    skipped = {}
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    for bench in benches:
        script = ROOT / "benchmarks" / bench.script
        if not script.is_file():
            skipped[bench.script] = "script not found"
        elif bench.needs_data and not DATA.is_dir():
            skipped[bench.script] = f"needs the real data in {DATA}"
        else:
            command = [sys.executable, str(script), *(bench.quick if quick else ())]
            print(f"== {' '.join(command[1:])}", flush=True)
            start = time.perf_counter()
            code = subprocess.call(command, cwd=ROOT, env=env)
            print(f"== {bench.script}: exit {code} after {time.perf_counter() - start:.0f} s", flush=True)
            if code != 0:
                skipped[bench.script] = f"failed (exit code {code})"
            continue
        print(f"== {bench.script}: skipped, {skipped[bench.script]}", flush=True)
    return skipped


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small, fast versions of every benchmark")
    parser.add_argument("--only", help="comma-separated script names (without .py) to run")
    parser.add_argument("--assemble-only", action="store_true", help="run nothing; rebuild RESULTS.md from the pages")
    args = parser.parse_args()
    benches = list(BENCHES)
    if args.only:
        names = set(args.only.split(","))
        unknown = names - {b.script[:-3] for b in BENCHES}
        if unknown:
            parser.error(f"unknown benchmark(s): {', '.join(sorted(unknown))}")
        benches = [b for b in BENCHES if b.script[:-3] in names]
    skipped = {} if args.assemble_only else run_benches(benches, args.quick)
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    assemble(BENCH_DIR, RESULTS, IMAGES, info=machine(), date=date, skipped=skipped)
    print(f"wrote {RESULTS}" + (f"; skipped or failed: {', '.join(skipped)}" if skipped else ""))


if __name__ == "__main__":
    main()
