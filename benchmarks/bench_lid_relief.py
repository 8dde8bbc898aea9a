"""How much of the hinge lid's rotation error the assumed relief decides (issue 16's lid target).

The synthetic hinge (seed 0, 32 frames, 320x240: the body stays, the lid opens ~77°) extracted with
``parts="auto"`` under several reliefs of the silhouette lift (``ExtractOptions.relief``) and weights of the
bundle adjustment's depth prior (``RigidOptions.depth_prior_weight``). Per setting: the lid's median and largest
rotation error over frames 1..31, and the estimated turn over the true one at frame 4 (early: the lid's frame-0 tracks
have a median error of 0.06 px at frame 3) and at the end. Writes ``docs/benchmarks/lid_relief.md``.

    flock /tmp/marionette-bench.lock python benchmarks/bench_lid_relief.py
"""

from __future__ import annotations

import platform
import warnings
from pathlib import Path

import numpy as np

from marionette.geometry import rotation_angle_deg
from marionette.source.extract import ExtractOptions, extract_prior
from marionette.source.rigid import RigidOptions
from marionette.synthetic import make_scene

PAGE = Path(__file__).resolve().parents[1] / "docs" / "benchmarks" / "lid_relief.md"
#: (relief, depth prior weight, hinge joints); the defaults first, then the free fit under each relief and weight.
SETTINGS = [(1.0, 0.1, True), (1.0, 0.1, False), (0.5, 0.1, False), (0.25, 0.1, False), (2.0, 0.1, False),
            (1.0, 0.01, False), (1.0, 1.0, False), (0.5, 1.0, False), (0.5, 0.1, True), (2.0, 0.1, True)]


#: What the rows say; the first paragraph reads the free rows as they were measured on 2026-12-03.
READING = """\
Reading (2026-12-03, free fit): the lid's early turn scales inversely with the relief the silhouette lift
assumes (frame 4: 0.23 of the truth at relief 2, 0.58 at 1, 1.17 at 0.5, 2.42 at 0.25), and a hundred times weaker
depth prior changes nothing (0.60): the tracks do not decide the lid's rotation, the assumed relief does (the bas-relief
ambiguity of a thin part turning away from the camera, with sub-pixel track noise). No single relief fixes it
(best median 10.9° at 0.5, with a 36° worst frame). What could decide it: the lid's attachment to the body (a
hinge: its motion a turn about an axis on the body, whose structure is known), or its silhouette.

Reading (2026-12-04): with the lid fitted as a hinge on the body (`marionette/source/hinge.py`: one angle per frame
about an axis fixed in the body, fitted by variable projection with a Cauchy loss on up to 400 tracks and 24 key
frames, tracks that do not follow it dropped, the other frames' angles fitted one by one), the lid's error no longer
follows the assumed relief (1.16-1.55° median, 1.9-2.8° worst, turn ratios 0.97-0.98), against 14.0° median for the
free fit at the defaults. The target (<= 1°) is not met: on the tracks' exact positions (`scene.track_truth`) the
same fit is 0.06° off, so what is left is the Lucas-Kanade drift on the lid (up to 2.9 px at frames 13-15, where it
turns edge-on). The hinge fit has local minima: at relief 0.5, sampling 120 or 200 tracks instead of 400 ended 13° and
22° off with a lower residual than the right answer (session script, 2026-12-04). The free rows moved from the page
of 2026-12-03 (relief 0.5: 10.85 -> 28.21°): the free fit of the thin lid is that unstable.
"""


def main() -> None:
    warnings.simplefilter("ignore")
    scene = make_scene("hinge", seed=0, num_frames=32, size=(320, 240))
    true = scene.poses[1]
    lines = ["# The hinge lid's rotation against the assumed relief", "",
             f"`python benchmarks/bench_lid_relief.py` on {platform.machine()}. The synthetic hinge (seed 0, 32 "
             "frames, 320x240; the lid opens ~77°, the body stays) extracted with `parts=\"auto\"` and the "
             "tracker's own tracks, under each relief of the silhouette lift (`ExtractOptions.relief`, default 1) "
             "and weight of the depth prior (`RigidOptions.depth_prior_weight`, default 0.1), with the lid fitted as a "
             "hinge on the body (`ExtractOptions.joints`, default on) or free. Lid error: rotation "
             "error of the part that turns most, over frames 1-31. Turn ratio: its estimated turn over the true one.",
             "", "| relief | depth prior weight | joints | parts | lid error median (°) | lid error max (°) "
             "| turn ratio, frame 4 | turn ratio, frame 31 |", "|---:|---:|---|---:|---:|---:|---:|---:|"]
    for relief, weight, joints in SETTINGS:
        options = ExtractOptions(parts="auto", relief=relief, joints=joints,
                                 rigid=RigidOptions(depth_prior_weight=weight))
        prior = extract_prior(scene.frames, scene.masks, scene.camera.K, scene.fps, options=options)
        lid = int(np.argmax(rotation_angle_deg(prior.poses[:, -1, :3, :3])))
        est = prior.poses[lid]
        err = rotation_angle_deg(est[1:, :3, :3] @ np.swapaxes(true[1:, :3, :3], -1, -2))
        ratio = [rotation_angle_deg(est[t, :3, :3]) / rotation_angle_deg(true[t, :3, :3]) for t in (4, 31)]
        model = (prior.metadata.get("joints") or {}).get("1", {}).get("model", "–") if joints else "off"
        lines.append(f"| {relief:g} | {weight:g} | {model} | {prior.num_parts} | {np.median(err):.2f} | "
                     f"{err.max():.2f} | {ratio[0]:.2f} | {ratio[1]:.2f} |")
        print(lines[-1], flush=True)
    PAGE.write_text("\n".join(lines) + "\n\n" + READING)
    print(f"wrote {PAGE}")


if __name__ == "__main__":
    main()
