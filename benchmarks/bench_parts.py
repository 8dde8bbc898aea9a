"""Accuracy and speed of ``segment_parts`` on the synthetic scenes and on ``davis_train``.

Per seed: the hinge (body and lid; ground truth per pixel) with the share of
frame-0 object pixels labelled with the right part (labels matched to parts
by the best permutation; the static group counts as a label), and the number
of rigid groups ``auto`` finds on the hinge (2), the oscillating box and the
box turning out of plane (1). Then the real clip ``davis_train`` (a toy train,
locomotive and wagons), with its frame-0 labels drawn to ``--figure``.
Writes ``docs/benchmarks/parts.md``.

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

from marionette.camera import Camera  # noqa: E402
from marionette.io import read_masks, read_video  # noqa: E402
from marionette.source.parts import OFF_OBJECT, STATIC, segment_parts  # noqa: E402
from marionette.source.tracks import track  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DAVIS_TRAIN = ROOT.parent / "shared" / "data" / "videos" / "davis_train"
COLOURS = np.array([[230, 60, 60], [60, 200, 60], [60, 90, 230], [230, 200, 40], [200, 60, 200], [40, 200, 200]])


def pixel_accuracy(pixel_labels: np.ndarray, part_mask: np.ndarray) -> float:
    """Share of object pixels labelled right under the best matching of labels to ground-truth parts."""
    on = part_mask >= 0
    found = list(np.unique(pixel_labels[on]))
    best = 0
    for perm in itertools.permutations(found, min(len(found), int(part_mask.max()) + 1)):
        best = max(best, sum(((pixel_labels == label) & (part_mask == part)).sum() for part, label in enumerate(perm)))
    return best / on.sum()


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
        seg = segment_parts(tracks, scene.masks[0], scene.camera.K, "auto")
        elapsed = time.perf_counter() - t
        acc = pixel_accuracy(seg.pixel_labels, scene.part_masks[0]) * 100
        expected = 2 if motion == "hinge" else 1
        rows.append((motion, frames, seed, tracks.num_tracks, seg.num_parts, groups(seg), expected, acc,
                     int((seg.track_labels < STATIC).sum()), seg.noise, elapsed))
        print(f"{motion:12s} {frames} frames seed {seed}: tracks {tracks.num_tracks:4d}  moving parts {seg.num_parts}  "
              f"groups {groups(seg)}  pixel accuracy {acc:5.1f} %  noise {seg.noise:.2f} px  {elapsed:.2f} s", flush=True)

    davis = None
    if DAVIS_TRAIN.is_dir():
        video = read_video(DAVIS_TRAIN / "frames", max_side=480)
        masks = read_masks(DAVIS_TRAIN / "masks", count=len(video), size=video.size)
        tracks = track(video.frames, masks)
        K = Camera.from_fov(*video.size).K
        results = {}
        for parts in ("auto", 3):
            t = time.perf_counter()
            results[parts] = (segment_parts(tracks, masks[0], K, parts), time.perf_counter() - t)
        seg, elapsed = results["auto"]
        at0 = tracks.visible[0]
        panels = [draw(video.frames[0], s, zip(tracks.uv[0, at0], s.track_labels[at0])) for s, _ in results.values()]
        cv2.imwrite(args.figure, cv2.cvtColor(np.concatenate(panels, axis=1), cv2.COLOR_RGB2BGR))
        sizes = np.bincount(seg.track_labels[seg.track_labels >= 0])
        davis = (len(video), video.size, tracks.num_tracks, seg.num_parts, groups(seg), sizes.tolist(),
                 int((seg.track_labels < STATIC).sum()), elapsed, results[3][1], seg.scores, seg.noise)
        print(f"davis_train: {len(video)} frames {video.size}, tracks {tracks.num_tracks}: auto -> moving parts "
              f"{seg.num_parts} (tracks per part {sizes.tolist()}, outliers {davis[6]}), noise {seg.noise:.2f} px, {elapsed:.2f} s; "
              f"scores {({k: round(v) for k, v in seg.scores.items()})}; figure {args.figure}")

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
    if davis is not None:
        t, (w, h), m, p, g, sizes, outliers, elapsed, elapsed3, scores, noise = davis
        lines += [
            "",
            f"Real clip `davis_train` ({t} frames at {w}x{h}, {m} tracks): `auto` gives {p} moving part(s)"
            f" (tracks per part {sizes}, {outliers} outlier tracks), estimated σ {noise:.2f} px, {elapsed:.2f} s; scores"
            f" {({k: round(v) for k, v in scores.items()})}. `num_parts=3`: {elapsed3:.2f} s."
            f" Figure (frame 0, `auto` left, `num_parts=3` right): `{args.figure}` (not in the repository).",
            "",
            "Open: the train is not split. Tracks under the rigid motion of their 12-track patch leave 0.39 px"
            " (median RMS), under one motion of the whole train 0.74 px; motions fitted to the frame-0 tracks of"
            " the locomotive, the grey car and the red car explain their own tracks to 0.50 / 0.49 / 0.95 px, one"
            " motion of all of them to 0.51 / 0.58 / 0.73 px (all frames). On a track of constant curvature every"
            " car turns about the same centre by the same angle, so the cars differ only where the curvature"
            " changes, and the per-point depths absorb most of the rest over a track's life (median 34 of 80"
            " frames): the evidence per track is within the noise, and the sequential growth, which seeds a new"
            " part only on tracks no motion explains, finds none.",
        ]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
