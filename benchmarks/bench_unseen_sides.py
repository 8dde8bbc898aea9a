"""A target from the sides its photo never showed (issue 53): randomised objects lifted from one view and turned.

1. Per shape. Synthetic objects of known 3D (``object_view``: box, box with a lid, squat can, vase, thin
   rod, a car-like shape mirror-symmetric about its long mid-plane), each with rich (checkered) and plain
   (one colour per face) textures, ``--seeds`` of each (sizes and textures vary with the seed) seen from
   a random yaw (0-60°) and pitch (5-30°), 256x256, 60° field of view. Each photo is lifted in its true
   camera (``lift_image``, shape prior ``auto``), its centre at the true depth, turned 45°, 90° and 180°
   about the object's own vertical axis and rendered, against the object rendered so: silhouette IoU
   (alpha > 0.5), and masked PSNR of both images composed on grey and blurred with σ = 3 px over the
   silhouettes' union (the colours in the right places, not texture no one could know).
   Boxes and pots are relit (``--relight``, the default); the car-like shape is carved as ``mirror``.
2. The independent box: a rich box tilted 25° towards the camera, from yaws 0, 20, 40, 60 (seeds 0-1),
   turned 0-90° about its vertical axis: the last third (60-90°), means of blurred PSNR and IoU.
3. Lift time of a 512² box photo, median of ``--runs``.
4. The demo (``marionette demo``): its result's frames where the extracted turn is nearest 0°, 45° and 90°,
   ``docs/images/unseen_sides_demo_<label>.png``.
5. Photos the project was not tuned on: every image in ``../shared/data/images`` (skipped when absent)
   lifted as ``transfer`` lifts it and turned 0°, 45°, 90° and 180° about the vertical through its centre,
   one sheet per run: ``docs/images/unseen_sides_photos_<label>.png``, to be judged by eye.
6. What the lift rebuilds (box, solid of revolution, mirror hull or sheets) over ``--views`` random views of
   each object: yaw 0-90°, pitch 0-35°, field of view 30-70°, 192².

``--code DIR`` imports ``marionette`` from another checkout (the baseline); ``--save FILE`` keeps the
figures, ``--baseline FILE`` adds them to the page as "before" (default: the saved run of commit 186e776,
``docs/benchmarks/unseen_sides_186e776.json``). Contact sheets (truth above the lift, at
0°, 45°, 90°, 180°) go to ``docs/images/unseen_sides_<label>.png``.

    flock /tmp/marionette-bench.lock python benchmarks/bench_unseen_sides.py --code ../base --label before \\
        --save docs/benchmarks/unseen_sides_186e776.json
    flock /tmp/marionette-bench.lock python benchmarks/bench_unseen_sides.py
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "unseen_sides.md"
# The lift before boxes were rebuilt as boxes (commit 186e776), run with --code on that checkout.
BEFORE = ROOT / "docs" / "benchmarks" / "unseen_sides_186e776.json"
IMAGES = ROOT / "docs" / "images"
PHOTOS = ROOT.parent / "shared" / "data" / "images"
OBJECTS = ("box", "hinge", "cylinder", "vase", "rod", "car")
TEXTURES = ("rich", "plain")
TURNS = (45, 90, 180)
SIZE = (256, 256)
FOV = 60.0
INDEPENDENT = {"pitch": 25.0, "yaws": (0.0, 20.0, 40.0, 60.0), "seeds": (0, 1), "turns": (60, 70, 80, 90)}


def blurred_psnr(truth: np.ndarray, image: np.ndarray, alpha: np.ndarray) -> float:
    """Masked PSNR (dB) of a render (H, W, 3) uint8 with alpha (H, W) against an RGBA truth, both blurred σ = 3."""
    import cv2

    true_mask, mask = truth[..., 3] > 0, alpha > 0.5
    a = cv2.GaussianBlur(np.where(true_mask[..., None], truth[..., :3], 128).astype(np.float32), (0, 0), 3)
    b = cv2.GaussianBlur(np.where(mask[..., None], image, 128).astype(np.float32), (0, 0), 3)
    return float(10 * np.log10(255.0**2 / max(float(((a - b) ** 2)[true_mask | mask].mean()), 1e-12)))


def views(obj: str, seed: int, yaw: float, pitch: float, plain: bool, turns) -> tuple[dict, list]:
    """{turn: (IoU, blurred PSNR)} of the lift turned, the shape chosen, and the sheet's two rows."""
    from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
    from marionette.render import render
    from marionette.synthetic import object_view
    from marionette.target.lift import LiftOptions, lift_image

    kwargs = {"size": SIZE, "seed": seed, "pitch_deg": pitch, "fov_deg": FOV}
    if plain:
        kwargs["plain"] = True
    photo, camera, centre = object_view(obj, yaw_deg=yaw, **kwargs)
    lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
    up = axis_angle_to_matrix([np.radians(pitch), 0.0, 0.0]) @ np.array([0.0, 1.0, 0.0])
    scores, truth_row, lift_row = {}, [], []
    for turn in (0, *turns):
        truth = object_view(obj, yaw_deg=yaw + turn, **kwargs)[0]
        r = axis_angle_to_matrix(up * np.radians(turn))
        g = lifted.gaussians
        out = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)), camera)
        image = np.clip(np.rint(out.image * 255), 0, 255).astype(np.uint8)
        seen, true_mask = out.alpha > 0.5, truth[..., 3] > 0
        scores[turn] = (float((seen & true_mask).sum() / max((seen | true_mask).sum(), 1)),
                        blurred_psnr(truth, image, out.alpha))
        truth_row.append(np.where(true_mask[..., None], truth[..., :3], 255))
        lift_row.append(np.where(out.alpha[..., None] > 0.02, image, 255))
    shape = lifted.shape.name if lifted.shape is not None else "?"
    leaning = getattr(lifted.shape, "pitch", None)
    return scores, [(shape, leaning), np.concatenate(truth_row, axis=1), np.concatenate(lift_row, axis=1)]


def per_shape(seeds: int) -> tuple[list[dict], np.ndarray]:
    """One record per scene, and the contact sheet (seed 0 of each object and texture)."""
    rows, sheet = [], []
    for obj in OBJECTS:
        for texture in TEXTURES:
            for seed in range(seeds):
                rng = np.random.default_rng(1000 * seed + 17)
                yaw, pitch = float(rng.uniform(0, 60)), float(rng.uniform(5, 30))
                scores, ((shape, leaning), truth, lift) = views(obj, seed, yaw, pitch, texture == "plain", TURNS)
                rows.append({"object": obj, "texture": texture, "seed": seed, "yaw": yaw, "pitch": pitch,
                             "shape": shape, "leaning": leaning, "scores": {str(t): v for t, v in scores.items()}})
                if seed == 0:
                    sheet += [truth, lift]
    return rows, np.concatenate(sheet, axis=0)


def independent_box() -> dict:
    """Means over the independent box's starting views of the last third of a 90° turn."""
    ious, psnrs = [], []
    for seed in INDEPENDENT["seeds"]:
        for yaw in INDEPENDENT["yaws"]:
            scores, _ = views("box", seed, yaw, INDEPENDENT["pitch"], False, INDEPENDENT["turns"])
            ious += [scores[t][0] for t in INDEPENDENT["turns"]]
            psnrs += [scores[t][1] for t in INDEPENDENT["turns"]]
    return {"iou": float(np.mean(ious)), "psnr": float(np.mean(psnrs)), "worst_psnr": float(np.min(psnrs))}


def choices(views: int) -> dict[str, dict[str, int]]:
    """{object: {shape lifted: count}} over ``views`` random views of each (yaw 0-90°, pitch 0-35°, field of
    view 30-70°, random seed; 192²), as ``lift_image`` rebuilds them with the shape prior ``auto``."""
    from collections import Counter

    from marionette.synthetic import object_view
    from marionette.target.lift import LiftOptions, lift_image

    rng = np.random.default_rng(7)
    out = {}
    for obj in OBJECTS:
        counts: Counter = Counter()
        for _ in range(views):
            yaw, pitch = rng.uniform(0, 90), rng.uniform(0, 35)
            seed, fov = int(rng.integers(0, 50)), rng.uniform(30, 70)
            photo, camera, centre = object_view(obj, yaw_deg=yaw, pitch_deg=pitch, size=(192, 192), seed=seed,
                                                fov_deg=fov)
            lifted = lift_image(photo, camera=camera, options=LiftOptions(depth=float(centre[2])))
            shape = lifted.shape
            sheets = shape.name in ("inflate", "extrude") or (shape.name == "revolve" and shape.pitch is None)
            counts[f"{shape.name} sheets" if sheets else shape.name] += 1
        out[obj] = dict(counts)
    return out


def lift_time(runs: int) -> float:
    from marionette.synthetic import render_object_image
    from marionette.target.lift import lift_image

    image = render_object_image("box", size=(512, 512), seed=0)
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        lift_image(image)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def photo_sheet(label: str) -> Path | None:
    """The shared photos lifted and turned: ``docs/images/unseen_sides_photos_<label>.png`` (None without them)."""
    import cv2

    from marionette.geometry import axis_angle_to_matrix, matrix_to_quaternion
    from marionette.io.video import read_image
    from marionette.render import render
    from marionette.target.lift import alpha_mask, lift_image

    files = sorted(p for p in PHOTOS.glob("*/*.png") if p.name not in ("mask.png", "image.png")) \
        if PHOTOS.is_dir() else []
    rows = []
    for path in files:
        image = read_image(path)
        if image.shape[0] > 512:
            image = cv2.resize(image, (512, 512), interpolation=cv2.INTER_AREA)
        lifted = lift_image(image, mask=alpha_mask(image))
        g = lifted.gaussians
        centre = 0.5 * (g.means.min(axis=0) + g.means.max(axis=0))
        views = []
        for turn in (0, 45, 90, 180):
            r = axis_angle_to_matrix([0.0, np.radians(turn), 0.0])
            out = render(g.with_means((g.means - centre) @ r.T + centre).turned(matrix_to_quaternion(r)),
                         lifted.camera, (1.0, 1.0, 1.0))
            views.append(np.clip(np.rint(out.image * 255), 0, 255).astype(np.uint8))
        rows.append(cv2.resize(np.concatenate(views, axis=1), (4 * 256, 256), interpolation=cv2.INTER_AREA))
    if not rows:
        return None
    out = IMAGES / f"unseen_sides_photos_{label}.png"
    cv2.imwrite(str(out), cv2.cvtColor(np.concatenate(rows, axis=0), cv2.COLOR_RGB2BGR))
    return out


def demo_sheet(label: str) -> Path:
    """The demo's result at the frames turned nearest 0°, 45° and 90°: ``docs/images/unseen_sides_demo_<label>.png``.
    """
    import tempfile

    import cv2

    from marionette.demo import run_demo
    from marionette.io import read_prior, read_video

    with tempfile.TemporaryDirectory() as folder:
        paths = run_demo(folder)
        poses = read_prior(paths["prior"]).poses[0]
        frames = read_video(paths["result"]).frames
    angles = np.degrees(np.arccos(np.clip((np.trace(poses[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    picks = [int(np.argmin(np.abs(angles - a))) for a in (0, 45, 90)]
    out = IMAGES / f"unseen_sides_demo_{label}.png"
    cv2.imwrite(str(out), cv2.cvtColor(np.concatenate([frames[i] for i in picks], axis=1), cv2.COLOR_RGB2BGR))
    return out


def table(rows: list[dict], turn: int, key: int) -> dict[tuple[str, str], float]:
    """{(object, texture): mean of score ``key`` (0 IoU, 1 PSNR) at ``turn``}."""
    out: dict[tuple[str, str], list] = {}
    for row in rows:
        out.setdefault((row["object"], row["texture"]), []).append(row["scores"][str(turn)][key])
    return {k: float(np.mean(v)) for k, v in out.items()}


READING = (
    "Reading: a box rebuilt as a box keeps its silhouette from every side (IoU 0.99 at every turn), and one "
    "seen nearly level (a five-corner outline) is a box too. Relit, a side the photo saw in shadow brightens as "
    "it turns to the light (the synthetic renders light the object from above, left and in front, fixed to the "
    "camera): at 90° a box gains 5.2-9.0 dB over the lift before, the last third of the independent box's turn "
    "reaches 20.8 dB (issue 53's target 19.9). Cans and vases gain 0.10-0.15 IoU from an axis that leans as the photo "
    "shows (read from the outline's ends and any edge that runs round the body: a rim, a step, a band) and is "
    "placed by its middle, and 3.3-11.6 dB (cans) and 4.2-7.7 dB (vases) at 90°: what is left is the colours "
    "of a rich pot's hidden half (a checkered can's back cannot be known; its sides seen edge-on are quilted "
    "from about the same heights, not stretched), and a rich pot's many colours sometimes put the light below "
    "it, where it is taken for paint and the photo's colours are kept. The thin rod is now a box (IoU at 90° "
    "0.11 → 0.77). The car-like shape is carved from the photo and its mirror image (``mirror``): IoU at 90° "
    "0.63 → 0.81, +1.5-1.9 dB; two views leave its cabin spread over the bonnet and its underside coloured "
    "from its nearest neighbours (the wheels' blue).")


def report(after: dict, before: dict | None, label: str) -> str:
    lines = ["# A target from the sides its photo never showed", "",
             f"`python benchmarks/bench_unseen_sides.py` on {platform.machine()}, Python "
             f"{platform.python_version()}; the method and the commands are in the script's docstring. "
             f"{len(after['rows'])} scenes: {', '.join(OBJECTS)}, each with rich and plain textures, "
             f"{len(after['rows']) // (len(OBJECTS) * len(TEXTURES))} seeds (random size, texture and view: yaw "
             "0-60°, pitch 5-30°), lifted from one view and turned about the object's own vertical axis. "
             "PSNR: both images on grey, blurred σ = 3 px, over the silhouettes' union. Issue 53's targets: IoU "
             ">= 0.9 at 90°, and blurred PSNR at 90° at least 5 dB above the lift before.", ""]
    for turn in TURNS:
        lines += [f"**Turned {turn}°** (IoU / blurred PSNR dB, mean over seeds)", "",
                  "| object | texture | shape chosen (after) | " + ("before | " if before else "") + "after |",
                  "|---|---|---|" + ("---:|" if before else "") + "---:|"]
        iou, psnr = table(after["rows"], turn, 0), table(after["rows"], turn, 1)
        if before:
            iou0, psnr0 = table(before["rows"], turn, 0), table(before["rows"], turn, 1)
        for key in iou:
            shapes = sorted({r["shape"] for r in after["rows"] if (r["object"], r["texture"]) == key})
            was = f"{iou0[key]:.3f} / {psnr0[key]:.2f} | " if before else ""
            lines.append(f"| {key[0]} | {key[1]} | {', '.join(shapes)} | {was}{iou[key]:.3f} / {psnr[key]:.2f} |")
        lines.append("")
    leaning = [(r["object"], r["texture"], r["pitch"], r["leaning"]) for r in after["rows"]
               if r.get("leaning") is not None]
    if leaning:
        errors = [abs(est - true) for _, _, true, est in leaning]
        lines += ["**Solids of revolution: the axis' lean** (true pitch → estimated, degrees; median error "
                  f"{np.median(errors):.1f}°, worst {max(errors):.1f}°)", "",
                  "| object | texture | true | estimated |", "|---|---|---:|---:|"]
        lines += [f"| {o} | {t} | {true:.1f} | {est:.1f} |" for o, t, true, est in leaning]
        lines.append("")
    lines += ["**The independent box** (rich box tilted 25°, yaws 0/20/40/60, seeds 0-1; turns 60-90°)", "",
              "| | IoU | blurred PSNR dB (mean) | worst view dB |", "|---|---:|---:|---:|"]
    for name, run in (("before", before), ("after", after)):
        if run:
            box = run["independent"]
            lines.append(f"| {name} | {box['iou']:.3f} | {box['psnr']:.2f} | {box['worst_psnr']:.2f} |")
    lines += ["", "**What the lift rebuilds**, over random views of each object (yaw 0-90°, pitch 0-35°, field of "
              "view 30-70°: `cuboid`, `revolve` and `mirror` solids where one explains the outline, else sheets)", "",
              "| object | " + ("before | " if before and "choices" in before else "") + "after |",
              "|---|" + ("---|" if before and "choices" in before else "") + "---|"]
    for obj, counts in after["choices"].items():
        was = (", ".join(f"{k} {v}" for k, v in sorted(before["choices"][obj].items())) + " | "
               if before and "choices" in before else "")
        lines.append(f"| {obj} | {was}{', '.join(f'{k} {v}' for k, v in sorted(counts.items()))} |")
    lines += ["", READING]
    lines += ["", f"**Lift time**, 512² box photo, median of runs: "
              + (f"before {before['lift_s']:.2f} s, " if before else "") + f"after {after['lift_s']:.2f} s.", "",
              f"Contact sheets (per object and texture, seed 0: the truth above the lift, at 0°, 45°, 90°, 180°): "
              f"[`docs/images/unseen_sides_{label}.png`](../images/unseen_sides_{label}.png)"
              + (" and [`docs/images/unseen_sides_before.png`](../images/unseen_sides_before.png)." if before else "."),
              "", f"The shared photos (0°, 45°, 90°, 180° about the vertical): "
              f"[`docs/images/unseen_sides_photos_{label}.png`](../images/unseen_sides_photos_{label}.png)"
              + (" and [before](../images/unseen_sides_photos_before.png)." if before else "."), "",
              "The demo's result turned 0°, 45° and 90°: "
              f"[`docs/images/unseen_sides_demo_{label}.png`](../images/unseen_sides_demo_{label}.png)"
              + (" and [before](../images/unseen_sides_demo_before.png)." if before else "."), ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--views", type=int, default=30, help="random views per object of what the lift rebuilds")
    parser.add_argument("--code", type=Path, help="import marionette from this checkout (a baseline)")
    parser.add_argument("--label", default="after")
    parser.add_argument("--save", type=Path)
    parser.add_argument("--baseline", type=Path, default=BEFORE if BEFORE.exists() else None)
    args = parser.parse_args()
    sys.path.insert(0, str((args.code or ROOT).resolve()))
    import cv2

    rows, sheet = per_shape(args.seeds)
    run = {"rows": rows, "independent": independent_box(), "lift_s": lift_time(args.runs),
           "choices": choices(args.views)}
    photo_sheet(args.label)
    demo_sheet(args.label)
    IMAGES.mkdir(parents=True, exist_ok=True)
    small = cv2.resize(sheet, (sheet.shape[1] // 2, sheet.shape[0] // 2), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(IMAGES / f"unseen_sides_{args.label}.png"), cv2.cvtColor(small, cv2.COLOR_RGB2BGR))
    if args.save:
        args.save.write_text(json.dumps(run))
    if args.code is None:
        before = json.loads(args.baseline.read_text()) if args.baseline else None
        OUT.write_text(report(run, before, args.label))
        print(OUT.read_text())
    else:
        print(json.dumps(run["independent"]), run["lift_s"])


if __name__ == "__main__":
    main()
