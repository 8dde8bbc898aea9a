"""Self-transfer on every shared DAVIS clip, the hard ones included: silhouettes, stray pixels, failed frames.

Needs ``../shared/data``. For each clip, ``eval_self`` with its masks (the reconstruction target, the camera's
motion kept in the poses, the focal length estimated, the joint fit on unless ``--no-joint-fit``) and, from the
render of every frame in full against the true masks (:mod:`marionette.eval.silhouette`): the silhouette IoU
(median and worst frame), the frames with more than 0.5 % of their pixels drawn farther than 15 px from the
mask (stray frames), the part-frames whose poses the extraction interpolated (failed) or recovered, whole-frame
and object-pixel PSNR, motion fidelity and the time. Frames where something in front covers the object are told
from the masks alone (:func:`marionette.reconstruct.occlusion.covered_frames`), listed with the share covered,
and held to the median only: the worst IoU is also given over the other frames. Writes
``docs/benchmarks/hard_clips.md`` and a sheet per clip under ``docs/images/hard_clips/`` (source | render at the
first, the worst and the last frame).

    flock /tmp/marionette-bench.lock python benchmarks/bench_hard_clips.py [--clips drift-turn,bus] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "videos"
DOC = ROOT / "docs" / "benchmarks" / "hard_clips.md"
SHEETS = ROOT / "docs" / "images" / "hard_clips"

#: clip: (DAVIS folder, rigid parts, what makes it hard)
CLIPS = {
    "car-shadow": ("davis_car-shadow", 1, "clean: slides, turns a little"),
    "car-turn": ("davis_car-turn", 1, "clean: yaws about 90°"),
    "train": ("davis_train", 4, "clean: coupled cars"),
    "drift-turn": ("davis_drift-turn", 1, "fast yaw, smoke, blur, approaches and leaves the frame"),
    "drift-chicane": ("davis_drift-chicane", 1, "small and far, smoke, panning camera"),
    "motocross-bumps": ("davis_motocross-bumps", 1, "pitch, approaches, the rider moves on the bike"),
    "bus": ("davis_bus", 1, "trees in front, panning camera"),
    "soccerball": ("davis_soccerball", 1, "small, rolls, a trunk in front"),
}


#: The table of the same run before the joint fit existed (commit 6f6af46): clip -> (IoU median, IoU worst, stray
#: frames, failed part-frames, whole-frame PSNR, object PSNR, total seconds).
BEFORE = {
    "car-shadow": (0.992, 0.986, 0, 0, 33.07, 21.37, 25), "car-turn": (0.989, 0.955, 0, 0, 32.24, 22.07, 42),
    "train": (0.977, 0.968, 0, 31, 27.60, 22.07, 66), "drift-turn": (0.955, 0.778, 7, 0, 26.19, 16.81, 49),
    "drift-chicane": (0.943, 0.428, 6, 0, 37.33, 20.45, 19),
    "motocross-bumps": (0.787, 0.327, 33, 0, 21.67, 13.13, 33), "bus": (0.844, 0.604, 0, 0, 19.02, 17.13, 51),
    "soccerball": (0.135, 0.013, 48, 45, 22.38, 9.93, 14),
}


def run(name: str, out: Path, joint_fit: bool = True) -> dict:
    """eval_self on one clip; its metrics with the object-pixel PSNR and the times."""
    import numpy as np

    from marionette import pipeline
    from marionette.eval import EVAL_EXTRACT, eval_self
    from marionette.eval.metrics import masked_psnr
    from marionette.io import read_masks, read_video
    from marionette.progress import Reporter
    from marionette.reconstruct.occlusion import covered_frames

    folder, parts, _ = CLIPS[name]
    frames_dir, masks_dir = DATA / folder / "frames", DATA / folder / "masks"
    reporter = Reporter(quiet=True)
    start = time.perf_counter()
    metrics = eval_self(frames_dir, masks_dir, out / name, reporter=reporter,
                        options=dataclasses.replace(EVAL_EXTRACT, parts=parts, joint_fit=joint_fit))
    metrics["seconds"] = time.perf_counter() - start
    metrics["stages"] = dict(reporter.timings)
    video = read_video(frames_dir, max_side=pipeline.DEFAULT_MAX_SIDE)
    w, h = metrics["width"], metrics["height"]
    masks = np.asarray(read_masks(masks_dir, count=len(video.frames), size=(w, h), indices=video.indices), bool)
    rendered = read_video(out / name / "video.mp4").frames[:, :h, :w]
    metrics["masked_psnr"] = float(np.median([masked_psnr(r, f, m) for r, f, m in zip(rendered, video.frames, masks)
                                              if m.any()]))
    metrics["mask_share"] = float(masks.mean())
    metrics["covered"] = covered_frames(masks)  # the masks' own: the fit's view of them may differ
    return metrics


def sheet(name: str, out: Path, metrics: dict) -> Path:
    """Source (masked) beside render at the first, the worst-IoU and the last frame, stacked; a PNG."""
    import cv2
    import numpy as np

    from marionette.io import read_video, write_image

    frames = read_video(out / name / "side_by_side.mp4").frames
    worst = metrics["silhouette"]["worst_frame"]
    rows = []
    for t in sorted({0, worst, len(frames) - 1}):
        row = np.ascontiguousarray(frames[t])
        label = f"{name} frame {t}" + (" (worst IoU)" if t == worst else "")
        cv2.putText(row, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
        rows.append(row)
    image = np.concatenate(rows, axis=0)
    scale = 720 / image.shape[1]
    image = cv2.resize(image, (720, int(round(image.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    SHEETS.mkdir(parents=True, exist_ok=True)
    path = SHEETS / f"{name}.png"
    write_image(path, image)
    return path


#: What the table shows (re-read after a new run).
READING = """\
Reading the table. The joint fit (poses and object fitted together to the masks, pixels and tracks,
`marionette.reconstruct.joint`) took soccerball from a ball drawn everywhere but on its mask (45 of 48 frames lost
by the tracker and interpolated) to IoU 0.93 with 4 stray frames: the lost frames are put on their masks first
(their depth from the long side of the mask's box, which a trunk in front leaves whole), then fitted. Where the
trunk covers the ball (the covered frames above: its mask dips below its size on both sides,
`marionette.reconstruct.occlusion`) the fit counts only where the ball shows, so the trunk no longer pushes it
aside, and a frame the tracks lost there is placed when its silhouette holds what shows at its neighbours' size:
13 failed part-frames became 5 (frames 5, 8, 17, 20 and 21, where the ball is drawn 4-12 px beside the sliver that
shows; frames 8 and 17 are partly covered but not a dip, and so held to the worst too). On drift-chicane the
tracks slip by about 30° over the first four frames (smoke): the joint fit mends them from their neighbours' poses
(a frame whose loss is several times the median tries the poses of the frames beside it), which took its worst
frame from 0.45 to 0.76. Frame 0 keeps its turn but its place is fitted (the car some 60 px wide at drift-turn's
start, a depth the tracks barely tell): drift-turn's worst frame went from 0.80 to 0.88, car-turn's from 0.94 to
0.96. Drift-turn's last frames, the car leaving the frame, draw up to 1.5 % of it off the mask. Motocross-bumps'
rider moves on the bike, and as the bike nears the camera its poses go wrong (frame 44 on its sheet: drawn smaller
and beside it): Gaussians off the mask in a quarter of the frames are dropped after the fit
(`marionette.reconstruct.strays`), but what draws off the mask there is the whole bike, misplaced. The bus is
behind trees all along (its masks show only what the trees leave; no dip to tell them by). Train has four parts
and keeps its tracks' poses (the joint fit is for one-part motion); its tracks now place every frame of the
locomotive (31 frames were interpolated before)."""


def report(results: dict[str, dict]) -> str:
    from marionette.eval.silhouette import DRAWN_ALPHA, STRAY_REACH_PX, STRAY_SHARE
    from marionette.reconstruct.occlusion import COVER_WINDOW, COVERED_SHARE

    lines = [
        "# Every shared DAVIS clip: silhouettes, stray pixels, failed frames",
        "",
        "`python benchmarks/bench_hard_clips.py` (needs `../shared/data`): `marionette eval-self` on each clip",
        "with its masks (the object reconstructed from the video and moved by the extracted poses, the camera's",
        "motion kept in them, the focal length estimated), then every frame rendered in full with the source",
        "camera and compared with the true mask (`marionette.eval.silhouette`): *IoU* of the silhouette (alpha",
        f"≥ 0.5); a *stray frame* draws more than {STRAY_SHARE:.1%} of its pixels (alpha ≥ {DRAWN_ALPHA}) farther",
        f"than {STRAY_REACH_PX:g} px from the mask. *Failed*: part-frames whose pose the extraction interpolated;",
        "*recovered*: those it placed by aligning a model or about a hinge instead. PSNR over whole frames on",
        "white (as Table 1) and over the object's pixels (median over frames). Where something in front covers",
        "the object (the bus's trees, the ball's trunk), the mask holds only what shows, and so a render of the",
        "whole object overlaps it less there: those frames, told from the masks alone (a mask at least "
        f"{COVERED_SHARE:.0%}",
        f"smaller than the largest within {COVER_WINDOW} frames on either side, off the frame's border), are listed "
        "below with the share covered, and the",
        "worst IoU is given over the other frames too.",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}.",
        "",
        "| clip | what makes it hard | frames | IoU median | IoU worst (frame) | uncovered: IoU worst (frame) "
        "| stray frames | largest stray share "
        "| failed | recovered | PSNR (dB) | object PSNR (dB) | motion fidelity | joint fit (s) | reconstruction (s) "
        "| total (s) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, m in results.items():
        s = m["silhouette"]
        fidelity = "–" if m.get("motion_fidelity") is None else f"{m['motion_fidelity']:.3f}"
        rec = m["stages"].get("reconstruction")
        joint = (m.get("extract_seconds") or {}).get("joint")
        uncovered = {t: iou for t, iou in enumerate(s["iou_per_frame"]) if t not in m["covered"]}
        low = min(uncovered, key=uncovered.get)
        lines.append(
            f"| {name} | {CLIPS[name][2]} | {m['frames']} | {s['iou_median']:.3f} | {s['iou_worst']:.3f} "
            f"({s['worst_frame']}) | {uncovered[low]:.3f} ({low}) | {len(s['stray_frames'])} "
            f"| {s['stray_share_max']:.2%} "
            f"| {len(m['failed_frames'])} | {m['recovered_frames']} | {m['psnr']:.2f} | {m['masked_psnr']:.2f} "
            f"| {fidelity} | {'–' if joint is None else f'{joint:.0f}'} | {'–' if rec is None else f'{rec:.0f}'} "
            f"| {m['seconds']:.0f} |")
    lines += ["", "Covered frames (frame: share covered, IoU):", ""]
    for name, m in results.items():
        if m["covered"]:
            ious = m["silhouette"]["iou_per_frame"]
            lines.append(f"- {name}: " + ", ".join(f"{t}: {share:.0%}, {ious[t]:.2f}"
                                                   for t, share in m["covered"].items()))
    lines += ["", "Before the joint fit (commit 6f6af46, the same protocol) → with it:", "",
              "| clip | IoU median | IoU worst | stray frames | failed | PSNR (dB) | object PSNR (dB) | total (s) |",
              "|---|---|---|---|---|---|---|---|"]
    for name, m in results.items():
        if name in BEFORE:
            b, s = BEFORE[name], m["silhouette"]
            now = (s["iou_median"], s["iou_worst"], len(s["stray_frames"]), len(m["failed_frames"]), m["psnr"],
                   m["masked_psnr"], m["seconds"])
            cells = [f"{x:.3f} → {y:.3f}" for x, y in zip(b[:2], now[:2])]
            cells += [f"{x} → {y}" for x, y in zip(b[2:4], now[2:4])]
            cells += [f"{x:.2f} → {y:.2f}" for x, y in zip(b[4:6], now[4:6])] + [f"{b[6]} → {now[6]:.0f}"]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", READING, "", "Sheets (source masked on white | render; the first, the worst and the last frame):", ""]
    lines += [f"- {name}: `docs/images/hard_clips/{name}.png`" for name in results]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", default=",".join(CLIPS))
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-hard-clips"))
    parser.add_argument("--joint-fit", action=argparse.BooleanOptionalAction, default=True)
    args = parser.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"needs {DATA}")
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in args.clips.split(","):
        results[name] = run(name, args.out, args.joint_fit)
        sheet(name, args.out, results[name])
        (args.out / name / "bench.json").write_text(json.dumps(results[name], indent=2, default=str) + "\n")
        print(name, json.dumps(results[name]["silhouette"]), f"{results[name]['seconds']:.0f} s", flush=True)
    DOC.write_text(report(results), encoding="utf-8")
    print(f"wrote {DOC}")


if __name__ == "__main__":
    main()
