"""Articulated objects (issue 52): randomised synthetic scenes of a body with one moving part, extracted as a user
would with the part count given, scored against the truth.

Scene types (``marionette.synthetic.make_scene``): ``hinge`` (a box whose lid opens 60-80° about its back edge)
and ``slide`` (a cabinet whose drawer is pulled out by 50-80 % of its depth). Each seed draws the object's size,
its textures, the view (a yaw of 20-40° either way, a pitch of 25-35°), whether the body stays still or turns
6-12° itself, and the image size (320x240 or 400x300). ``extract_prior`` runs with ``parts=2`` and default
options. Per scene:

- joint: the model the prior's metadata gives the moving part (``hinge``, ``slider`` or ``free``) against the
  true one;
- axis error: degrees between the fitted axis (hinge axis or direction of travel) and the true one;
- range error: for a hinge the final angle's error (degrees), for a slider the final travel's relative error
  (both measured against the part's distance from the camera, which the prior's scale leaves free);
- label IoU: the frame-0 part labels against the true part masks, the mean over the two parts under the best
  matching;
- body error: the body's largest rotation error over the clip (degrees), and the time of the extraction.

    flock /tmp/marionette-bench.lock python benchmarks/bench_articulated.py [--scenes 24]

Writes ``docs/benchmarks/articulated.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from marionette.geometry import rotation_angle_deg  # noqa: E402
from marionette.source import ExtractOptions  # noqa: E402
from marionette.source.extract import extract_prior  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "articulated.md"
TRUE_JOINT = {"hinge": "hinge", "slide": "slider"}
SIZES = ((320, 240), (400, 300))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two lines (directions up to sign)."""
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))))))


def score(kind: str, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    size = SIZES[int(rng.integers(len(SIZES)))]
    scene = make_scene(kind, seed=seed, num_frames=32, size=size)
    start = time.perf_counter()
    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts=2))
    elapsed = time.perf_counter() - start
    labels, truth = prior.extras["labels"], scene.part_masks[0]
    # The prior's part that is the true body: the one whose frame-0 labels overlap the true body most.
    body = int(np.argmax([((labels == p) & (truth == 0)).sum() for p in range(prior.num_parts)]))
    moving = 1 - body if prior.num_parts == 2 else None
    ious = []
    for true_part, part in ((0, body), (1, moving)):
        found, true = labels == part, truth == true_part
        ious.append(float((found & true).sum() / max((found | true).sum(), 1)))
    relative = np.linalg.inv(scene.poses[0]) @ scene.poses[1]
    centre = scene.part_points[1].mean(axis=0)
    row = {"kind": kind, "seed": seed, "size": f"{size[0]}x{size[1]}", "parts": prior.num_parts,
           "body_moves": bool(rotation_angle_deg(scene.poses[0][:, :3, :3]).max() > 1.0),
           "label_iou": float(np.mean(ious)), "time": elapsed,
           "body_error": float(rotation_angle_deg(prior.poses[body][:, :3, :3]
                                                  @ np.swapaxes(scene.poses[0][:, :3, :3], -1, -2)).max())}
    joint = (prior.metadata.get("joints") or {}).get(str(moving), {"model": "free"}) if moving is not None else \
        {"model": "none"}
    row["joint"] = joint["model"]
    row["axis_error"] = row["range_error"] = None
    if joint["model"] == "hinge" and kind == "hinge":
        rotvec = _rotvec(relative[-1, :3, :3])
        row["axis_error"] = _angle(np.asarray(joint["axis"]), rotvec)
        row["range_error"] = abs(max(np.abs(joint["range_deg"])) - np.degrees(np.linalg.norm(rotvec)))
    elif joint["model"] == "slider" and kind == "slide":
        travel = relative[-1, :3, :3] @ centre + relative[-1, :3, 3] - centre
        row["axis_error"] = _angle(np.asarray(joint["axis"]), travel)
        true_share = np.linalg.norm(travel) / np.linalg.norm(centre)
        found_share = max(np.abs(joint["range"])) / np.linalg.norm(prior.centroids[moving, 0])
        row["range_error"] = abs(found_share / true_share - 1.0) * 100
    return row


def _rotvec(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def _median(values) -> str:
    values = [v for v in values if v is not None]
    return f"{statistics.median(values):.2f}" if values else "–"


def report(rows: list[dict], scenes: int) -> str:
    lines = [
        "# Articulated objects: randomised scenes",
        "",
        f"`python benchmarks/bench_articulated.py --scenes {scenes}` on {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}. The scenes, the extraction and the scores "
        "are in the script's docstring. Range error: degrees for a hinge's final angle, per cent for a slider's "
        "final travel; axis and range errors only where the joint found is the true one.",
        "",
        "| scene | scenes | joint right | axis error ° (median) | range error (median) | label IoU (median) "
        "| body error ° (median) | time s (median) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for kind in TRUE_JOINT:
        for moves in (False, True):
            group = [r for r in rows if r["kind"] == kind and r["body_moves"] == moves]
            if not group:
                continue
            right = sum(r["joint"] == TRUE_JOINT[kind] for r in group)
            lines.append(f"| {kind}, body {'turning' if moves else 'still'} | {len(group)} | {right} of {len(group)} "
                         f"| {_median(r['axis_error'] for r in group)} | {_median(r['range_error'] for r in group)} "
                         f"| {_median(r['label_iou'] for r in group)} | {_median(r['body_error'] for r in group)} "
                         f"| {_median(r['time'] for r in group)} |")
    right = sum(r["joint"] == TRUE_JOINT[r["kind"]] for r in rows)
    lines += ["", f"Joint type right in {right} of {len(rows)} scenes ({100 * right / len(rows):.0f} %; issue 52's "
              "target 90 %); label IoU median "
              f"{_median(r['label_iou'] for r in rows)} (target 0.9); body error median "
              f"{_median(r['body_error'] for r in rows)}° (target 0.5°).", "", "Per scene:", "",
              "| scene | seed | size | body | parts | joint | axis error ° | range error | label IoU | body error ° "
              "| time s |", "|---|---:|---|---|---:|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        fmt = (lambda v: "–" if v is None else f"{v:.2f}")
        lines.append(f"| {r['kind']} | {r['seed']} | {r['size']} | {'turning' if r['body_moves'] else 'still'} "
                     f"| {r['parts']} | {r['joint']} | {fmt(r['axis_error'])} | {fmt(r['range_error'])} "
                     f"| {r['label_iou']:.3f} | {r['body_error']:.2f} | {r['time']:.1f} |")
    lines += ["", READING, ""]
    return "\n".join(lines)


READING = (
    "Reading: where the drawer or lid's tracks are its own, the joint comes out right (a still cabinet's drawer "
    "as a slider, a lid as a hinge). The label IoU shows what holds the rest back: a drawer pulled out over its "
    "cabinet's front hides the front's tracks, which then follow the drawer, so the cabinet's lower front is "
    "labelled with it; with those tracks in, and where the cabinet turns too, a hinge about a far axis fits "
    "the drawer's tracks better than one direction of travel and is kept (issue 52, item 2: part discovery "
    "that does not lean on the tracks alone).")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=24, help="scenes in all, half of each type")
    args = parser.parse_args()
    rows = []
    for index in range(args.scenes):
        kind = ("hinge", "slide")[index % 2]
        rows.append(score(kind, 100 + index // 2))
        r = rows[-1]
        print(f"{kind} seed {r['seed']}: joint {r['joint']}, axis {r['axis_error']}, range {r['range_error']}, "
              f"label IoU {r['label_iou']:.3f}, body {r['body_error']:.2f}°, {r['time']:.1f} s", flush=True)
    OUT.write_text(report(rows, args.scenes))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
