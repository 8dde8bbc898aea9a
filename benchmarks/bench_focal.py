"""The focal length estimated from the object's motion (``--focal auto``), against the truth and on real clips.

Synthetic scenes (``make_scene``, focal length known): the tracks of each
motion and seed, as extraction hands them to the search (strict where the
footage allows, their pieces joined into chains), and :func:`~marionette.source.focal.estimate_focal` started
from the true focal length times each ``--starts`` factor; the estimate over
the truth, whether the tracks determined it, and the seconds. Real clips
(``../shared/data``, skipped when absent): ``marionette extract --focal auto``
(``pipeline.extract``) with their masks, from the default 60° field of view;
what it estimated and the focal stage's seconds. A plot of the costs over the
candidates per case. Writes ``docs/benchmarks/focal.md`` and
``docs/images/focal_costs.png``.

    python benchmarks/bench_focal.py [--seeds 3] [--frames 48] [--size 320x240] [--starts 0.7,1.4]
"""

from __future__ import annotations

import argparse
import platform
import time
import warnings
from pathlib import Path

import numpy as np

from marionette import pipeline
from marionette.camera import fov_from_focal
from marionette.source.focal import FOCAL_SCALES, estimate_focal
from marionette.source.tracks import track
from marionette.synthetic import make_scene

MOTIONS = ("outofplane", "oscillation", "translation", "inplane")
ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "focal.md"
FIGURE = ROOT / "docs" / "images" / "focal_costs.png"
DATA = ROOT.parent / "shared" / "data" / "videos"
CLIPS = ("davis_car-turn", "davis_car-shadow", "davis_train")


READING = """\
Reading (2026-12-05). Where the object turns in depth the cost has one clear valley. One search lands closer to
the start than it should: its first pose fit carries the start's shape guess (out-of-plane turns 0.857-0.917 of
the truth from 0.7x, 0.949-0.972 from 1.4x, in the run of 07:40). The second search, from the first one's
answer, removes most of that. With the tracks extraction now hands the search on clean footage (strict tracks
joined into chains, 11:20), out-of-plane turns end at 0.927-0.965 of the truth and oscillations at 0.932-0.981,
each seed within 1 % of itself from the two starts (anchored tracks, 09:06: 0.889-0.951 and 0.914-1.028). What
remains, 4-7 % short on the out-of-plane turns, is a bias of the fit itself (the inflated shape guess), not of
the start. Where the object slides or turns in the image plane the cost is flat to within about 1 % and the start
is kept: a valley has to climb all the way out on both sides (inplane seed 2 from 0.7x, anchored: 1.6 % and 4.0 %
next to its lowest point), and a cost still falling at the edge of the last search is a drift of the fit, not a
valley (the same case on chains: lowest at 2x, then flat from there). The real clips keep anchored tracks. Their
estimates moved with the machine, not the code: car-turn 42° on the AMD EPYC of the morning's run, 45° on this
Intel Xeon (the same tracks and poses from the code before and after this session's change, bit for bit); train
72°. Since the rounding of 2026-12-05's afternoon (`reproducibility_real.md`) they no longer do: car-turn 47° (991
px, the same under every BLAS kernel tried there), train 74°. What the morning's estimate did to Table 1 is in
`table1.md` (car-turn 0.974 / 0.029 -> 0.979 / 0.023 SSIM / LPIPS). The search costs a pose fit and seven bundle
adjustments, twice where the focal length moved: 4-7 s on these 48-frame 320x240 scenes, 2-8 s where it is kept,
and up to 18 s on the 80-frame 854x480 clips."""


def plot(curves: dict, path: Path) -> None:
    """Cost over the last search's candidate focal lengths (over the true one), normalised to its minimum, per
    case: ``curves[label] = (start factor, candidates as factors of the start, costs)``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, (factor, scales, costs) in curves.items():
        ax.plot(factor * scales, costs / np.nanmin(costs), marker="o", label=label)
    ax.axvline(1.0, color="grey", lw=0.8)
    ax.set_xscale("log")
    ax.set_ylim(0.99, 1.3)
    ax.set_xlabel("candidate focal length / true focal length")
    ax.set_ylabel("reprojection cost / its minimum")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--starts", default="0.7,1.4", help="start focal lengths, as factors of the true one")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    starts = [float(v) for v in args.starts.split(",")]
    rows, curves = [], {}
    for motion in MOTIONS:
        for seed in range(args.seeds):
            scene = make_scene(motion, seed=seed, num_frames=args.frames, size=size)
            tracks = track(scene.frames, scene.masks, strict="auto").joined()  # what extraction hands the search
            truth = scene.camera.K[0, 0]
            for factor in starts:
                k = scene.camera.K.copy()
                k[:2, :2] *= factor
                begin = time.perf_counter()
                estimate = estimate_focal(tracks, scene.masks[0], k)
                seconds = time.perf_counter() - begin
                rows.append((motion, seed, factor, estimate.focal / truth, estimate.measured, seconds))
                if seed == 0:
                    curves[f"{motion}, start x{factor:g}"] = (factor, estimate.scales, estimate.costs)
                print(f"{motion:12s} seed {seed} start x{factor:g}: {estimate.note} -> {estimate.focal / truth:.3f} "
                      f"of the truth, {seconds:.1f} s", flush=True)

    real = []
    for clip in CLIPS if DATA.is_dir() else ():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prior = pipeline.extract(DATA / clip / "frames", masks=DATA / clip / "masks", focal="auto")
        focal, width = prior.metadata["focal"], float(prior.image_size[0])
        real.append((clip, fov_from_focal(width, focal["given_px"]), fov_from_focal(width, focal["focal_px"]),
                     focal["measured"],
                     prior.metadata["timings"]["focal"], focal["note"]))
        print(f"{clip}: {focal['note']} ({real[-1][4]:.1f} s)", flush=True)
    plot(curves, FIGURE)

    lines = [
        "# Focal length from the object's motion",
        "",
        f"`python benchmarks/bench_focal.py --seeds {args.seeds} --frames {args.frames} --size {args.size} "
        f"--starts {args.starts}` on {platform.machine()}, 2 cores. `marionette.source.focal.estimate_focal` "
        "(`--focal auto`): one pose fit at the start focal length, then a bundle adjustment per candidate "
        f"({len(FOCAL_SCALES)} candidates, 0.5-2x the start) carried over by scaling the camera-frame depths, and a "
        "parabola through the best three; where that moved the focal length by more than 5 %, a second search "
        "from there. The start is kept when the cost 26 % off the best is less than 1 % "
        "higher, or does not climb steadily away from it (the focal length leaves no trace in the tracks).",
        "",
        "Synthetic scenes (`make_scene`, true focal length known, 60° wide; the tracks as extraction hands them"
        " to the search: strict here, their pieces joined into chains): the estimate over the truth, per "
        "start; *measured*: whether the tracks determined it (if not, the start is kept, so the ratio is the "
        "start's).",
        "",
        "| motion | start | estimate / truth, per seed | median | measured | seconds (mean) |",
        "|---|---|---|---|---|---|",
    ]
    for motion in MOTIONS:
        for factor in starts:
            sel = [r for r in rows if r[0] == motion and r[2] == factor]
            lines.append(f"| {motion} | x{factor:g} | {' / '.join(f'{r[3]:.3f}' for r in sel)} | "
                         f"{np.median([r[3] for r in sel]):.3f} | {sum(r[4] for r in sel)} of {len(sel)} | "
                         f"{np.mean([r[5] for r in sel]):.1f} |")
    lines += ["", f"![cost over the last search's candidates, seed 0, against the true focal length]"
                  f"(../images/{FIGURE.name})", ""]
    if real:
        lines += ["Real clips (`pipeline.extract(..., focal=\"auto\")` with their masks, from the default 60°); "
                  "their true focal lengths are unknown.", "",
                  "| clip | start (°) | estimate (°) | measured | seconds | note |", "|---|---|---|---|---|---|"]
        lines += [f"| {c} | {a:.0f} | {b:.1f} | {m} | {s:.1f} | {n} |" for c, a, b, m, s, n in real]
    else:
        lines += [f"Real clips: skipped ({DATA} not found)."]
    lines += ["", READING]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
