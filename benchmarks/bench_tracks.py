"""Accuracy of the Lucas–Kanade tracks against the synthetic scenes' ground truth.

Every track starts on a whole pixel, so its 3D point is known exactly: the
rendered depth at that pixel, moved by the ground-truth pose of the part it
lies on. Its true position at every later frame is that point projected; the
error is the distance of the tracked position to it, over the frames where the
track is visible. Per motion (3 seeds each) and level of pixel noise added to
the rendered frames (grey levels, std): the median error, the mean error with
each clipped at 5 px (drift shows here), and the share of tracks that stray
more than 1 px at some frame. ``--compare BLUR,NORM`` adds rows with other
values of the tracker's pre-blur and contrast-normalisation scales (pixels),
for choosing them (the first timing includes compiling the tracker). Writes ``docs/benchmarks/tracks.md``.

    python benchmarks/bench_tracks.py [--seeds 3] [--frames 48] [--size 320x240] [--noise 0,3]
                                      [--compare 0.85,3 --compare 0.7,2]
"""

from __future__ import annotations

import argparse
import contextlib
import platform
import time
from pathlib import Path
from unittest import mock

import numpy as np

from marionette.source import tracks as tracks_module
from marionette.source.tracks import Tracks, track
from marionette.synthetic import make_scene

MOTIONS = ("translation", "inplane", "outofplane", "oscillation", "hinge")
#: Pre-blur and normalisation scales compared by default: sharper than the tracker's, better here, but not on
#: the real clips (see the page), so not its defaults.
COMPARED = ("0.85,3", "0.7,2")
OUT = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "tracks.md"


def track_errors(scene, tracks: Tracks) -> np.ndarray:
    """(T, M) distance (pixels) of each visible track to the projection of its true 3D point; NaN elsewhere."""
    m = np.arange(tracks.num_tracks)
    truth, _ = scene.track_truth(tracks.start, tracks.uv[tracks.start, m])  # seeds sit on whole pixels
    return np.where(tracks.visible, np.linalg.norm(truth - tracks.uv, axis=2), np.nan)


def settings(blur: float | None, norm: float | None):
    """The tracker with other pre-blur and normalisation scales (None: its own)."""
    if blur is None:
        return contextlib.nullcontext()
    return mock.patch.multiple(tracks_module, _BLUR_SIGMA=blur, _NORM_SIGMA=norm)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--noise", default="0,3", help="comma-separated pixel noise levels (grey levels, std)")
    ap.add_argument("--compare", action="append", metavar="BLUR,NORM",
                    help=f"also track with these pre-blur and normalisation scales (pixels); repeatable; default "
                         f"{' '.join(COMPARED)}; 'none' for none")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    args.compare = [c for c in (args.compare or COMPARED) if c != "none"]
    variants = [(None, None)] + [tuple(float(v) for v in c.split(",")) for c in args.compare]
    rows = []
    for noise in (float(v) for v in args.noise.split(",")):
        for motion in MOTIONS:
            scenes = [make_scene(motion, seed=s, num_frames=args.frames, size=size, noise=noise)
                      for s in range(args.seeds)]
            for blur, norm in variants:
                errors, times, counts = [], [], []
                with settings(blur, norm):
                    for scene in scenes:
                        start = time.perf_counter()
                        tracks = track(scene.frames, scene.masks)
                        times.append(time.perf_counter() - start)
                        errors.append(track_errors(scene, tracks))
                        counts.append(tracks.num_tracks)
                used = f"{tracks_module._BLUR_SIGMA:g} / {tracks_module._NORM_SIGMA:g}" if blur is None else \
                    f"{blur:g} / {norm:g}"
                with np.errstate(all="ignore"):
                    strays = np.mean(np.concatenate([np.nanmax(e, axis=0) > 1 for e in errors]))
                row = (motion, noise, used + ("" if blur is None else " (compared)"),
                       float(np.median([np.nanmedian(e) for e in errors])),
                       float(np.mean([np.nanmean(np.minimum(e, 5.0)) for e in errors])),
                       100 * float(strays), int(np.mean(counts)), float(np.mean(times)))
                rows.append(row)
                print(f"{motion:12s} noise {noise:g} blur/norm {row[2]}: median {row[3]:.3f} px, clipped mean "
                      f"{row[4]:.3f} px, {row[5]:.0f} % stray > 1 px, {row[6]} tracks, {row[7]:.2f} s", flush=True)

    lines = [
        "# Track accuracy on synthetic scenes",
        "",
        f"`python benchmarks/bench_tracks.py --seeds {args.seeds} --frames {args.frames} --size {args.size}"
        f" --noise {args.noise}" + "".join(f" --compare {c}" for c in args.compare) + "` on "
        f"{platform.machine()}, Python {platform.python_version()}; `marionette.source.track` with its defaults.",
        "",
        "Error: distance of a tracked position to the projection of the track's true 3D point (the rendered depth"
        " at its seed pixel, moved by the ground-truth pose of its part), over the frames where the track is"
        " visible. Median: median over seeds of the median error. Clipped mean: mean error with each clipped at"
        " 5 px (drift shows here). Strays: share of tracks more than 1 px off at some frame. Noise: Gaussian"
        " pixel noise added to the rendered frames (grey levels, std). Blur / norm: the tracker's pre-blur and"
        " local-contrast-normalisation scales in pixels (`_BLUR_SIGMA`, `_NORM_SIGMA`); compared rows track"
        " with other values.",
        "",
        "Reading: where a surface turns away from the camera (out-of-plane turns, the hinge's lid) tracks drift"
        " most, about half of them past 1 px at some frame, and those errors feed the poses directly. A sharper"
        " tracker (pre-blur 0.7 px, normalisation 2 px) drifts less on these renders (clipped mean 12-41 % lower,"
        " with or without pixel noise), but it did worse on the real clips: re-running `bench_table1.py` with it"
        " (2026-11-30), davis_train fell from 16.66 to 15.52 dB (motion fidelity 0.975 to 0.952) and the"
        " backpack from 11.03 to 10.93 dB (fidelity 0.765 to 0.698), while the two cars stayed within 0.01 dB."
        " Halfway (0.85 px, 3 px): davis_train 16.91 dB, the backpack 10.82 dB (fidelity 0.715), and the"
        " synthetic poses mixed (`bench_extract.py` medians: out-of-plane 0.42° clean but 1.34° with 1 px of"
        " noise, against 0.55° and 1.13°). Motion fidelity is measured with this tracker too, so it moves with"
        " it; PSNR does not. No setting is better on both, so the defaults stay at 1 px and 4 px.",
        "",
        "| motion | pixel noise | blur / norm (px) | median error (px) | clipped mean (px) | strays > 1 px (%) "
        "| tracks | time (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {m} | {n:g} | {u} | {med:.3f} | {mean:.3f} | {s:.0f} | {c} | {t:.2f} |"
              for m, n, u, med, mean, s, c, t in rows]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
