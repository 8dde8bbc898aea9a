"""How time grows: against source frames, against target Gaussians, and rasterizer throughput.

(a) Extraction against source frames: a synthetic 854x480 out-of-plane turn
of 50, 200 and 800 frames (written once to /tmp as MP4 plus mask PNGs),
extracted by ``marionette extract`` in a fresh process, with the masks
given and (``--no-auto`` skips it) found automatically; per-stage times
from the prior's ``metadata["timings"]``, peak memory from ``ru_maxrss``.

(b) Transfer and rendering against target Gaussians: a 512x512-equivalent
target lifted from a synthetic still at stride 1, the still's size chosen
so the lift gives a little more than N Gaussians, then N kept at random
(density, and so the splats' screen footprint, stays that of a real lift);
the synthetic out-of-plane prior (50 frames) moves it; 50 frames rendered at
512x512 (``pipeline.transfer``, ``pipeline.render_frames``).

(c) Rasterizer throughput (``marionette.render.render``) against Gaussian
count and image size, on the 3DGS-like object of ``bench_rasterizer.py``.

Each case gives the median of several runs (fewer for the large cases); the
growth is the least-squares slope ``a`` of log time against log size
(time ∝ size^a). Writes ``docs/benchmarks/scaling.md`` and PNG plots under
``docs/images/results/``.

    python benchmarks/bench_scaling.py [--quick] [--no-auto]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from paper_setting import measured_run, synthetic_clip  # noqa: E402  (same folder)

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks" / "scaling.md"
IMAGES = ROOT / "docs" / "images" / "results"
#: Cases above these sizes run once: source frames, target Gaussians, rasterizer Gaussians x pixels.
LARGE_FRAMES, LARGE_GAUSSIANS, LARGE_RASTER = 200, 200_000, 200_000 * 512 * 512


def runs_for(size: float, large: float, runs: int) -> int:
    """``runs`` for a case up to ``large``, one above it."""
    return runs if size <= large else 1


def fit_growth(sizes, times) -> tuple[float, float]:
    """Least-squares fit of ``time = c * size**a`` in log-log space; ``(a, c)``.

    Parameters
    ----------
    sizes, times : array_like, shape (M,)
        Positive sizes (at least two distinct) and the times measured at them.
    """
    sizes, times = np.asarray(sizes, float), np.asarray(times, float)
    if not (sizes.shape == times.shape and np.all(sizes > 0) and np.all(times > 0) and np.ptp(sizes) > 0):
        raise ValueError(f"need positive times at two or more distinct positive sizes, got {sizes}, {times}")
    a, log_c = np.polyfit(np.log(sizes), np.log(times), 1)
    return float(a), float(np.exp(log_c))


def frames_scaling(counts: list[int], size: tuple[int, int], runs: int, auto: bool) -> list[dict]:
    """Extraction time per stage and peak memory for each clip length (and mask mode)."""
    from marionette.io import read_prior

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        prior_path = Path(tmp) / "prior.npz"
        for frames in counts:
            video, masks = synthetic_clip(frames, size)
            for mode in ("given", "auto") if auto else ("given",):
                command = ["marionette", "extract", str(video), "-o", str(prior_path), "--quiet"]
                command += ["--masks", str(masks)] if mode == "given" else []
                samples = []
                for _ in range(runs_for(frames, LARGE_FRAMES, runs)):
                    prior_path.unlink(missing_ok=True)
                    wall, peak = measured_run(command)
                    samples.append({"wall": wall, "peak MB": peak, **read_prior(prior_path).metadata["timings"]})
                row = {k: statistics.median(s[k] for s in samples) for k in samples[0]}
                rows.append({"frames": frames, "size": f"{size[0]}x{size[1]}", "masks": mode, "runs": len(samples),
                             **row})
                print(f"{frames} frames, masks {mode}: {row['wall']:.1f} s wall, extraction {row['total']:.1f} s, "
                      f"peak {row['peak MB']:.0f} MB", flush=True)
    return rows


def lifted_target(count: int, seed: int = 0):
    """A lifted synthetic still with exactly ``count`` Gaussians, its camera as at 512x512."""
    from marionette.synthetic import render_object_image
    from marionette.target.lift import lift_image

    # The hinge still lifts to about 1.35 Gaussians per image pixel (a third of the pixels, each with a
    # front, a back and some wall Gaussians): aim 10 % above the count, correct if short.
    side = int(np.sqrt(1.1 * count / 1.35))
    for _ in range(3):
        target = lift_image(render_object_image("hinge", size=(side, side), seed=1))
        if len(target.gaussians) >= count:
            break
        side = int(side * np.sqrt(1.1 * count / len(target.gaussians))) + 1
    keep = np.sort(np.random.default_rng(seed).choice(len(target.gaussians), count, replace=False))
    return replace(target, gaussians=target.gaussians.subset(keep), pixel_of=target.pixel_of[keep],
                   camera=target.camera.resized(512, 512))


def gaussians_scaling(counts: list[int], frames: int, runs: int) -> list[dict]:
    """Transfer and render seconds for ``frames`` frames at 512x512, per target size."""
    from marionette.source import extract_prior
    from marionette.synthetic import make_scene

    sys.path.insert(0, str(Path(__file__).parent))
    from bench_transfer import time_transfer_render

    scene = make_scene("outofplane", num_frames=frames, size=(320, 240), seed=0)
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps)
    rows = []
    for count in counts:
        target = lifted_target(count)
        if not rows:
            time_transfer_render(prior, target)  # warm-up: load the compiled kernels
        samples = [time_transfer_render(prior, target) for _ in range(runs_for(count, LARGE_GAUSSIANS, runs))]
        row = {"gaussians": count, "frames": frames, "runs": len(samples),
               "transfer": statistics.median(s[0] for s in samples),
               "render": statistics.median(s[1] for s in samples),
               "total": statistics.median(s[0] + s[1] for s in samples)}
        rows.append(row)
        print(f"{count:,} Gaussians: transfer {row['transfer']:.2f} s, render {row['render']:.2f} s", flush=True)
    return rows


def rasterizer_scaling(counts: list[int], sides: list[int], runs: int) -> list[dict]:
    """Median seconds per frame of ``render`` for each Gaussian count and square image side."""
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_rasterizer import make_scene

    from marionette.render import render

    rows = []
    for count in counts:
        gaussians, camera = make_scene(count)
        for side in sides:
            cam = camera.resized(side, side)
            render(gaussians, cam)  # warm-up
            samples = []
            for _ in range(runs_for(count * side * side, LARGE_RASTER, runs)):
                start = time.perf_counter()
                render(gaussians, cam)
                samples.append(time.perf_counter() - start)
            rows.append({"gaussians": count, "side": side, "runs": len(samples), "seconds": statistics.median(samples)})
            print(f"rasterizer {count:,} Gaussians at {side}²: {1e3 * rows[-1]['seconds']:.1f} ms", flush=True)
    return rows


def _loglog(ax, title: str, xlabel: str, ylabel: str) -> None:
    from matplotlib.ticker import FuncFormatter, LogFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):  # plain numbers, not powers of ten; minor labels when the span is short
        axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
        axis.set_minor_formatter(LogFormatter(labelOnlyBase=False))
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def plot(frames_rows: list[dict], gauss_rows: list[dict], raster_rows: list[dict], folder: Path) -> list[Path]:
    """Three log-log PNGs (frames, Gaussians, rasterizer); their paths."""
    from matplotlib.figure import Figure

    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / "scaling_frames.png", folder / "scaling_gaussians.png", folder / "rasterizer_throughput.png"]

    fig = Figure(figsize=(6, 4.2), dpi=100)
    ax = fig.add_subplot()
    for mode in dict.fromkeys(r["masks"] for r in frames_rows):
        sel = [r for r in frames_rows if r["masks"] == mode]
        x, y = [r["frames"] for r in sel], [r["wall"] for r in sel]
        label = f"masks {mode}" + (f" (∝ T^{fit_growth(x, y)[0]:.2f})" if len(sel) > 1 else "")
        ax.plot(x, y, "o-", label=label)
    _loglog(ax, "Extraction (854x480 synthetic clip)", "source frames T", "seconds (whole process)")
    fig.tight_layout()
    fig.savefig(paths[0])

    fig = Figure(figsize=(6, 4.2), dpi=100)
    ax = fig.add_subplot()
    x = [r["gaussians"] for r in gauss_rows]
    for key in ("transfer", "render", "total"):
        y = [r[key] for r in gauss_rows]
        ax.plot(x, y, "o-", label=f"{key} (∝ N^{fit_growth(x, y)[0]:.2f})" if len(x) > 1 else key)
    _loglog(ax, f"Transfer and render, {gauss_rows[0]['frames']} frames at 512x512", "target Gaussians N",
            "seconds")
    fig.tight_layout()
    fig.savefig(paths[1])

    fig = Figure(figsize=(6, 4.2), dpi=100)
    ax = fig.add_subplot()
    for side in dict.fromkeys(r["side"] for r in raster_rows):
        sel = [r for r in raster_rows if r["side"] == side]
        ax.plot([r["gaussians"] for r in sel], [1 / r["seconds"] for r in sel], "o-", label=f"{side}x{side}")
    _loglog(ax, "Rasterizer throughput", "Gaussians N", "frames per second")
    fig.tight_layout()
    fig.savefig(paths[2])
    return paths


def _growth_text(sizes, times, letter: str) -> str:
    """'∝ T^1.02' for the fitted growth, '–' with fewer than two sizes."""
    if len(set(sizes)) < 2:
        return "–"
    return f"∝ {letter}^{fit_growth(sizes, times)[0]:.2f}"


def _growth_by(rows: list[dict], group: str, size, time: str, letter: str, label=lambda value: f"{value:,}") -> str:
    """The growth of ``time`` with ``size(row)`` within each value of ``group``, as 'label(value): ∝ …; …'."""
    parts = []
    for value in dict.fromkeys(r[group] for r in rows):
        sel = [r for r in rows if r[group] == value]
        parts.append(f"{label(value)}: {_growth_text([size(r) for r in sel], [r[time] for r in sel], letter)}")
    return "; ".join(parts)


def report(frames_rows, gauss_rows, raster_rows, plots: list[Path], out: Path, command: str) -> str:
    """The markdown page, to be written to ``out`` (plot links are relative to it)."""
    fixed = ("frames", "size", "masks", "runs", "wall", "peak MB", "total")
    stages = [k for k in dict.fromkeys(k for r in frames_rows for k in r) if k not in fixed]
    link = lambda path: os.path.relpath(path, out.parent)  # noqa: E731
    lines = ["# Scaling", "",
             f"`{command}` on {os.cpu_count()} cores (load average {os.getloadavg()[0]:.2f} at the end; other"
             " work on the machine inflates wall times). Growth: least-squares slope `a` of log time against"
             " log size, time ∝ size^a (a = 1: linear).", "",
             "## Extraction against source frames", "",
             f"Synthetic out-of-plane turn at {frames_rows[0]['size']}, `marionette extract` in a fresh process;"
             " wall includes start-up and reading the MP4; stage columns (seconds) from the prior's metadata.", "",
             "| frames | masks | runs | wall s | extraction s | " + " | ".join(stages) + " | peak MB |",
             "|---:|---|---:|---:|---:|" + "---:|" * len(stages) + "---:|"]
    for r in frames_rows:
        lines.append(f"| {r['frames']} | {r['masks']} | {r['runs']} | {r['wall']:.1f} | {r['total']:.1f} | "
                     + " | ".join(f"{r.get(k, 0.0):.2f}" for k in stages) + f" | {r['peak MB']:.0f} |")
    lines += ["", "Measured growth with the frame count T (stages under 10 ms are left out):", "",
              "| masks | wall | extraction | " + " | ".join(stages) + " |", "|---|---|---|" + "---|" * len(stages)]
    for mode in dict.fromkeys(r["masks"] for r in frames_rows):
        sel = [r for r in frames_rows if r["masks"] == mode]
        x = [r["frames"] for r in sel]
        cells = [_growth_text(x, [r.get(k, 0.0) for r in sel], "T") if min(r.get(k, 0.0) for r in sel) >= 0.01
                 else "–" for k in ["wall", "total", *stages]]
        lines.append(f"| {mode} | " + " | ".join(cells) + " |")
    lines += ["", f"![extraction against frames]({link(plots[0])})", "",
              "## Transfer and rendering against target Gaussians", "",
              f"{gauss_rows[0]['frames']} frames rendered at 512x512 from a lifted synthetic still"
              " (see the script's docstring); median of the runs after a warm-up.", "",
              "| Gaussians | runs | transfer s | render s | total s | ms / frame |", "|---:|---:|---:|---:|---:|---:|"]
    for r in gauss_rows:
        lines.append(f"| {r['gaussians']:,} | {r['runs']} | {r['transfer']:.2f} | {r['render']:.2f} | "
                     f"{r['total']:.2f} | {1e3 * r['total'] / r['frames']:.0f} |")
    x = [r["gaussians"] for r in gauss_rows]
    lines += ["", "Measured growth with the Gaussian count N: " + ", ".join(
        f"{key} {_growth_text(x, [r[key] for r in gauss_rows], 'N')}" for key in ("transfer", "render", "total"))
        + ".", "", f"![transfer and render against Gaussians]({link(plots[1])})", "",
        "## Rasterizer throughput", "",
        "`marionette.render.render` on the 3DGS-like object of `bench_rasterizer.py` (SH degree 3), camera"
        " resized to each side; median seconds per frame after a warm-up.", ""]
    sides = list(dict.fromkeys(r["side"] for r in raster_rows))
    lines += ["| Gaussians | " + " | ".join(f"{s}² ms (fps)" for s in sides) + " |",
              "|---:|" + "---:|" * len(sides)]
    for count in dict.fromkeys(r["gaussians"] for r in raster_rows):
        cells = [next(r for r in raster_rows if r["gaussians"] == count and r["side"] == s) for s in sides]
        lines.append(f"| {count:,} | " + " | ".join(f"{1e3 * c['seconds']:.1f} ({1 / c['seconds']:.1f})"
                                                    for c in cells) + " |")
    lines += ["", "Measured growth with the Gaussian count N, per image side: "
              + _growth_by(raster_rows, "side", lambda r: r["gaussians"], "seconds", "N", lambda v: f"{v}²") + ".",
              "With the pixel count P, per Gaussian count: "
              + _growth_by(raster_rows, "gaussians", lambda r: r["side"] ** 2, "seconds", "P") + ".", "",
              f"![rasterizer throughput]({link(plots[2])})"]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, one run each: a smoke test")
    parser.add_argument("--runs", type=int, default=3, help="runs per case (large cases: one)")
    parser.add_argument("--no-auto", action="store_true", help="skip extraction without masks")
    parser.add_argument("--out", type=Path, default=DOC)
    parser.add_argument("--images", type=Path, default=IMAGES)
    args = parser.parse_args()
    if args.quick:
        frame_counts, gaussian_counts, sides, runs = [10, 20], [20_000, 50_000], [256, 512], 1
    else:
        frame_counts, sides, runs = [50, 200, 800], [256, 512, 1024], args.runs
        gaussian_counts = [50_000, 100_000, 200_000, 500_000, 1_000_000]
    frames_rows = frames_scaling(frame_counts, (854, 480), runs, auto=not args.no_auto)
    gauss_rows = gaussians_scaling(gaussian_counts, 50, runs)
    raster_rows = rasterizer_scaling(gaussian_counts, sides, runs)
    plots = plot(frames_rows, gauss_rows, raster_rows, args.images)
    command = "python benchmarks/bench_scaling.py" + (" --quick" if args.quick else f" --runs {runs}") + (
        " --no-auto" if args.no_auto else "")
    text = report(frames_rows, gauss_rows, raster_rows, plots, args.out, command)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
