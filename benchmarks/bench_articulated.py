"""Articulated objects (issue 52): randomised synthetic scenes of a body with one moving part, extracted as a user
would with the part count given, scored against the truth.

Scene types (``marionette.synthetic.make_scene``): ``lid`` (a box whose lid opens 60-80° about its back edge),
``door`` (a tall cabinet whose door swings open 60-80° about its left or right upright edge), ``drawer`` (a
cabinet whose drawer is pulled out by 50-80 % of its depth) and ``screen`` (a screen swivelling 60-80° on the
upright post of its stand). Each seed draws the object's size, its textures
(rich, or in a third of the scenes plain: one colour per face), the view (a yaw of 20-40° either way, a pitch of
25-35°), whether the body stays still or turns 6-12° itself, and the image size (320x240 or 400x300).
``extract_prior`` runs with ``parts=2`` and default options. Per scene:

- joint: the model the prior's metadata gives the moving part (``hinge``, ``slider`` or ``free``; ``refused``
  when the tracks show one part and the extraction stops) against the true one;
- axis error: degrees between the fitted axis (hinge axis or direction of travel) and the true one;
- range error: for a hinge the final angle's error (degrees), for a slider the final travel's relative error
  (the true scene scaled to the prior's by their bodies' distances from the camera, as for the part motion
  error below: a part's own centroid, carved from its outline, is no measure of its scale);
- label IoU: the frame-0 part labels against the true part masks, the mean over the two parts under the best
  matching;
- body error: the body's largest rotation error over the clip (degrees), and the time of the extraction;
- part motion error: where the moving part's found motion (relative to frame 0) carries the true part's centre,
  against where it is, the largest over the clip, as a share of the part's extent (the true scene scaled to the
  prior's by their bodies' distances from the camera): a joint's scale too (a slider's travel, a hinge's axis
  point), which a still body leaves to the extraction.

    flock /tmp/marionette-bench.lock python benchmarks/bench_articulated.py [--scenes 32]

Writes ``docs/benchmarks/articulated.md`` and ``docs/images/articulated_labels.png`` (frames and part labels of
one scene of each type and texture).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from marionette.errors import InputError  # noqa: E402
from marionette.geometry import rotation_angle_deg  # noqa: E402
from marionette.source import ExtractOptions  # noqa: E402
from marionette.source.extract import extract_prior  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "articulated.md"
SHEET = ROOT / "docs" / "images" / "articulated_labels.png"
#: Scene type: (motion, object, the true joint).
KINDS = {"lid": ("hinge", "hinge", "hinge"), "door": ("hinge", "door", "hinge"),
         "drawer": ("slide", "drawer", "slider"), "screen": ("hinge", "screen", "hinge")}
SIZES = ((320, 240), (400, 300))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two lines (directions up to sign)."""
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))))))


def score(kind: str, seed: int, *, size: tuple[int, int] | None = None, num_frames: int = 32) -> dict:
    """One scene extracted and scored; its image size and texture drawn from ``seed`` unless ``size`` is given
    (then rich)."""
    rng = np.random.default_rng(seed)
    drawn = SIZES[int(rng.integers(len(SIZES)))]
    plain = bool(rng.random() < 1 / 3) and size is None
    size = size or drawn
    motion, obj, _ = KINDS[kind]
    scene = make_scene(motion, object=obj, seed=seed, num_frames=num_frames, size=size, plain=plain)
    start = time.perf_counter()
    try:
        prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=ExtractOptions(parts=2))
    except InputError:  # the tracks do not show two parts: the command stops and says so
        return {"kind": kind, "seed": seed, "size": f"{size[0]}x{size[1]}", "plain": plain, "parts": 1,
                "body_moves": bool(rotation_angle_deg(scene.poses[0][:, :3, :3]).max() > 1.0), "label_iou": 0.0,
                "time": time.perf_counter() - start, "body_error": None, "joint": "refused", "axis_error": None,
                "range_error": None, "motion_error": None}
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
    row = {"kind": kind, "seed": seed, "size": f"{size[0]}x{size[1]}", "plain": plain, "parts": prior.num_parts,
           "body_moves": bool(rotation_angle_deg(scene.poses[0][:, :3, :3]).max() > 1.0),
           "label_iou": float(np.mean(ious)), "time": elapsed,
           "body_error": float(rotation_angle_deg(prior.poses[body][:, :3, :3]
                                                  @ np.swapaxes(scene.poses[0][:, :3, :3], -1, -2)).max())}
    row["motion_error"] = None if moving is None else _motion_error(scene, prior, body, moving)
    joint = (prior.metadata.get("joints") or {}).get(str(moving), {"model": "free"}) if moving is not None else \
        {"model": "none"}
    row["joint"] = joint["model"]
    row["axis_error"] = row["range_error"] = None
    if joint["model"] == "hinge" == KINDS[kind][2]:
        rotvec = _rotvec(relative[-1, :3, :3])
        row["axis_error"] = _angle(np.asarray(joint["axis"]), rotvec)
        row["range_error"] = abs(max(np.abs(joint["range_deg"])) - np.degrees(np.linalg.norm(rotvec)))
    elif joint["model"] == "slider" == KINDS[kind][2]:
        travel = relative[-1, :3, :3] @ centre + relative[-1, :3, 3] - centre
        row["axis_error"] = _angle(np.asarray(joint["axis"]), travel)
        found = max(np.abs(joint["range"])) / _scale(scene, prior, body)
        row["range_error"] = abs(found / np.linalg.norm(travel) - 1.0) * 100
    row["sheet"] = _sheet_row(scene, labels, body)
    return row


def _scale(scene, prior, body: int) -> float:
    """The prior's units per the scene's: the distances of their bodies (the prior's part ``body``) from the
    camera at frame 0."""
    return float(np.linalg.norm(prior.centroids[body, 0]) / np.linalg.norm(scene.part_points[0].mean(axis=0)))


def _motion_error(scene, prior, body: int, moving: int) -> float:
    """The part motion error (module docstring) of the prior's part ``moving``, its body ``body``."""
    truth = scene.part_points[1]
    extent = np.linalg.norm(truth - truth.mean(axis=0), axis=1).max()
    centres = np.einsum("tij,j->ti", scene.poses[1][:, :3, :3], truth.mean(axis=0)) + scene.poses[1][:, :3, 3]
    scale = _scale(scene, prior, body)
    relative = prior.poses[moving] @ np.linalg.inv(prior.poses[moving][0])
    carried = np.einsum("tij,j->ti", relative[:, :3, :3], scale * centres[0]) + relative[:, :3, 3]
    return float(np.linalg.norm(carried / scale - centres, axis=1).max() / extent)


def _sheet_row(scene, labels: np.ndarray, body: int) -> np.ndarray:
    """(120, 480, 3) uint8: the first and last frames, the part labels found (body red, moving part green) and
    the true ones, each 160x120."""
    colours = np.array([(210, 70, 70), (70, 190, 90)], np.uint8)

    def paint(part_of: np.ndarray) -> np.ndarray:
        out = np.zeros(part_of.shape + (3,), np.uint8)
        for index, colour in enumerate(colours):
            out[part_of == index] = colour
        return out

    found = np.where(labels < 0, -1, np.where(labels == body, 0, 1))
    tiles = [scene.frames[0], scene.frames[-1], paint(found), paint(scene.part_masks[0])]
    return np.hstack([cv2.resize(tile, (160, 120), interpolation=cv2.INTER_AREA) for tile in tiles])


def _rotvec(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def _median(values) -> str:
    values = [v for v in values if v is not None]
    return f"{statistics.median(values):.2f}" if values else "–"


def _worst(values) -> str:
    values = [v for v in values if v is not None]
    return f"{max(values):.2f}" if values else "–"


#: A joint whose type is right and whose axis is within this (degrees) of the true one counts as found.
AXIS_FOUND_DEG = 10.0


def _found(r: dict) -> bool:
    return r["joint"] == KINDS[r["kind"]][2] and r["axis_error"] is not None and r["axis_error"] <= AXIS_FOUND_DEG


def _group_row(label: str, group: list[dict]) -> str:
    right = sum(r["joint"] == KINDS[r["kind"]][2] for r in group)
    found = sum(_found(r) for r in group)
    return (f"| {label} | {len(group)} | {right} of {len(group)} | {found} | {_median(r['axis_error'] for r in group)} "
            f"| {_median(r['range_error'] for r in group)} | {_median(r['label_iou'] for r in group)} "
            f"| {_median(r['body_error'] for r in group)} | {_median(r['motion_error'] for r in group)} "
            f"| {_median(r['time'] for r in group)} |")


def time_at_size(size=(640, 480), num_frames: int = 50, seed: int = 200) -> list[dict]:
    """One rich clip of each type at issue 52's size, extracted (``parts=2``) and scored: its time and what was
    found."""
    return [score(kind, seed, size=size, num_frames=num_frames) for kind in KINDS]


def _timed(r: dict) -> str:
    """A timed clip: its time, the joint found and how far off."""
    found = r["joint"]
    if r["range_error"] is not None:
        found += f", {r['range_error']:.1f}{'°' if found == 'hinge' else ' %'} off"
    return f"{r['kind']} {r['time']:.1f} s ({found})"


def report(rows: list[dict], scenes: int, timed: list[dict]) -> str:
    lines = [
        "# Articulated objects: randomised scenes",
        "",
        f"`python benchmarks/bench_articulated.py --scenes {scenes}` on {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}. The scenes, the extraction and the scores "
        "are in the script's docstring. Range error: degrees for a hinge's final angle, per cent for a slider's "
        "final travel; axis and range errors only where the joint found is the true one (medians).",
        "",
        "![first and last frames, part labels found (body red, moving part green), true labels: one scene of each "
        "type, rich then plain](../images/articulated_labels.png)",
        "",
        f"| scenes | count | joint right | and axis ≤ {AXIS_FOUND_DEG:.0f}° | axis error ° | range error "
        "| label IoU | body error ° | part motion error | time s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for kind in KINDS:
        for moves in (False, True):
            group = [r for r in rows if r["kind"] == kind and r["body_moves"] == moves]
            if group:
                lines.append(_group_row(f"{kind}, body {'turning' if moves else 'still'}", group))
    for plain in (False, True):
        group = [r for r in rows if r["plain"] == plain]
        if group:
            lines.append(_group_row(f"all, {'plain' if plain else 'rich'} textures", group))
    def right_of(r: dict) -> str:
        return KINDS[r["kind"]][2]
    right = sum(r["joint"] == right_of(r) for r in rows)
    doors = [r for r in rows
             if r["kind"] == "door" and not r["plain"] and not r["body_moves"] and r["joint"] == "hinge"]
    lines += ["", f"Joint type right in {right} of {len(rows)} scenes ({100 * right / len(rows):.0f} %; issue 52's "
              f"target 90 %), with its axis within {AXIS_FOUND_DEG:.0f}° too in {sum(_found(r) for r in rows)}; "
              "label IoU median "
              f"{_median(r['label_iou'] for r in rows)} (target 0.9); body error median "
              f"{_median(r['body_error'] for r in rows)}° (target 0.5°; "
              f"{_median(r['body_error'] for r in rows if r['body_moves'])}° where the body turns). Hinges' final "
              f"angle error median {_median(r['range_error'] for r in rows if r['joint'] == 'hinge' == right_of(r))}° "
              "(target 2°). Textured doors on a still body (the issue's independent scene): final-angle error "
              f"median {_median(r['range_error'] for r in doors)}°, worst {_worst(r['range_error'] for r in doors)}° "
              f"(target 1°), body worst {_worst(r['body_error'] for r in doors)}° (target 0.5°). Part motion error "
              f"median {_median(r['motion_error'] for r in rows)} of the part's extent "
              f"({_median(r['motion_error'] for r in rows if not r['body_moves'])} on a still body).", "",
              "Time at issue 52's size (50 frames 640x480, `--parts 2`, one rich clip of each type, seed 200; the "
              "joint found and its final angle's or travel's error): " + ", ".join(_timed(r) for r in timed)
              + f"; median {statistics.median(r['time'] for r in timed):.1f} s (target 30 s).", "",
              "Per scene:", "",
              "| scene | seed | size | texture | body | parts | joint | axis error ° | range error | label IoU "
              "| body error ° | part motion error | time s |",
              "|---|---:|---|---|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        fmt = (lambda v: "–" if v is None else f"{v:.2f}")
        lines.append(f"| {r['kind']} | {r['seed']} | {r['size']} | {'plain' if r['plain'] else 'rich'} "
                     f"| {'turning' if r['body_moves'] else 'still'} | {r['parts']} | {r['joint']} "
                     f"| {fmt(r['axis_error'])} | {fmt(r['range_error'])} | {r['label_iou']:.3f} "
                     f"| {fmt(r['body_error'])} | {fmt(r['motion_error'])} | {r['time']:.1f} |")
    lines += ["", READING, ""]
    return "\n".join(lines)


READING = (
    "Reading: the parts come from the tracks, where the set of local motions that explains them best finds a drawer "
    "in a turning cabinet that the motions grown from a compromise miss (`source/parts.py`); the labels from what "
    "each part's motion predicts for every pixel, each pixel tested on the surface of the part it is tested for "
    "(`source/part_pixels.py`); a plain door or lid, too plain for its few tracks to make a part, is split from a "
    "still body by the pixels that keep their colour and has its joint fitted to its pixels on the faces of the box "
    "the first frame's outline shows (`source/pixel_joint.py`). A turning body is fitted with its points held on that "
    "box, which brings its turn within about 2° (5° free: a small turn trades against the depths). On a still body a "
    "joint's scale is not in its tracks (the part and its joint scaled together about the camera change no image, and "
    "each track's own depth trades against it): a slider's travel and a hinge's axis are scaled to put the part's "
    "frame-0 tracks on the faces of that box, or else the inflated outline, which the part is part of at frame 0 "
    "(`source/joint_tracks.py` `surface_scale`; before, the part motion error's median on a still body was 0.21 of "
    "the part's extent). Joints are fitted to and judged by the tracks off the seams between parts (a seam track's "
    "window is on both parts; with them a hinge fitted a drawer on a turning cabinet better than a slider), and the "
    "body is the part the other's joint is kept on before the one under which the tracks are explained best (a thin "
    "drawer's free fit, 12° off, explained them better than its cabinet). A hinge whose fits from the free poses "
    "leave many tracks out (a lid the free fit loses once it turns edge-on) is fitted once more from its first half "
    "carried on (lid 100: 39° → 63° of 72°). A hinge, once chosen, is fitted again to its tracks re-aligned to their "
    "seed windows (`source/seed_align.py`; lid 100 → 68°, the lids' median final-angle error 6.2° → 3.7°), and frames "
    "no track of it sees are placed from its pixels and the mask (a screen turned away: screen 102's last nine "
    "frames, which the tracks' fit had swing back to 4-35°, now follow the turn to 71° of 67°), as are the frames "
    "after such a run that only tracks seeded after it see (a door's other face, come into view: they fix their own "
    "depths; door 107 2.7° → 1.3°). What is still missed: a plain drawer keeps its colour as it slides, so the pixels "
    "give it only its border, and a hinge along that explains it better than a slider; a drawer whose cabinet's "
    "tracks below it are covered as it slides out (the tracks slip onto it and the segmentation gives it half the "
    "cabinet's front); a plain body that turns a few degrees is taken for a still one (its faces keep their colour); "
    "a lid's angle from its re-aligned tracks still comes out a few percent short or long at every frame (its turn "
    "against its relief, which only perspective tells apart: on exact tracks the hinge fit is within 0.1°, "
    "docs/benchmarks/lid_information.md); a screen on a small stand that turns is fitted with the stand hinged on it "
    "(the joints explain the tracks best that way; the joint is then told from the stand), and the stand's poses, "
    "carried by the screen's free fit, come out 13-19° off, the axis 11-17°.")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=32, help="scenes in all, a quarter of each type")
    args = parser.parse_args()
    rows = []
    for index in range(args.scenes):
        kind = tuple(KINDS)[index % len(KINDS)]
        rows.append(score(kind, 100 + index // len(KINDS)))
        r = rows[-1]
        print(f"{kind} seed {r['seed']}: joint {r['joint']}, axis {r['axis_error']}, range {r['range_error']}, "
              f"motion {r['motion_error']}, "
              f"label IoU {r['label_iou']:.3f}, body {r['body_error']}°, {r['time']:.1f} s", flush=True)
    timed = time_at_size()
    print("time at 640x480, 50 frames:", ", ".join(_timed(r) for r in timed), flush=True)
    OUT.write_text(report(rows, args.scenes, timed))
    # One scene of each type and texture: frames, labels found, true labels.
    picked = [next(r for r in rows if r["kind"] == kind and r["plain"] == plain and "sheet" in r)
              for kind in KINDS for plain in (False, True)
              if any(r["kind"] == kind and r["plain"] == plain and "sheet" in r for r in rows)]
    cv2.imwrite(str(SHEET), cv2.cvtColor(np.vstack([r["sheet"] for r in picked]), cv2.COLOR_RGB2BGR))
    print(f"wrote {OUT} and {SHEET}")


if __name__ == "__main__":
    main()
