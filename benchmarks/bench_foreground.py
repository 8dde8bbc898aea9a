"""Accuracy and speed of ``auto_masks`` (automatic foreground) on synthetic scenes and real clips.

Synthetic scenes (exact masks): IoU per frame, its mean and minimum. Real
clips with DAVIS ground-truth masks in ``../shared/data/videos``: mean and
minimum IoU per clip, and time per clip (the whole clip, and scaled to 50
frames). ``cotracker_backpack`` has no masks: a contact sheet with the masks
overlaid is written to ``--sheets`` for looking at. Writes
``docs/benchmarks/foreground.md``.

    python benchmarks/bench_foreground.py [--data ../shared/data/videos] [--sheets /tmp]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from marionette.io.video import read_masks, read_video  # noqa: E402
from marionette.segment import SalientModel  # noqa: E402
from marionette.source.foreground import auto_masks  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SYNTHETIC = (("translation", "static"), ("inplane", "static"), ("outofplane", "static"), ("oscillation", "static"),
             ("hinge", "static"), ("translation", "pan"), ("outofplane", "handheld"))
CLIPS = ("davis_car-turn", "davis_car-shadow", "davis_train", "cotracker_backpack")


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T,) intersection over union of (T, H, W) bool masks; 1 where both are empty."""
    inter = (a & b).sum(axis=(1, 2))
    union = (a | b).sum(axis=(1, 2))
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def contact_sheet(frames: np.ndarray, masks: np.ndarray, path: Path, count: int = 6,
                  truth: np.ndarray | None = None) -> None:
    """Write ``count`` evenly spaced frames with the mask tinted green (ground truth outlined red) as one PNG."""
    tiles = []
    for t in np.linspace(0, len(frames) - 1, count).round().astype(int):
        tile = frames[t].copy()
        tile[masks[t]] = (0.5 * tile[masks[t]] + [0, 127, 0]).astype(np.uint8)
        if truth is not None:
            contours, _ = cv2.findContours(truth[t].astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(tile, contours, -1, (255, 0, 0), 2)
        cv2.putText(tile, str(t), (8, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 0), 2)
        tiles.append(cv2.resize(tile, (round(240 * tile.shape[1] / tile.shape[0]), 240)))
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(tiles, axis=1), cv2.COLOR_RGB2BGR))


def timing_rows(folder: Path, model: SalientModel) -> list[str]:
    """Markdown lines timing the stages on the first 50 frames of a clip, from the progress callback.

    With T frames the callback counts 2 (T - 1) flows, then the key frames'
    saliency, then the T masks (motion residuals are computed before the first).
    """
    if not folder.is_dir():
        return []
    frames = read_video(folder / "frames").frames[:50]
    T = len(frames)
    keys = len(set(range(0, T, 8)) | {T - 1})
    stamps = {}
    start = time.perf_counter()
    auto_masks(frames, model=model, progress=lambda done, total: stamps.setdefault(done, time.perf_counter()))
    total = time.perf_counter() - start
    flow = stamps[2 * (T - 1)] - start
    salient = stamps[2 * (T - 1) + keys] - stamps[2 * (T - 1)]
    load = os.getloadavg()[0]
    print(f"{folder.name} first {T} frames: {total:.2f} s (flow {flow:.2f}, saliency {salient:.2f}, "
          f"motion and masks {total - flow - salient:.2f}); load average {load:.1f}")
    return ["", f"## Time per stage ({folder.name}, first {T} frames, 854x480)", "",
            "| flow (s) | saliency (s) | motion and masks (s) | total (s) | load average |", "|---|---|---|---|---|",
            f"| {flow:.2f} | {salient:.2f} | {total - flow - salient:.2f} | {total:.2f} | {load:.1f} |"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "videos"))
    ap.add_argument("--sheets", default="/tmp")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "foreground.md"))
    args = ap.parse_args()
    model = SalientModel()
    model.predict(np.zeros((32, 32, 3), np.uint8))  # load the network outside the timings

    lines = ["# Automatic foreground masks", "",
             f"`python benchmarks/bench_foreground.py` on {platform.machine()}, Python {platform.python_version()}; "
             "default `ForegroundOptions`, `key_every=8`. IoU against the exact (synthetic) or DAVIS "
             "(real) masks, per frame.", "",
             "## Synthetic (320x240, 24 frames, seed 0)", "",
             "| motion | camera | mean IoU | min IoU | time (s) |", "|---|---|---|---|---|"]
    for motion, camera in SYNTHETIC:
        scene = make_scene(motion, num_frames=24, size=(320, 240), seed=0, camera_motion=camera)
        start = time.perf_counter()
        masks = auto_masks(scene.frames, model=model)
        elapsed = time.perf_counter() - start
        score = iou(masks, scene.masks)
        print(f"{motion:12s} {camera:9s} mean IoU {score.mean():.3f} min {score.min():.3f} {elapsed:.2f} s")
        lines.append(f"| {motion} | {camera} | {score.mean():.3f} | {score.min():.3f} | {elapsed:.2f} |")

    lines += timing_rows(Path(args.data) / "davis_car-turn", model)
    lines += ["", "## Real clips (854x480)", "",
              "| clip | frames | mean IoU | min IoU | time (s) | time per 50 frames (s) |",
              "|---|---|---|---|---|---|"]
    for clip in CLIPS:
        folder = Path(args.data) / clip
        if not folder.is_dir():
            print(f"{clip}: not found in {args.data}, skipped")
            continue
        video = read_video(folder / "frames" if (folder / "frames").is_dir() else folder / "source.mp4")
        truth = (read_masks(folder / "masks", count=len(video), size=video.size)
                 if (folder / "masks").is_dir() else None)
        start = time.perf_counter()
        masks = auto_masks(video.frames, model=model)
        elapsed = time.perf_counter() - start
        sheet = Path(args.sheets) / f"foreground_{clip}.png"
        contact_sheet(video.frames, masks, sheet, truth=truth)
        per50 = elapsed * 50 / len(video)
        if truth is None:
            print(f"{clip:20s} no ground truth; {elapsed:.2f} s; sheet {sheet}")
            lines.append(f"| {clip} | {len(video)} | – | – | {elapsed:.2f} | {per50:.2f} |")
        else:
            score = iou(masks, truth)
            print(f"{clip:20s} mean IoU {score.mean():.3f} min {score.min():.3f} {elapsed:.2f} s; sheet {sheet}")
            lines.append(f"| {clip} | {len(video)} | {score.mean():.3f} | {score.min():.3f} | {elapsed:.2f} "
                         f"| {per50:.2f} |")
    lines += ["", "## Notes", "",
              "- Saliency (U²-Netp on every 8th frame) dominates the time; on an idle machine a 50-frame 854x480 clip "
              "takes about 4.5 s, on this shared 2-core machine under load up to ~12 s (ONNX Runtime threads "
              "compete with other processes). Flow and motion run at a long side of 480.",
              "- `hinge` with a static body: only the moving lid is found (rule 2: of a salient object that moves "
              "only in part, the moving part is kept), so the IoU against the whole object is low by design.",
              "- `cotracker_backpack` (see the contact sheet): the swinging bag and the holding arm are found in "
              "every frame; in the middle of the clip (about frames 30-75), where the hand-held camera translates, the "
              "person's torso shows parallax against the stairs' homography, counts as moving, and is included "
              "with the bag (rule 1). Pass masks for such clips.",
              "- `ForegroundOptions(grabcut=True)` (not the default) lowers the mean IoU on the first 40 frames of "
              "davis_car-shadow from 0.893 to 0.885 and of davis_car-turn from 0.930 to 0.909.",
              "- `davis_train`: the blue locomotive is missed in the last frames (saliency does not pick it up); "
              "salient scenery next to the track sometimes joins."]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
