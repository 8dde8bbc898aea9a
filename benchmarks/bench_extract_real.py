"""Source extraction on the real clips: motion found, time per stage, peak memory.

Needs ``../shared/data``. Each run happens in a fresh process so that its
peak memory (``ru_maxrss``) is its own. Writes
``docs/benchmarks/extract_real.md`` and one plot per clip under
``docs/images/``.

    python benchmarks/bench_extract_real.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "videos"
DOC = ROOT / "docs" / "benchmarks" / "extract_real.md"
IMAGES = ROOT / "docs" / "images"

#: name: (clip, masks?, parts, frame range end or None, what to look for)
CASES = {
    "car-turn": ("davis_car-turn", True, "1", None, "yaw of about 100° as the camera sees it, about 50° in the world (the camera pans about 55° with the car)"),
    "car-turn, no masks": ("davis_car-turn", False, "1", None, "the same without masks"),
    "car-shadow": ("davis_car-shadow", True, "1", None, "mostly translation, slight turn"),
    "train, parts auto": ("davis_train", True, "auto", None, "more than one part"),
    "backpack, no masks": ("cotracker_backpack", False, "1", None, "back-and-forth twist"),
    "speed: 50 frames 854x480": ("davis_car-turn", True, "1", 50, "<= 30 s, <= 2 GB"),
    "speed: 50 frames 854x480, no masks": ("davis_car-turn", False, "1", 50, "<= 30 s, <= 2 GB"),
}


def reversals(values, tolerance: float = 2.0) -> int:
    """How often a curve changes direction by more than ``tolerance`` (a zig-zag count)."""
    count, direction, extreme = 0, 0, values[0]
    for v in values[1:]:
        if direction >= 0 and v < extreme - tolerance:
            count, direction, extreme = count + (direction > 0), -1, v
        elif direction <= 0 and v > extreme + tolerance:
            count, direction, extreme = count + (direction < 0), 1, v
        elif (direction > 0 and v > extreme) or (direction < 0 and v < extreme):
            extreme = v
    return count


def _tracks(metadata: dict) -> str:
    """The tracks column: strict or anchored, and the share of windows that matched their anchor closely."""
    tracks = metadata.get("tracks") or {}
    share = tracks.get("anchor_match")
    return ("strict" if tracks.get("strict") else "anchored") + ("" if share is None else f" ({share:.0%})")


def _camera(metadata: dict) -> str:
    """The camera column: what was done, and how much of the background each model tried explains."""
    model = metadata.get("camera_model") or {}
    fits = [f"rotation {model['rotation_agreement']:.0%}"] if "rotation_agreement" in model else []
    if model.get("full_pose_agreement") is not None:
        fits.append(f"full pose {model['full_pose_agreement']:.0%}")
    return metadata["camera_motion"] + (f" ({model['model']}; {', '.join(fits)})" if model else "")


def run_one(case: str, plot: Path | None) -> dict:
    """Extract one case in this process; figures as a dict."""
    import numpy as np

    from marionette import pipeline
    from marionette.geometry import matrix_to_axis_angle, rotation_angle_deg
    from marionette.plot import plot_prior
    from marionette.source import ExtractOptions

    clip, with_masks, parts, end, _ = CASES[case]
    folder = DATA / clip
    source = folder / "frames" if (folder / "frames").is_dir() else folder / "source.mp4"
    prior = pipeline.extract(source, masks=folder / "masks" if with_masks else None, end=end,
                             options=ExtractOptions(parts="auto" if parts == "auto" else int(parts)))
    if plot is not None:
        plot_prior(prior, plot, title=case)
    rot = prior.poses[0, :, :3, :3]
    vec = np.degrees(matrix_to_axis_angle(rot))  # (T, 3) rotation vectors, camera axes
    return {
        "frames": prior.num_frames, "size": [int(x) for x in prior.image_size], "parts": prior.num_parts,
        "final_angle": float(rotation_angle_deg(rot[-1])), "max_angle": float(rotation_angle_deg(rot).max()),
        "yaw_range": float(vec[:, 1].max() - vec[:, 1].min()),
        "yaw_sign_changes": reversals(vec[:, 1]),
        "timings": prior.metadata["timings"], "camera": _camera(prior.metadata),
        "tracks": _tracks(prior.metadata),
        "failed": len(prior.metadata.get("failed_frames") or {}),
        "recovered": len(prior.metadata.get("recovered_frames") or {}),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per speed case (median reported)")
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: run one case, print JSON
    parser.add_argument("--plot", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one, args.plot)))
        return
    if not DATA.is_dir():
        sys.exit(f"needs the real clips in {DATA}")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    rows = []
    for case in CASES:
        runs = args.runs if case.startswith("speed") else 1
        slug = case.split(",")[0].replace(" ", "-")
        suffix = "-auto" if "no masks" in case else ""
        plot = None if case.startswith("speed") else IMAGES / f"extract_{slug}{suffix}.png"
        results = []
        for _ in range(runs):
            cmd = [sys.executable, __file__, "--one", case] + (["--plot", str(plot)] if plot else [])
            out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env)
            results.append(json.loads(out.stdout.strip().splitlines()[-1]))
        total = statistics.median(r["timings"]["total"] for r in results)
        rows.append((case, results[len(results) // 2], total, plot))
        print(case, f"{total:.1f} s", json.dumps(results[0]["timings"]))

    lines = ["# Source extraction on real clips", "",
             f"`python benchmarks/bench_extract_real.py --runs {args.runs}` on {platform.machine()}, "
             f"{os.cpu_count()} cores, Python {platform.python_version()}; default options, "
             "frames downscaled to a long side of 960 (the DAVIS clips are 854x480 already). Each case runs in a "
             "fresh process; speed cases give the median of the runs. Angles in degrees: `final` is the rotation "
             "from frame 0 to the last frame, `yaw range` the spread of the rotation vector's vertical component "
             "(camera y axis), `yaw turns` how often it changes direction; failed part-frames are interpolated, "
             "recovered ones were lost by the tracks and found again (by alignment, `marionette.source.recover`; "
             "about a hinge; or by PnP once the frames before them were refined); `tracks`: "
             "strict or anchored (`--strict-tracks`), with the share of windows that matched their anchor closely "
             "where strict ones were tried (one-part cases; parts are found on anchored tracks).", "",
             "| case | frames | parts | final angle | yaw range | yaw turns | failed / recovered part-frames "
             "| tracks | camera | total s | peak MB | expected |",
             "|---|---:|---:|---:|---:|---:|---:|---|---|---:|---:|---|"]
    for case, r, total, _ in rows:
        lines.append(f"| {case} | {r['frames']} | {r['parts']} | {r['final_angle']:.1f} | {r['yaw_range']:.1f} | "
                     f"{r['yaw_sign_changes']} | {r['failed']} / {r['recovered']} | {r['tracks']} | {r['camera']} "
                     f"| {total:.1f} | "
                     f"{r['peak_mb']:.0f} | {CASES[case][4]} |")
    stages = sorted({k for _, r, _, _ in rows for k in r["timings"] if k != "total"})
    lines += ["", "Time per stage (seconds, the median run):", "",
              "| case | " + " | ".join(stages) + " | total |", "|---|" + "---:|" * (len(stages) + 1)]
    for case, r, total, _ in rows:
        cells = [f"{r['timings'].get(s, 0.0):.2f}" for s in stages]
        lines.append(f"| {case} | " + " | ".join(cells) + f" | {total:.1f} |")
    lines += ["", "Plots (rotation angle and centroid displacement per part over time):", ""]
    lines += [f"- {case}: ![{case}](../images/{plot.name})" for case, _, _, plot in rows if plot]
    DOC.write_text("\n".join(lines) + "\n")
    print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
