"""Peak memory and per-stage time of ``marionette extract`` on a long 480p video.

Builds (once, cached in ``--cache``) a synthetic 1000-frame 854x480 clip of an
oscillating box (``make_scene``) as an H.264 mp4 plus a folder of PNG masks,
then runs ``marionette extract`` on it in a subprocess, with the masks and
without them (automatic foreground), and reports the peak resident set size
of that process (``wait4``'s ``ru_maxrss``) with the wall time of each stage
(the prior's ``timings`` metadata; "reading" is what the run spent outside
``extract_prior``: start-up, decoding, mask reading). Writes
``docs/benchmarks/memory.md``.

    python benchmarks/bench_memory.py [--frames 1000] [--size 854x480] [--cases masks,auto,prompt]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from marionette.io import read_mask, read_prior, write_image, write_video  # noqa: E402 (after OPENBLAS_NUM_THREADS)
from marionette.synthetic import make_scene  # noqa: E402

BUDGET_MB = 2048
OUT = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "memory.md"


NOTES = """## Before

- 2026-11-30 (commit 29d1055, frames decoded whole): with masks at least 2622 MB, stopped after 44 min in the
  pose stage; without masks more than 3.3 GB (the frames and the foreground's flows alone).
- 2026-11-30, streamed (the page of that day): 1109 MB with masks (2313 s under a load of 4-15); the
  foreground stage alone 1251 MB without masks.
- 2026-12-05 (commit 1a3cefc): with masks, 2236 MB and still in the pose stage after 46 min (stopped): over
  the budget. Strict tracks (since 2026-12-05 the default where windows keep matching, as on this clip) are
  pieces, 28,547 of them here over 1000 frames, and the pose fit held whole-clip arrays of them: a float64
  copy of the tracks (T x M x 2, 457 MB) and, at its end, the reprojection errors of every track in every
  frame computed at once (T x M x 3 float64 camera points, 685 MB). Its bundle adjustment built each matrix
  entry's row and column (288 bytes per observation) and solved a system the long tracks fill to 80 % or more
  by SuperLU (`bundle.md`). Fixed that night (23e3b26): float32 tracks, errors a million point-frames at a
  time, block-sparse matrices.
- 2026-12-05, night: a 500-frame run read "2102 MB", which was not the extraction's peak. The benchmark had
  rendered the clip in its own process (2104 MB, measured alone), and on Linux a child inherits its parent's
  high-water mark at `exec`: `wait4`'s `ru_maxrss` is at least the parent's peak when it started the child (a
  process that grows by 1.5 GB, frees it and starts `python -c pass` reads 1526 MB for the child). The
  extraction's own `VmHWM` was about 1 GB. The clip is now rendered in a process of its own, and a peak not
  above the benchmark's own is refused.
- 2026-12-06, 23e3b26 with the windowed refinement below: 2361 MB (wall 1376 s, poses 1165 s). The
  sequential pass reached 1.41 GB; the final refinement, every frame free, added 0.95 GB: its reduced system
  dense (6,000 x 6,000, 288 MB) next to the whole block-sparse product it was copied from (288 MB), and
  scipy's own copy before LAPACK (288 MB: scipy overwrites only a Fortran-ordered matrix). Now the product is
  formed a slab of frames at a time into the dense matrix, which is solved in place; W's blocks are used
  without copies when they come in frame order; a part holding every track is fitted from the tracks
  themselves, not a 228 MB copy. That refinement's bundle adjustment, replayed from its saved inputs (3 cost
  evaluations, 241 MB loaded): peak 1385 MB before, 873 MB after, the same poses to 3e-15.
- 2026-12-06 (949c73b): 1539 MB with masks, 1944 MB without (5 % under the budget). The final refinement
  then fitted the points it leaves out (every other track, 20,000 pieces here) with all their observations at
  once; now 2048 points at a time (each point is fitted alone: the same bits).
- 2026-12-06 (f8e6d5d): 1495 MB with masks; without masks 1983 MB, 3 % under the budget. The extra 0.5 GB
  without masks was the salient-object network's: ONNX Runtime keeps a memory arena as large as its largest
  run needed (about 0.3 GB after one 320 x 320 prediction, 0.5 GB after a few) for as long as the session
  lives, and the packaged model's session lived to the end of the process. Now the foreground stage releases
  it once the key frames are done (as do one photo's or prompt's mask; a new session takes about 40 ms).
  Measured the same day before that change's full run: 1407 MB without masks (in a run of that case alone).
  The `prompt` case (a click on frame 0, `--source-point`) was added then; its masks are found before
  `extract_prior` starts, so its foreground time is part of 'reading'.

## Time

The pose stage of 1a3cefc ran more than 40 minutes on this clip: every 8 frames the sequential pass refined
all frames so far, each refinement's reduced system growing with the frames squared. Now those refinements
move only the last 200 frames (`RigidOptions.refine_window`), the earlier ones held with their tracks; the final
refinement still moves every frame. Clips of up to 200 frames come out the same bits. On this clip the poses'
median rotation error is 0.041° over the 1000 frames (session script against the scene's truth); on its first
300 frames the pose stage took 116 s against 166 s, with the same error (0.026°).

## Where the memory goes

Before streaming (commit 29d1055), `marionette extract` decoded the whole
video into one array and every stage worked on whole-video arrays. For this
clip: frames (T, H, W, 3) uint8 1.23 GB, masks (T, H, W) bool 0.41 GB, and
without masks the foreground's optical flows, both directions, (T-1, h, w, 2)
float32 at the 480 x 270 working size, 2.07 GB, plus several (T, h, w) float32
maps of 0.52 GB each. Measured then, on the same machine: with masks at
least 2622 MB (the high-water mark when stopped after 44 min in the pose
stage); without masks the frames and flows alone pass 3.3 GB.

Now:

- frames are decoded on demand (`open_video` → `VideoFrames`): one pass to
  count and check them, then one pass per stage that needs pixels
  (foreground, object tracking, background tracking), each in order; only
  the current frame is held;
- masks are packed bits (`PackedMasks`, 51 MB here) and unpacked per frame;
- the foreground keeps one greyscale frame per frame at the working size
  (130 MB here) and packed masks, and frees the salient-object network's
  session (its memory arena) after the key frames; flows are computed on demand with a
  bounded cache (128 MB per direction) and recomputed by later stages when
  they fell out of it; saliency is propagated and the background residuals
  are computed in the same pass, frame by frame;
- depth maps (`--depth`) are checked once and read again per frame
  (`DepthMaps`), and lifted one frame at a time.

What still grows with T x H x W: the packed masks, the background masks of
the camera-motion stage (`estimate_camera_motion` stacks them as bool,
0.41 GB here: the largest single item left), and the tracking's anchor
images (one normalised float32 image and mask per frame still anchoring a
live track). Tracks grow with T x M. `open_video(max_pixels=2**29)`
downscales (with a warning) a video whose frames hold more pixels in all, so
that these stay bounded.
""".splitlines()


def make_clip(cache: Path, frames: int, size: tuple[int, int]) -> tuple[Path, Path]:
    """The cached clip ``cache/clip.mp4`` and its mask folder ``cache/masks``; rendered when missing.

    Rendered in a process of its own: a child started later inherits its parent's high-water mark at ``exec``
    (Linux keeps the larger of the two in ``ru_maxrss``), so a parent that had held the rendered clip would
    show up as the child's peak.
    """
    video, masks = cache / "clip.mp4", cache / "masks"
    if not (video.is_file() and masks.is_dir() and len(list(masks.iterdir())) == frames):
        renderer = multiprocessing.get_context("spawn").Process(target=_render_clip, args=(cache, frames, size))
        renderer.start()
        renderer.join()
        if renderer.exitcode != 0:
            raise RuntimeError(f"rendering the clip failed ({renderer.exitcode})")
    return video, masks


def _render_clip(cache: Path, frames: int, size: tuple[int, int]) -> None:
    video, masks = cache / "clip.mp4", cache / "masks"
    cache.mkdir(parents=True, exist_ok=True)
    scene = make_scene("oscillation", num_frames=frames, size=size, seed=0)
    masks.mkdir(exist_ok=True)
    for t, mask in enumerate(scene.masks):
        write_image(masks / f"{t:05d}.png", mask)
    write_video(video, scene.frames, scene.fps)


def case_options(case: str, masks: Path) -> list[str]:
    """``marionette extract`` options of a case: the masks given, none, or a click on the object's frame-0 centre."""
    if case == "masks":
        return ["--masks", str(masks)]
    if case == "prompt":
        rows, cols = np.nonzero(read_mask(sorted(masks.iterdir())[0]))
        return ["--source-point", f"{cols.mean():.0f},{rows.mean():.0f}"]
    if case == "auto":
        return []
    raise SystemExit(f"error: unknown case {case!r} (masks, auto, prompt)")


def run_extract(video: Path, options: list[str], output: Path) -> tuple[float, float, float, dict[str, float]]:
    """Run ``marionette extract`` in a child process → (peak RSS in MB, wall and CPU seconds, stage timings)."""
    cmd = [sys.executable, "-m", "marionette", "extract", str(video), "-o", str(output), "--quiet", *options]
    parent_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    start = time.perf_counter()
    process = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    stderr = process.stderr.read()
    process.stderr.close()
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({process.returncode}):\n{stderr}")
    if stderr.strip():
        print(stderr.strip(), file=sys.stderr)
    timings = dict(read_prior(output).metadata["timings"])
    peak = usage.ru_maxrss / 1024.0
    if peak <= parent_peak:  # the child's own peak is hidden under the one it inherited (see make_clip)
        raise RuntimeError(f"the child's peak ({peak:.0f} MB) is not above this process's ({parent_peak:.0f} MB)")
    return peak, wall, usage.ru_utime + usage.ru_stime, timings  # ru_maxrss: KiB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--size", default="854x480")
    parser.add_argument("--cases", default="masks,auto",
                        help="masks (given masks), auto (found automatically), prompt (a click on frame 0)")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/marionette-bench-memory"))
    parser.add_argument("--output", type=Path, default=OUT)
    args = parser.parse_args()
    size = tuple(int(x) for x in args.size.lower().split("x"))

    start = time.perf_counter()
    video, masks = make_clip(args.cache / f"{args.frames}x{size[0]}x{size[1]}", args.frames, size)
    print(f"clip ready ({time.perf_counter() - start:.0f} s): {video}", flush=True)

    stages = ("foreground", "tracking", "camera", "poses", "smoothing")
    rows = []
    for case in args.cases.split(","):
        peak, wall, cpu, timings = run_extract(video, case_options(case, masks), args.cache / f"{case}.npz")
        reading = wall - timings["total"]
        cells = [f"{timings[s]:.1f}" if s in timings else "-" for s in stages]
        rows.append(f"| {case} | {peak:.0f} | {'yes' if peak <= BUDGET_MB else 'NO'} | {wall:.1f} | {cpu:.1f} | "
                    f"{reading:.1f} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)

    lines = [
        "# Peak memory of `marionette extract` on a long video",
        "",
        f"`python benchmarks/bench_memory.py --frames {args.frames} --size {args.size} --cases {args.cases}` "
        f"on {platform.machine()}, Python {platform.python_version()}, {os.cpu_count()} cores (shared).",
        "",
        f"Input: a synthetic {args.frames}-frame {size[0]}x{size[1]} H.264 clip (`make_scene('oscillation')`) "
        "and its PNG masks. `masks`: `marionette extract clip.mp4 --masks masks/`; `auto`: without masks "
        "(automatic foreground); `prompt`: `--source-point` on the object's centre in frame 0. Peak RSS: "
        "`ru_maxrss` of the `marionette` process (`os.wait4`). Times in seconds: wall and CPU (user + system) "
        "time of the process; 'reading' is the wall time outside "
        "`extract_prior` (start-up, decoding, masks); stages from the prior's `timings` (wall). "
        f"Budget: {BUDGET_MB} MB.",
        "",
        "| case | peak RSS (MB) | within budget | wall (s) | CPU (s) | reading | " + " | ".join(stages) + " |",
        "|---|---|---|---|---|---|" + "---|" * len(stages),
        *rows,
        "",
        *NOTES,
    ]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text("\n".join(lines))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
