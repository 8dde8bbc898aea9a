"""The single-photo lift from every side (issue 17): novel views against the truth, photos turned, speed.

1. Novel views. Synthetic objects of known shape (``object_view``: a box, a squat can, a vase, a thin
   rod; seed 0, 256x256, 30° field of view, the camera level with the object) are seen frontally (yaw 0)
   and at three-quarters (yaw 30). Each still is lifted in its true camera, its mid-surface at the true
   centre's depth, then turned 30°, 60°, 90° and 180° about the camera's vertical axis through that
   centre and rendered, against the true render turned alike: PSNR over the union of the two
   silhouettes, SSIM over the image (scikit-image), silhouette IoU (alpha > 0.5 against coverage > 0.5).
   Rows: the shape prior chosen automatically (also with ``POLISH`` steps of ``--polish``) and each one
   forced; ``--baseline FILE`` adds the rows saved (``--save FILE``) by this script run on an earlier
   version.
2. Photos. Every image in ``../shared/data/images`` (skipped when absent) lifted as ``transfer`` lifts
   it and turned 0°, 45°, 90° and 180° about the vertical through its centre: one contact sheet per run
   (``--label``), ``docs/images/lift_photos_<label>.png``.
3. Speed. Lifting a synthetic 512² and 1024² photo (vase, box): median of ``--runs`` runs, and the
   number of Gaussians.
4. Single-frame self-transfer (``--clips``, needs ``../shared/data``): ``eval_self(target="frame0")`` on
   davis_car-shadow, davis_car-turn and davis_train (parts 1, 1, 4 as in ``bench_table1.py``): PSNR at
   frame 0, over the whole clip and over its last third, where the object shows the sides frame 0 hid.

Writes ``docs/benchmarks/lift.md`` and ``docs/images/lift_views.png`` (truth above, lift below, per object).

    flock /tmp/marionette-bench.lock python benchmarks/bench_lift.py [--clips] [--baseline FILE] [--save FILE]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "lift.md"
IMAGES = ROOT / "docs" / "images"
PHOTOS = ROOT.parent / "shared" / "data" / "images"
VIDEOS = ROOT.parent / "shared" / "data" / "videos"
CLIPS = {"car-shadow": ("davis_car-shadow", 1), "car-turn": ("davis_car-turn", 1), "train": ("davis_train", 4)}
OBJECTS = ("box", "cylinder", "vase", "rod")
STARTS = {"frontal": 0.0, "three-quarter": 30.0}
TURNS = (30, 60, 90, 180)
SIZE = (256, 256)
FOV = 30.0
POLISH = 10


def lift(image: np.ndarray, shape: str | None, **kwargs):
    """Lift with a shape prior when this version has them (``shape`` None: the version's only lift;
    ``"polish"``: the automatic prior with ``POLISH`` steps of photometric polish)."""
    from marionette.target.lift import LiftOptions, lift_image

    options = LiftOptions(depth=kwargs.pop("depth")) if "depth" in kwargs else LiftOptions()
    if shape == "polish":
        options = dataclasses.replace(options, polish=POLISH)
    elif shape is not None:
        options = dataclasses.replace(options, shape=shape)
    return lift_image(image, options=options, **kwargs)


def turned(gaussians, degrees: float, centre: np.ndarray):
    """Gaussians turned about the camera's vertical axis through ``centre`` (3,)."""
    from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion

    r = axis_angle_to_matrix([0.0, np.radians(degrees), 0.0])
    return gaussians.with_means((gaussians.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r))


def compare(truth: np.ndarray, image: np.ndarray, alpha: np.ndarray) -> dict:
    """PSNR over the silhouettes' union, SSIM, silhouette IoU of a render (H, W, 3) uint8 against an RGBA truth."""
    from skimage.metrics import structural_similarity

    true_mask, mask = truth[..., 3] > 0, alpha > 0.5
    union = true_mask | mask
    mse = float(((truth[..., :3].astype(np.float64) - image) ** 2)[union].mean())
    return {"psnr": 10 * np.log10(255.0**2 / max(mse, 1e-12)),
            "ssim": float(structural_similarity(truth[..., :3], image, channel_axis=2, data_range=255)),
            "iou": float((true_mask & mask).sum() / max(union.sum(), 1))}


def novel_views(shapes: list[str | None]) -> tuple[dict, np.ndarray]:
    """{method: {start: {object: {turn: metrics}}}} and a contact sheet (truth above each method's lift)."""
    from marionette.render import render
    from marionette.synthetic import object_view

    results: dict = {}
    rows = []
    for obj in OBJECTS:
        for start, yaw in STARTS.items():
            photo, camera, centre = object_view(obj, size=SIZE, seed=0, yaw_deg=yaw, pitch_deg=0.0, fov_deg=FOV)
            truths = {t: object_view(obj, size=SIZE, seed=0, yaw_deg=yaw, pitch_deg=0.0, fov_deg=FOV, turn_deg=t)[0]
                      for t in (0, *TURNS)}
            rows.append(np.concatenate([truths[t][..., :3] for t in (0, *TURNS)], axis=1))
            for shape in shapes:
                lifted = lift(photo, shape, camera=camera, depth=float(centre[2]))
                method = {None: "auto", "polish": f"auto, --polish {POLISH}"}.get(shape, shape)
                row = []
                for t in (0, *TURNS):
                    out = render(turned(lifted.gaussians, t, centre), camera)
                    image = np.clip(np.rint(out.image * 255), 0, 255).astype(np.uint8)
                    results.setdefault(method, {}).setdefault(start, {}).setdefault(obj, {})[str(t)] = \
                        compare(truths[t], image, out.alpha)
                    row.append(image)
                if method == "auto":
                    rows.append(np.concatenate(row, axis=1))
    return results, np.concatenate(rows, axis=0)


def photo_sheet(label: str) -> Path | None:
    """Every shared photo lifted and turned 0/45/90/180 degrees: ``docs/images/lift_photos_<label>.png``."""
    import cv2

    from marionette.io.video import read_image
    from marionette.render import render
    from marionette.target.lift import alpha_mask

    files = sorted(p for p in PHOTOS.glob("*/*.png") if p.name not in ("mask.png", "image.png")) \
        if PHOTOS.is_dir() else []
    if not files:
        return None
    rows = []
    for path in files:
        image = read_image(path)
        if image.shape[0] > 512:
            image = cv2.resize(image, (512, 512), interpolation=cv2.INTER_AREA)
        mask = alpha_mask(image)
        lifted = lift(image, None, mask=mask)
        g = lifted.gaussians
        centre = 0.5 * (g.means.min(axis=0) + g.means.max(axis=0))
        views = [np.clip(render(turned(g, t, centre), lifted.camera).image * 255, 0, 255).astype(np.uint8)
                 for t in (0, 45, 90, 180)]
        rows.append(cv2.resize(np.concatenate(views, axis=1), (4 * 256, 256), interpolation=cv2.INTER_AREA))
    out = IMAGES / f"lift_photos_{label}.png"
    cv2.imwrite(str(out), cv2.cvtColor(np.concatenate(rows, axis=0), cv2.COLOR_RGB2BGR))
    return out


def speed(runs: int, shape: str | None) -> list[tuple[str, int, int, float]]:
    """(object, side, Gaussians, median seconds) of lifting synthetic photos."""
    from marionette.synthetic import render_object_image

    rows = []
    for side in (512, 1024):
        for obj in ("vase", "box"):
            image = render_object_image(obj, size=(side, side), seed=0)
            times = []
            for _ in range(runs):
                t0 = time.perf_counter()
                lifted = lift(image, shape)
                times.append(time.perf_counter() - t0)
            rows.append((obj, side, len(lifted.gaussians), statistics.median(times)))
    return rows


def self_transfer(out: Path) -> dict[str, dict[str, float]]:
    """{clip: PSNR at frame 0, over the clip and over its last third} of the frame-0 self-transfer."""
    import csv

    from marionette.eval import EVAL_EXTRACT, eval_self

    rows = {}
    out.mkdir(parents=True, exist_ok=True)
    for name, (clip, parts) in CLIPS.items():
        folder = VIDEOS / clip
        if not (folder / "frames").is_dir():
            continue
        eval_self(folder / "frames", folder / "masks", out / name, target="frame0", fidelity=False,
                  options=dataclasses.replace(EVAL_EXTRACT, parts=parts))
        with open(out / name / "frames.csv") as f:
            psnr = [float(row["psnr"]) for row in csv.DictReader(f)]
        third = len(psnr) - len(psnr) // 3
        rows[name] = {"frame0": psnr[0], "all": float(np.mean(psnr)), "last_third": float(np.mean(psnr[third:]))}
    return rows


def mean_over(results: dict, method: str, turn: int, key: str, objects=OBJECTS) -> float:
    return float(np.mean([results[method][s][o][str(turn)][key] for s in STARTS for o in objects]))


def report(results: dict, speeds: dict[str, list], clips: dict[str, dict], label: str,
           sheets: dict[str, Path | None], runs: int) -> str:
    methods = list(results)
    lines = ["# The single-photo lift from every side", "",
             f"`python benchmarks/bench_lift.py` on {platform.machine()}, Python {platform.python_version()} "
             f"({label}). Synthetic objects of known shape ({', '.join(OBJECTS)}; seed 0, {SIZE[0]}x{SIZE[1]}, "
             f"{FOV:.0f}° field of view, camera level with the object), seen frontally and at three-quarters, "
             "lifted from that one view and turned about the camera's vertical axis through the object's centre. "
             "PSNR over the union of the true and rendered silhouettes, SSIM over the image, silhouette IoU; "
             "means over the four objects and both starting views. Issue 17's targets: IoU >= 0.9 at 90° for "
             "revolved and boxy objects, and >= 3 dB over the baseline at 60-90°.", ""]
    for key, name in (("iou", "silhouette IoU"), ("psnr", "PSNR (dB)"), ("ssim", "SSIM")):
        lines += [f"**{name}**", "", "| lift | 0° | " + " | ".join(f"{t}°" for t in TURNS) + " |",
                  "|---|" + "---:|" * (1 + len(TURNS))]
        for m in methods:
            vals = [mean_over(results, m, t, key) for t in (0, *TURNS)]
            lines.append(f"| {m} | " + " | ".join(f"{v:.3f}" if key != "psnr" else f"{v:.2f}" for v in vals) + " |")
        lines.append("")
    lines += ["**At 90°, per object** (IoU / PSNR dB, mean of the two starting views)", "",
              "| lift | " + " | ".join(OBJECTS) + " |", "|---|" + "---:|" * len(OBJECTS)]
    for m in methods:
        cells = [f"{mean_over(results, m, 90, 'iou', (o,)):.3f} / {mean_over(results, m, 90, 'psnr', (o,)):.2f}"
                 for o in OBJECTS]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", f"Contact sheet: [`docs/images/lift_views.png`](../images/lift_views.png) (per object and "
              "starting view, the truth above the automatic lift; 0°, 30°, 60°, 90°, 180°).", ""]
    lines += [f"**Speed** (median of {runs} runs; issue 17's target: <= 2 s at 1024²)", "",
              "| lift | photo | side | Gaussians | lift s |", "|---|---|---:|---:|---:|"]
    lines += [f"| {name} | {o} | {s} | {n:,} | {t:.2f} |" for name, rows in speeds.items() for o, s, n, t in rows]
    if any(clips.values()):
        lines += ["", "**Single-frame self-transfer** (`eval-self --target frame0`: source frame 0 lifted alone and "
                  "moved by the clip's own prior; PSNR in dB over whole frames on white)", "",
                  "| lift | clip | frame 0 | whole clip | last third |", "|---|---|---:|---:|---:|"]
        lines += [f"| {name} | {clip} | {r['frame0']:.2f} | {r['all']:.2f} | {r['last_third']:.2f} |"
                  for name, rows in clips.items() for clip, r in rows.items()]
    present = {k: v for k, v in sheets.items() if v is not None}
    if present:
        lines += ["", "**Photos** (`../shared/data/images`, turned 0°, 45°, 90°, 180°): "
                  + ", ".join(f"[{k}](../images/{v.name})" for k, v in present.items()) + "."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--label", default="after", help="name of this version in the photo sheet's file name")
    parser.add_argument("--save", type=Path, help="also write the novel-view results as JSON")
    parser.add_argument("--baseline", type=Path, help="JSON saved by an earlier version: its rows are added")
    parser.add_argument("--clips", action="store_true", help="also the frame-0 self-transfer on the shared clips")
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-lift"), help="eval-self outputs")
    args = parser.parse_args()
    from marionette.target.lift import LiftOptions

    has_shapes = "shape" in {f.name for f in dataclasses.fields(LiftOptions)}
    shapes = [None, "polish", "inflate", "revolve", "extrude"] if has_shapes else [None]
    results, sheet = novel_views(shapes)
    speeds = {"auto": speed(args.runs, None)}
    sheets = {args.label: photo_sheet(args.label)}
    clips = {"auto": self_transfer(args.out / args.label) if args.clips else {}}
    if args.save:
        args.save.write_text(json.dumps({"results": results, "speeds": speeds["auto"], "clips": clips["auto"]},
                                        indent=1) + "\n")
    if args.baseline:
        base = json.loads(args.baseline.read_text())
        name = f"baseline ({args.baseline.stem})"
        results = {name: base["results"]["auto"], **results}
        speeds = {name: base["speeds"], **speeds}
        clips = {name: base.get("clips", {}), **clips}
        before = IMAGES / "lift_photos_before.png"
        sheets = {"before": before if before.exists() else None, **sheets}
    if has_shapes:
        import cv2

        half = cv2.resize(sheet, (sheet.shape[1] // 2, sheet.shape[0] // 2), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(IMAGES / "lift_views.png"), cv2.cvtColor(half, cv2.COLOR_RGB2BGR))
        OUT.write_text(report(results, speeds, clips, args.label, sheets, args.runs))
        print(OUT.read_text())


if __name__ == "__main__":
    main()
