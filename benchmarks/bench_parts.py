"""Accuracy and speed of ``segment_parts`` on the synthetic scenes and on real clips.

Per seed: the hinge (body and lid; ground truth per pixel) with the share of
frame-0 object pixels labelled with the right part (labels matched to parts
by the best permutation; the static group counts as a label), and the number
of rigid groups ``auto`` finds on the hinge (2), the oscillating box and the
box turning out of plane (1). Then the real clips with their masks, at the
size ``marionette extract`` reads them by default: ``davis_train`` (a toy
train, locomotive and wagons: more than one part) and two cars
(``davis_car-shadow``, ``davis_car-turn``: one rigid body), with the train's
frame-0 labels drawn to ``--figure``. ``segment_parts`` is called as
``extract_prior`` calls it, with the whole object's motion from ``fit_rigid``
as a candidate (its time counts). Writes ``docs/benchmarks/parts.md``.

    python benchmarks/bench_parts.py [--seeds 3] [--frames 32,48] [--size 320x240] [--figure /tmp/parts_davis_train.png]
"""

from __future__ import annotations

import argparse
import itertools
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small dense products; threads only contend on 2 cores

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from marionette.io import read_masks, read_video  # noqa: E402
from marionette.pipeline import DEFAULT_MAX_SIDE, source_intrinsics  # noqa: E402
from marionette.source.extract import whole_object_poses  # noqa: E402
from marionette.source.parts import OFF_OBJECT, STATIC, segment_parts  # noqa: E402
from marionette.source.rigid import ShapePrior  # noqa: E402
from marionette.source.tracks import track  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VIDEOS = ROOT.parent / "shared" / "data" / "videos"
REAL = {"davis_train": "> 1", "davis_car-shadow": "1", "davis_car-turn": "1"}  # clip: expected moving parts
COLOURS = np.array([[230, 60, 60], [60, 200, 60], [60, 90, 230], [230, 200, 40], [200, 60, 200], [40, 200, 200]])


def pixel_accuracy(pixel_labels: np.ndarray, part_mask: np.ndarray) -> float:
    """Share of object pixels labelled right under the best matching of labels to ground-truth parts."""
    on = part_mask >= 0
    found = list(np.unique(pixel_labels[on]))
    best = 0
    for perm in itertools.permutations(found, min(len(found), int(part_mask.max()) + 1)):
        best = max(best, sum(((pixel_labels == label) & (part_mask == part)).sum() for part, label in enumerate(perm)))
    return best / on.sum()


def segment(tracks, mask0: np.ndarray, k: np.ndarray, num_parts):
    """``segment_parts`` as ``extract_prior`` calls it: with the whole object's motion from ``fit_rigid``."""
    return segment_parts(tracks, mask0, k, num_parts, whole=whole_object_poses(tracks, ShapePrior.inflate(mask0, k)))


def groups(seg) -> int:
    """Moving parts plus the static group when it holds tracks."""
    return seg.num_parts + int((seg.track_labels == STATIC).any())


def draw(frame: np.ndarray, seg, uv0: np.ndarray) -> np.ndarray:
    """Frame (H, W, 3) RGB with the pixel labels tinted (static grey) and the frame-0 tracks as dots."""
    out = frame.astype(np.float32)
    for label in np.unique(seg.pixel_labels):
        if label == OFF_OBJECT:
            continue
        colour = (128, 128, 128) if label == STATIC else COLOURS[label % len(COLOURS)]
        m = seg.pixel_labels == label
        out[m] = 0.45 * out[m] + 0.55 * np.asarray(colour)
    out = out.astype(np.uint8)
    for (u, v), label in uv0:
        colour = (255, 255, 255) if label < STATIC else (128, 128, 128) if label == STATIC else COLOURS[label % 6]
        cv2.circle(out, (int(round(u)), int(round(v))), 2, tuple(int(c) for c in colour), -1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", default="32,48", help="clip lengths, comma-separated")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--figure", default="/tmp/parts_davis_train.png")
    ap.add_argument("--out", default=str(ROOT / "docs" / "benchmarks" / "parts.md"))
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))

    rows = []
    for motion, frames, seed in itertools.product(("hinge", "oscillation", "outofplane"),
                                                  [int(f) for f in args.frames.split(",")], range(args.seeds)):
        scene = make_scene(motion, seed=seed, num_frames=frames, size=size)
        tracks = track(scene.frames, scene.masks)
        t = time.perf_counter()
        seg = segment(tracks, scene.masks[0], scene.camera.K, "auto")
        elapsed = time.perf_counter() - t
        acc = pixel_accuracy(seg.pixel_labels, scene.part_masks[0]) * 100
        expected = 2 if motion == "hinge" else 1
        rows.append((motion, frames, seed, tracks.num_tracks, seg.num_parts, groups(seg), expected, acc,
                     int((seg.track_labels < STATIC).sum()), seg.noise, elapsed))
        print(f"{motion:12s} {frames} frames seed {seed}: tracks {tracks.num_tracks:4d}  moving parts {seg.num_parts}  "
              f"groups {groups(seg)}  pixel accuracy {acc:5.1f} %  noise {seg.noise:.2f} px  {elapsed:.2f} s",
              flush=True)

    real = []
    for clip, expected in REAL.items():
        if not (VIDEOS / clip).is_dir():
            continue
        video = read_video(VIDEOS / clip / "frames", max_side=DEFAULT_MAX_SIDE)
        masks = read_masks(VIDEOS / clip / "masks", count=len(video), size=video.size)
        tracks = track(video.frames, masks)
        t = time.perf_counter()
        seg = segment(tracks, masks[0], source_intrinsics(*video.size), "auto")
        elapsed = time.perf_counter() - t
        sizes = np.bincount(seg.track_labels[seg.track_labels >= 0]).tolist()
        real.append((clip, len(video), video.size, tracks.num_tracks, seg.num_parts, expected, sizes,
                     int((seg.track_labels < STATIC).sum()), seg.noise, {k: round(v) for k, v in seg.scores.items()},
                     elapsed))
        print(f"{clip}: {len(video)} frames {video.size}, tracks {tracks.num_tracks}: auto -> moving parts "
              f"{seg.num_parts} (expected {expected}; tracks per part {sizes}), noise {seg.noise:.2f} px, "
              f"{elapsed:.2f} s; scores {real[-1][9]}", flush=True)
        if clip == "davis_train":
            three = segment(tracks, masks[0], source_intrinsics(*video.size), 3)
            at0 = tracks.visible[0]
            panels = [draw(video.frames[0], s, zip(tracks.uv[0, at0], s.track_labels[at0])) for s in (seg, three)]
            cv2.imwrite(args.figure, cv2.cvtColor(np.concatenate(panels, axis=1), cv2.COLOR_RGB2BGR))

    lines = [
        "# Rigid part segmentation",
        "",
        f"`python benchmarks/bench_parts.py --seeds {args.seeds} --frames {args.frames} --size {args.size}` on "
        f"{platform.machine()}, Python {platform.python_version()}; default `segment_parts` options,"
        " `num_parts=\"auto\"`,"
        " tracks from `marionette.source.track` with its defaults.",
        "",
        "Pixel accuracy: share of frame-0 object pixels whose label matches the ground-truth part, under the best"
        " matching of labels to parts (the static group is a label like the others). Groups: moving parts plus the"
        " static group when it holds tracks (the hinge's body does not move in some seeds). Expected groups: 2 for the"
        " hinge, 1 for a rigid box. Target: >= 95 % on the hinge. σ: the noise `segment_parts` estimated (pixels; the"
        " threshold is 2 σ). Time: `segment_parts` alone, wall clock on a shared 2-core machine.",
        "",
        "| motion | frames | seed | tracks | moving parts | groups (expected) | pixel accuracy (%) | outlier tracks"
        " | σ (px) | time (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for motion, frames, seed, m, p, g, expected, acc, outliers, noise, elapsed in rows:
        lines.append(f"| {motion} | {frames} | {seed} | {m} | {p} | {g} ({expected}) | {acc:.1f} | {outliers}"
                     f" | {noise:.2f} | {elapsed:.2f} |")
    if real:
        lines += [
            "",
            f"Real clips with their masks, read as `marionette extract` reads them (long side <= {DEFAULT_MAX_SIDE},"
            " 60° horizontal field of view), `num_parts=\"auto\"`; scores per number of moving parts (lower is"
            " better; growing stops after the first that does not improve).",
            "",
            "| clip | frames | size | tracks | moving parts (expected) | tracks per part | outlier tracks | σ (px)"
            " | scores | time (s) |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for clip, t, (w, h), m, p, expected, sizes, outliers, noise, scores, elapsed in real:
            lines.append(f"| {clip} | {t} | {w}x{h} | {m} | {p} ({expected}) | {sizes} | {outliers} | {noise:.2f}"
                         f" | {scores} | {elapsed:.2f} |")
        lines += [
            "",
            f"Figure (`davis_train` at frame 0, `auto` left, `num_parts=3` right): `{args.figure}` (not in the"
            " repository).",
            "",
            "`davis_train`: one motion explains 92 % of the tracks within the threshold (2 σ), a compromise between"
            " the cars, so no track is left unexplained to seed a second part; the halves of the object tried as new"
            " parts find the locomotive against the wagons, and a third part the grey car against the red ones: the"
            " same three groups as `num_parts=3` (figure). The red cars are not split: on a track of constant"
            " curvature every car turns about the same centre by the same angle, and the per-point depths absorb"
            " most of what is left.",
            "",
            "`davis_car-turn` stays one rigid body: the whole object's motion from `fit_rigid`, the first part's"
            " extra candidate, explains 94 % of its tracks within the threshold, where the segmentation's own fit"
            " (started from a fronto-parallel surface, over the car's 90° turn) explained about half, which split"
            " the car into 4 parts before that candidate existed. `davis_car-shadow` gains 0.25-0.33 of the"
            " penalty from a second part and stays one.",
        ]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
