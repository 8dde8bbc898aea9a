"""Accuracy and speed of ``extract_prior`` on the synthetic motions (ground truth known).

For each motion, seed and tracking-noise level: the median over frames of the
rotation error (angle of ``R_est^T R_gt``, degrees) and of the centroid error
after the one scale factor that best aligns the estimated centroid trajectory
with the truth (the prior's scale is arbitrary), as a percentage of the
ground-truth radius; and the extraction time. A diagnostic column splits the
centroid error: the same error with the estimated poses but the true frame-0
centre (best scale again), i.e. what the poses alone contribute.

Noise: ``--noise 0,1`` runs each case once per level, adding N(0, sigma²) pixels
to every visible track position (``Tracks.uv``) between tracking and the pose
fit; ``--image-noise 0,3`` runs the one-part cases again with Gaussian noise of
each level (grey levels) added to the rendered frames instead, which the tracker
sees. Writes ``docs/benchmarks/extract.md``.

    python benchmarks/bench_extract.py [--seeds 3] [--frames 48] [--size 320x240] [--noise 0,1] [--image-noise 0,3]
                                       [--large 854x480]
                                       [--focal-scales 0.85,1.15] [--no-exact]

The table also times one larger video (``--large``, outofplane, 50 frames;
``--large 0`` skips it) per stage, and reports the peak resident memory of the
whole run. Two more tables: the hinge extracted with ``parts="auto"`` (the
rotation error of its moving part, the lid), and how the rotation error grows
when the focal length given is off (``--focal-scales``; real clips come
without one). Last, every case again on exact tracks (each track's true
positions, same seeds, visibility and noise): what the tracker contributes.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import resource
import time
import warnings
from pathlib import Path
from unittest import mock

# The bundle adjustment's dense products are small (a few hundred rows); on a
# busy 2-core machine OpenBLAS threads slow them down tenfold. Must be set
# before NumPy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from marionette.geometry import rotation_angle_deg  # noqa: E402
from marionette.source import ExtractOptions, extract_prior  # noqa: E402
from marionette.source import extract as extract_module  # noqa: E402
from marionette.synthetic import make_scene  # noqa: E402

# "hinge" has two parts; this one-part path is scored against part 0 (the body, the largest part).
MOTIONS = ("translation", "inplane", "outofplane", "oscillation", "hinge")
FOCAL_MOTIONS = ("inplane", "outofplane", "oscillation")
STRICT_FIGURE = Path(__file__).resolve().parents[1] / "docs" / "images" / "strict_tracks.png"
READING_STRICT = (
    "Reading: an anchored track whose window stops matching is aligned again from where it is; each time, the"
    " chained step's error is carried on, and a window across a crease of the box (a third of them) is matched"
    " with a bias that grows with the turn (0.4-0.8 px by 30°, against 0.02-0.05 px on one face); its windows are"
    " also compared locally contrast-normalised, a normalisation not covariant with the warp (a bias of about"
    " 0.6 % of the motion, even under pure translation). A strict track is aligned on lightly blurred grey images"
    " under a gain and a bias and cut where that stops matching closely; the fresh track that carries on from"
    " there is a new surface point to the pose fit, so no step's error is carried on (what needs long tracks, the"
    " amount of motion, the focal length, parts and joints, takes the pieces joined into chains). Cutting alone,"
    " with the normalised windows, changed nothing (translation 0.45°, outofplane 0.45° median, session of"
    " 2026-12-05); grey windows without the cuts were worse (0.60°, 0.73°). The pieces are short (median 3 frames"
    " here), and the pose fit treats them as pieces of their chains: the refinement draws whole chains (drawn"
    " piece by piece, 400 pieces held a sixth of the observations, and 1 px of track noise gave translation 1.35 /"
    " 4.90 / 1.99°), a chain's pieces share one track's depth prior, a piece starts from the point its chain was"
    " lifted to rather than a fresh lift, and pieces are checked by their chain at every refinement: a short piece"
    " on a part that moves otherwise (the hinge's lid, fitted with the body as one part) fits any motion over its"
    " few frames, its chain does not (the hinge row of the first table: 1.60 / 3.69 / 2.58° before these two, 0.76 /"
    " 3.69 / 0.18° anchored). Starting a piece from its chain's fitted point instead of the lift broke under 1 px"
    " of track noise (oscillation seed 0: 9.9°): a short piece places its point poorly along the ray. Track noise"
    " added after tracking is the hardest case for strict tracks (1 px, the first table: medians 0.66 / 0.42 /"
    " 0.96 / 1.03° for translation / inplane / outofplane / oscillation, against 1.03 / 0.30 / 1.40 / 0.46° anchored,"
    " page of 2026-12-05 09:06): they are chosen only on footage whose windows keep matching closely, and there"
    " image noise of 3 grey levels leaves them within the targets (the image-noise rows)."
    " A piece that starts at a cut and ends again within 12 frames sits where windows keep failing to match (a"
    " crease under changing shading, an occluding edge), and it lags the motion: 0.06-0.08 px over its 2-3"
    " frames, against 0.02 px for a track seeded on the grid (inplane and outofplane, seed 0, measured against"
    " `track_truth`); over a turn those lags add up to a tilt. When the refinement's median residual shows tracks"
    " that close (below 0.25 px), such pieces are left out of its second pass wherever 30 other tracks see the"
    " frame (`RigidOptions.min_piece_frames`); before that (page of 2026-12-05 19:00), image noise 0 / 3 grey,"
    " default medians: translation 0.10 / 0.10°, inplane 0.21 / 0.16°, outofplane 0.14 / 0.12°, oscillation 0.05"
    " / 0.07° (the tilt of the in-plane turn grew to 0.4° by the end). Noisy tracks (1 px, the first table) keep"
    " them (their poses unchanged): there the pieces' number counts more than their lag."
    " On compressed or blurred footage the pieces are a frame or two long"
    " (car-turn: median 1 frame) and the poses drift (car-turn's reconstruction 29.9 dB with strict tracks"
    " against 32.4 anchored), so the default tries strict tracks and starts over anchored once fewer than 70 % of"
    " the windows aligned so far still match (from the 8th frame step on): the synthetic one-part scenes here keep"
    " 73-97 %, the DAVIS clips and the backpack 36-66 % over the whole clip (car-turn 71 % over its first 8 steps,"
    " then less), and those start over after 8-9 steps, about a second. With `parts` other than 1 the tracks are"
    " anchored: on strict ones (the hinge rows 'strict' below: parts found on the chains, each part fitted on the"
    " pieces) the lid comes out 7-35° off.")


def errors(prior, scene) -> tuple[float, float, float]:
    """Median rotation error (deg), scale-aligned centroid error and the same with the true centre (% of GT radius)."""
    r_est, r_gt = prior.poses[0, :, :3, :3], scene.poses[0, :, :3, :3]
    rot = rotation_angle_deg(np.swapaxes(r_est, -1, -2) @ r_gt)
    c_est, c_gt = prior.centroids[0], scene.centroids()[0]
    s = float((c_est * c_gt).sum() / (c_est * c_est).sum())
    cent = np.linalg.norm(s * c_est - c_gt, axis=1) / scene.radii()[0] * 100
    # With the true frame-0 centre c (in the truth's units), s (R_t c / s + t_t) = R_t c + s t_t: linear in s.
    t_est = prior.poses[0, :, :3, 3]
    turned = r_est @ c_gt[0]
    s = float(((c_gt - turned) * t_est).sum() / max((t_est * t_est).sum(), 1e-300))
    posed = np.linalg.norm(turned + s * t_est - c_gt, axis=1) / scene.radii()[0] * 100
    return float(np.median(rot[1:])), float(np.median(cent[1:])), float(np.median(posed[1:]))


def part_errors(prior, scene) -> tuple[float, float]:
    """Median rotation errors (deg) of the hinge's lid and body, each against its best-matching extracted part."""
    rot = [[float(np.median(rotation_angle_deg(np.swapaxes(prior.poses[k, 1:, :3, :3], -1, -2)
                                               @ scene.poses[part, 1:, :3, :3]))) for k in range(prior.num_parts)]
           for part in (1, 0)]
    return min(rot[0]), min(rot[1])


def patched_tracking(sigma: float, seed: int, scene=None):
    """Patch extract_prior's tracking: with ``scene``, each track's positions become its true ones (same seeds
    and visibility; seeds off the object dropped); then N(0, sigma²) pixels are added to visible positions."""
    rng = np.random.default_rng(seed)

    def track(*args, **kwargs):
        tracks = extract_module.track.__wrapped__(*args, **kwargs)
        uv, visible = tracks.uv, tracks.visible
        if scene is not None:
            truth, valid = scene.track_truth(tracks.start, uv[tracks.start, np.arange(tracks.num_tracks)])
            visible = visible & valid[None]
            uv = np.where(visible[..., None], truth, np.nan)
        noise = rng.normal(scale=sigma, size=uv.shape)
        return dataclasses.replace(tracks, uv=(uv + noise).astype(np.float32), visible=visible)  # NaN stays NaN

    track.__wrapped__ = extract_module.track
    return mock.patch.object(extract_module, "track", track)


def exact_tracks(rows: list, seeds: int, frames: int, size: tuple[int, int], levels: list[float]) -> list[str]:
    """Markdown lines: the one-part cases and the hinge under ``parts="auto"`` again, on exact track positions."""
    exact, hinge = [], []
    for motion in dict.fromkeys(r[0] for r in rows):
        for seed in range(seeds):
            scene = make_scene(motion, seed=seed, num_frames=frames, size=size)
            for sigma in levels:
                with warnings.catch_warnings(), patched_tracking(sigma, seed, scene):
                    warnings.simplefilter("ignore")
                    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps)
                exact.append((motion, sigma) + errors(prior, scene))
                print(f"{motion:12s} seed {seed} noise {sigma:g}, exact tracks: rotation {exact[-1][2]:6.2f} deg  "
                      f"centroid {exact[-1][3]:6.2f} %", flush=True)
            if motion == "hinge":
                with warnings.catch_warnings(), patched_tracking(0.0, seed, scene):
                    warnings.simplefilter("ignore")
                    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps,
                                          options=ExtractOptions(parts="auto"))
                hinge.append((prior.num_parts,) + part_errors(prior, scene))
                print(f"hinge auto   seed {seed}, exact tracks: {hinge[-1][0]} parts, lid {hinge[-1][1]:.2f} deg, "
                      f"body {hinge[-1][2]:.2f} deg", flush=True)
    lines = ["", "The same extraction on exact tracks: every track keeps its seed and its frames but follows the"
             " true motion of its surface point (`SyntheticScene.track_truth`), with the same pixel noise added."
             " What remains is the pose fit's and the centre's own error; the difference to the table above is the"
             " tracker's (median over seeds).", "",
             "| motion | noise (px) | rotation, LK tracks (deg) | rotation, exact tracks (deg) "
             "| centroid, exact tracks (% radius) | true centre, exact tracks (% radius) |",
             "|---|---|---|---|---|---|"]
    for motion in dict.fromkeys(r[0] for r in exact):
        for sigma in levels:
            sel = [r for r in exact if r[0] == motion and r[1] == sigma]
            lk = [r[3] for r in rows if r[0] == motion and r[2] == sigma]
            lines.append(f"| {motion} | {sigma:g} | {np.median(lk):.2f} | {np.median([r[2] for r in sel]):.2f} "
                         f"| {np.median([r[3] for r in sel]):.2f} | {np.median([r[4] for r in sel]):.2f} |")
    if hinge:
        lines += ["", "The hinge with `parts=\"auto\"` on exact tracks (no noise), per seed: "
                  + "; ".join(f"{n} parts, lid {lid:.2f}°, body {body:.2f}°" for n, lid, body in hinge) + "."]
    return lines


def plot_curves(curves: dict, path: Path) -> None:
    """One panel per motion: rotation error per frame (deg) with anchored tracks and the default ones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    motions = list(dict.fromkeys(m for m, _ in curves))
    fig, axes = plt.subplots(1, len(motions), figsize=(3.2 * len(motions), 2.6), sharey=True, squeeze=False)
    for ax, motion in zip(axes[0], motions):
        for kind, style in (("anchored", dict(color="tab:red", label="anchored (aligned again)")),
                            ("default", dict(color="tab:blue", label="default (strict here)"))):
            if (motion, kind) in curves:
                ax.plot(curves[motion, kind], **style)
        ax.set_title(motion)
        ax.set_xlabel("frame")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("rotation error (deg)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def image_noise(motions: list[str], seeds: int, frames: int, size: tuple[int, int], levels: list[float]) -> list[str]:
    """Markdown lines: the one-part cases with Gaussian noise of each level (grey levels) in the frames, tracked
    with anchored tracks and as by default (strict where the windows keep matching)."""
    kinds = {"anchored": False, "default": "auto"}
    lines = ["", "Image noise: N(0, sigma²) grey levels added to every rendered frame (`make_scene(noise=sigma)`),"
             " before tracking; the tracks are the tracker's own, anchored (`--anchored-tracks`: a track whose"
             " window stops matching is aligned again from there) and by default (`strict_tracks=\"auto\"`:"
             " strict, each track cut there and a fresh one carrying on, while 70 % of the windows keep matching;"
             " the column 'strict' counts the seeds that got them). Median over frames of the rotation error, per"
             " seed, and the median over seeds (issue 16's targets: <= 0.2° without noise, <= 0.5° with 3 grey"
             " levels); 'true centre' as above, what the poses alone contribute to the centroid error, median over"
             " seeds (target <= 0.5 %).", "",
             "| motion | image noise (grey) | anchored: per seed (deg) | anchored: median (deg) "
             "| default: per seed (deg) | default: median (deg) | strict | true centre, anchored / default (% radius) "
             "| tracks, anchored / default (mean) |",
             "|---|---|---|---|---|---|---|---|---|"]
    curves = {}  # (motion, kind) -> (T,) rotation error per frame, seed 0 without noise
    for motion in motions:
        if motion == "hinge":
            continue
        for level in levels:
            rot, centre, count = ({kind: [] for kind in kinds} for _ in range(3))
            chosen = 0
            for seed in range(seeds):
                scene = make_scene(motion, seed=seed, num_frames=frames, size=size, noise=level)
                for kind, strict in kinds.items():
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps,
                                              options=ExtractOptions(strict_tracks=strict))
                    rotation, _, posed = errors(prior, scene)
                    rot[kind].append(rotation)
                    centre[kind].append(posed)
                    if seed == 0 and level == 0:
                        curves[motion, kind] = rotation_angle_deg(
                            np.swapaxes(prior.poses[0, :, :3, :3], -1, -2) @ scene.poses[0, :, :3, :3])
                    count[kind].append(prior.metadata["num_tracks"])
                    chosen += kind == "default" and prior.metadata["tracks"]["strict"]
                    print(f"{motion:12s} seed {seed} image noise {level:g}, {kind}: rotation {rot[kind][-1]:6.2f} deg"
                          f" (tracks {prior.metadata['tracks']})", flush=True)
            lines.append(f"| {motion} | {level:g} | " + " | ".join(
                f"{' / '.join(f'{r:.2f}' for r in rot[kind])} | {np.median(rot[kind]):.2f}" for kind in kinds)
                + f" | {chosen} of {seeds} | {np.median(centre['anchored']):.2f} / {np.median(centre['default']):.2f} "
                f"| {np.mean(count['anchored']):.0f} / {np.mean(count['default']):.0f} |")
    if curves:
        plot_curves(curves, STRICT_FIGURE)
        lines += ["", f"Seed 0 without noise, frame by frame: ![rotation error per frame, anchored and default tracks]"
                  f"(../images/{STRICT_FIGURE.name})"]
    return lines + ["", READING_STRICT]


def focal_sensitivity(scales: list[float], rows: list, seeds: int, frames: int, size: tuple[int, int]) -> list[str]:
    """Markdown lines: median rotation error when the focal length given is off by each of ``scales``."""
    lines = ["", "Sensitivity to the focal length (the extraction is given the true focal length times the factor;"
             " no noise; median over seeds of the median rotation error, deg). Real clips come without one:"
             " `marionette extract` assumes a 60° horizontal field of view unless `--focal` is given.", "",
             "| motion | " + " | ".join(f"focal x {f:g}" for f in sorted(scales + [1.0])) + " |",
             "|---|" + "---|" * (len(scales) + 1)]
    for motion in FOCAL_MOTIONS:
        by_scale = {1.0: [r[3] for r in rows if r[0] == motion and r[2] == 0]}
        if not by_scale[1.0]:
            continue
        for scale in scales:
            by_scale[scale] = []
            for seed in range(seeds):
                scene = make_scene(motion, seed=seed, num_frames=frames, size=size)
                k = scene.camera.K.copy()
                k[:2, :2] *= scale
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    prior = extract_prior(scene.frames, scene.masks, k, scene.fps)
                by_scale[scale].append(errors(prior, scene)[0])
                print(f"{motion:12s} seed {seed} focal x {scale:g}: rotation {by_scale[scale][-1]:6.2f} deg",
                      flush=True)
        lines.append(f"| {motion} | " + " | ".join(f"{np.median(by_scale[f]):.2f}" for f in sorted(by_scale)) + " |")
    return lines


def hinge_parts(seeds: int, frames: int, size: tuple[int, int]) -> list[str]:
    """Markdown lines: the hinge extracted with ``parts="auto"``, the rotation error of its lid per seed."""
    lines = ["", "The hinge with `parts=\"auto\"` (no noise): parts found and the median rotation error of the"
             " moving part, the lid (target <= 1°), scored as the best-matching extracted part.", "",
             "| seed | tracks | parts | lid rotation (deg) | body rotation (deg) | time (s) |",
             "|---|---|---|---|---|---|"]
    for seed in range(seeds):
        scene = make_scene("hinge", seed=seed, num_frames=frames, size=size)
        for strict in (False, True):
            start = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps,
                                      options=ExtractOptions(parts="auto", strict_tracks=strict))
            elapsed = time.perf_counter() - start
            lid, body = part_errors(prior, scene)
            kind = "strict" if strict else "default"
            lines.append(f"| {seed} | {kind} | {prior.num_parts} | {lid:.2f} | {body:.2f} | {elapsed:.2f} |")
            print(f"hinge auto   seed {seed} ({kind}): {prior.num_parts} parts, lid {lid:.2f} deg, body {body:.2f} deg",
                  flush=True)
    return lines + [
        "", "Reading: the lid is fitted as a hinge on the box (`ExtractOptions.joints`, on by default since"
        " 2026-12-04: one angle per frame about an axis fixed in the box); free, as before, it was 17.7-32.3° off"
        " (`--no-joints`). The free fit's trouble: the lid is a thin slab seen obliquely; as it opens its top"
        " face turns edge-on and its underside comes into view. Its rotation is underestimated from the first"
        " frames on, and the error jumps when the top face turns away. Measured with tracks made on the lid"
        " alone (true per-frame lid masks, so no window"
        " straddles the box): the lid's median error is still 4.7-15.6°, its tracks drift as its faces"
        " foreshorten (`tracks.md`), and even where they are within 0.15 px (frames 1-8) the error grows to 2.5°"
        " by frame 10: a near-planar part under near-affine viewing leaves its tilt and its rotation about an"
        " in-plane axis weakly separable, and the inflated shape prior's tilt is wrong for a box's top face."
        " On exact tracks (last table) the same extraction gets the lid to a degree or two: most of the error is"
        " the tracker's drift on the lid. Strict tracks (forced with `--strict-tracks`; by default the tracks are"
        " anchored where parts are found) do not help here: the parts are found on their chains, but the lid's"
        " pieces, cut as its faces turn away, leave its pose fit 7-35° off."]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--noise", default="0,1", help="comma-separated track noise levels, pixels (std)")
    ap.add_argument("--image-noise", default="0,3",
                    help="comma-separated levels of Gaussian noise added to the frames, grey levels (std); '' skips")
    ap.add_argument("--motions", default=",".join(MOTIONS))
    ap.add_argument("--large", default="854x480")
    ap.add_argument("--focal-scales", default="0.85,1.15",
                    help="comma-separated factors on the true focal length for the sensitivity table (0: skip)")
    ap.add_argument("--exact", action=argparse.BooleanOptionalAction, default=True,
                    help="also run every case on exact track positions (the tracker's share of the error)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "extract.md"))
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    levels = [float(v) for v in args.noise.split(",")]
    motions = args.motions.split(",")
    rows = []
    for motion in motions:
        for seed in range(args.seeds):
            scene = make_scene(motion, seed=seed, num_frames=args.frames, size=size)
            for sigma in levels:
                t = time.perf_counter()
                with warnings.catch_warnings(record=True) as caught, patched_tracking(sigma, seed):
                    warnings.simplefilter("always")
                    prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps)
                elapsed = time.perf_counter() - t
                rot, cent, posed = errors(prior, scene)
                rows.append((motion, seed, sigma, rot, cent, posed, elapsed, prior.metadata["num_tracks"],
                             len(prior.metadata["failed_frames"]), len(caught),
                             "strict" if prior.metadata["tracks"]["strict"] else "anchored"))
                print(f"{motion:12s} seed {seed} noise {sigma:g}: rotation {rot:6.2f} deg  centroid {cent:6.2f} % "
                      f"(true centre {posed:5.2f} %)  {elapsed:5.2f} s  tracks {rows[-1][7]}  failed {rows[-1][8]}",
                      flush=True)

    lines = [
        "# Source motion extraction on synthetic scenes",
        "",
        f"`python benchmarks/bench_extract.py --seeds {args.seeds} --frames {args.frames} --size {args.size}"
        f" --noise {args.noise} --image-noise '{args.image_noise}'` on {platform.machine()},"
        f" Python {platform.python_version()};"
        " default `ExtractOptions`.",
        "",
        "Rotation error: median over frames of the angle of `R_est^T R_gt`. Centroid error: median over frames of"
        " `|s c_est - c_gt|` with the one scale `s` that best fits the whole trajectory, in % of the ground-truth"
        " radius; `c_gt` is the mean of the object's surface samples (for the box, its centre). 'True centre':"
        " the same with the estimated poses moving the true frame-0 centre (what the poses alone contribute)."
        " Noise: N(0, sigma²) pixels added to every visible track position before the pose fit."
        " Targets: <= 0.5 deg and <= 1 % without noise, <= 1 deg and <= 2 % with 1 px. `hinge` is a two-part"
        " object (body and lid) fitted as one part and scored against the body.",
        "",
        "Reading it: the centroid error is dominated by the frame-0 centre, not by the poses (compare the two"
        " centroid columns). The centre is `carved_centroid`: the inflated mask volume carved by all silhouettes."
        " Its error is mostly sideways: under perspective the near half of the object fills more of the"
        " silhouette than the far half, so the silhouette's centre is not the projection of the object's centre,"
        " and the far half is never seen. Only the silhouettes of views from all round the object would fix it"
        " (with the 90° turns here, a full visual hull is worse: the region behind the object that no view sees"
        " stays in it).",
        "",
        "| motion | seed | noise (px) | rotation (deg) | centroid (% radius) | true centre (% radius) | time (s) "
        "| tracks | failed frames |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {m} | {s} | {n:g} | {r:.2f} | {c:.2f} | {p:.2f} | {e:.2f} | {k} {kind} | {f} |"
              for m, s, n, r, c, p, e, k, f, _, kind in rows]
    lines += ["", "| motion | noise (px) | median rotation (deg) | median centroid (% radius) "
              "| median true centre (% radius) | mean time (s) |", "|---|---|---|---|---|---|"]
    for motion in motions:
        for sigma in levels:
            sel = [r for r in rows if r[0] == motion and r[2] == sigma]
            lines.append(f"| {motion} | {sigma:g} | {np.median([r[3] for r in sel]):.2f} "
                         f"| {np.median([r[4] for r in sel]):.2f} | {np.median([r[5] for r in sel]):.2f} "
                         f"| {np.mean([r[6] for r in sel]):.2f} |")
    if args.image_noise:
        lines += image_noise(motions, args.seeds, args.frames, size, [float(v) for v in args.image_noise.split(",")])
    if args.focal_scales != "0":
        lines += focal_sensitivity([float(v) for v in args.focal_scales.split(",")], rows, args.seeds, args.frames,
                                   size)
    if "hinge" in motions:
        lines += hinge_parts(args.seeds, args.frames, size)
    if args.exact:
        lines += exact_tracks(rows, args.seeds, args.frames, size, levels)
    if args.large != "0":
        large = tuple(int(v) for v in args.large.split("x"))
        scene = make_scene("outofplane", seed=0, num_frames=50, size=large)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps)
        times = prior.metadata["timings"]
        rot, cent, posed = errors(prior, scene)
        stages = ", ".join(f"{k} {v:.2f} s" for k, v in times.items() if k != "total")
        lines += ["", f"Larger video: `outofplane`, seed 0, 50 frames at {args.large}: {times['total']:.2f} s"
                  f" ({stages}); {prior.metadata['num_tracks']} tracks; rotation {rot:.2f} deg, centroid {cent:.2f} %"
                  f" (true centre {posed:.2f} %)."]
        print(lines[-1])
    # ru_maxrss is in kilobytes on Linux.
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    lines += ["", f"Peak resident memory of the whole run (`ru_maxrss`): {peak:.0f} MB."]
    print(lines[-1])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
