"""Make the gallery: the shared clips' motions transferred onto the shared photos, good runs and failures.

Needs ``../shared/data``. Each case runs ``marionette run`` as a user would
(the command is shown on the page), then draws a contact sheet from its
side-by-side video: source frames (top) over result frames (bottom) at five
moments. Writes ``docs/images/gallery/<case>.png`` and ``docs/gallery.md``.
A case takes 10-40 s of CPU.

    flock /tmp/marionette-bench.lock python benchmarks/gallery.py [--only car-turn,train]
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from marionette.io import read_video

ROOT = Path(__file__).resolve().parents[1]
DATA = Path("..") / "shared" / "data"  # as the commands on the page name it, from the project root
IMAGES = ROOT / "docs" / "images" / "gallery"
PAGE = ROOT / "docs" / "gallery.md"
#: Quick settings: a 480 px source, 48 output frames spanning the whole clip.
QUICK = ("--max-side", "480", "--frames", "48")
PHOTOS = {"teapot": "realfusion15_colorful_teapot/image_rgba.png", "cat": "realfusion15_cat_statue/image_rgba.png",
          "chair": "instantmesh_chair_armed/chair_armed.png",
          "extinguisher": "instantmesh_extinguisher/extinguisher.png"}


@dataclass(frozen=True)
class Case:
    """One gallery entry: a shared clip, a shared photo, extra options, and what the picture shows."""

    name: str
    clip: str
    photo: str
    options: tuple[str, ...]
    note: str
    works: bool = True

    def command(self) -> list[str]:
        """The ``marionette run`` command, paths relative to the project root."""
        clip = DATA / "videos" / self.clip
        source = clip / "source.mp4" if self.clip.startswith(("cotracker", "partnet")) else clip / "frames"
        masks = ("--masks", str(clip / "masks")) if source.name == "frames" else ()
        return ["marionette", "run", str(source), str(DATA / "images" / PHOTOS[self.photo]),
                "-o", f"{self.name}.mp4", *masks, *self.options, *QUICK, "--side-by-side", f"{self.name}_sbs.mp4"]


CASES = (
    Case("car-turn", "davis_car-turn", "teapot", (),
         "The SUV comes towards the camera and yaws to a side view: the teapot comes nearer and turns. The view"
         " zooms out to keep the whole motion in the picture, so the teapot starts small."),
    Case("car-shadow", "davis_car-shadow", "chair", (),
         "The car drives away across the junction, turning a little: the chair recedes and turns as little."),
    Case("train", "davis_train", "cat", ("--parts", "3"),
         "Coupled cars on a curved track, fitted as three rigid parts (`--parts 3`: at this 480 px size"
         " `--parts auto` keeps the train whole); the statue is split into as many parts, laid out as the"
         " train's, and each turns with its car round the curve."),
    Case("bus", "davis_bus", "cat", (),
         "The bus crosses a third of the picture behind trees. The result is filmed as by a camera aimed at"
         " the object, so a crossing shows only as the small change of the angle it is seen at: the cat turns"
         " slightly and stays in the middle."),
    Case("backpack", "cotracker_backpack", "teapot", ("--source-point", "240,200", "--source-exclude", "190,55"),
         "Fails: the bag, picked by a click with the arm excluded, swings and twists about its strap; the"
         " teapot tumbles about a horizontal axis instead and ends on its side. No masks, a hand-held camera"
         " and a hand that moves the bag make the poses wrong.", works=False),
    Case("drift-turn", "davis_drift-turn", "chair", (),
         "Fails in part: the approach comes through, most of the car's yaw in the tyre smoke does not, and the"
         " chair tips over at the end, where the car leaves the picture.", works=False),
    Case("motocross-bumps", "davis_motocross-bumps", "extinguisher", (),
         "Fails: the bike comes over bumps towards the camera with its rider moving on it, which is not one"
         " rigid body; the extinguisher, tiny because the view zooms out to hold its whole path, tumbles"
         " onto its side.", works=False),
    Case("soccerball", "davis_soccerball", "teapot", (),
         "Fails: the ball rolls across the grass behind a tree trunk; the teapot turns a little in the first"
         " frames and then stands still, the roll lost.", works=False),
    Case("chest-lid", "partnet_chest_lid", "teapot", ("--parts", "auto"),
         "Fails: a chest's lid opening on its hinge (a render, no masks). The teapot is split as the chest is"
         " and, rather than a lid opening, it is thrown towards the camera and out of the picture.",
         works=False),
)


def run_case(case: Case, folder: Path) -> list[np.ndarray]:
    """Run the case's command in ``folder``; its side-by-side frames, (T, H, W, 3) uint8."""
    command = case.command()
    command[2:4] = [str((ROOT / p).resolve()) for p in command[2:4]]
    if "--masks" in command:
        i = command.index("--masks") + 1
        command[i] = str((ROOT / command[i]).resolve())
    subprocess.run(command, cwd=folder, check=True)
    return read_video(folder / f"{case.name}_sbs.mp4").frames


def contact_sheet(frames: np.ndarray, result_width: int, moments: int = 5, height: int = 150,
                  pad: int = 3) -> np.ndarray:
    """Side-by-side frames (T, H, W, 3) → source row over result row at ``moments`` times, tiles ``height`` high.

    ``result_width``: the result's width in the side-by-side frames (it sits on the right). Each result
    is centred under its source frame.
    """
    picks = np.linspace(0, len(frames) - 1, moments).round().astype(int)
    columns = []
    for t in picks:
        pair = []
        for part in (slice(None, -result_width), slice(-result_width, None)):
            tile = Image.fromarray(frames[t][:, part])
            pair.append(np.asarray(tile.resize((round(tile.width * height / tile.height), height),
                                               Image.Resampling.LANCZOS)))
        width = max(tile.shape[1] for tile in pair) + 2 * pad
        columns.append(np.concatenate(
            [np.pad(tile, ((pad, pad), ((width - tile.shape[1]) // 2, (width - tile.shape[1] + 1) // 2), (0, 0)),
                    constant_values=255) for tile in pair], axis=0))
    return np.concatenate(columns, axis=1)


def write_page(path: Path) -> None:
    """``docs/gallery.md``: every case's picture, what it shows, and its command."""
    lines = ["# Gallery", "",
             "The shared clips' motions transferred onto the shared photos with `marionette run`, at quick"
             " settings (a 480 px source, 48 output frames over the whole clip). Each picture: source frames"
             " (top) and result frames (bottom) at five moments. Made by"
             " `flock /tmp/marionette-bench.lock python benchmarks/gallery.py` (needs `../shared/data`; about"
             " 3 minutes on two cores); a case's own command, run from the project root, writes its video and"
             " side-by-side video.", ""]
    for works in (True, False):
        lines += ["## What works", ""] if works else ["## Hard clips and failures", ""]
        for case in (c for c in CASES if c.works == works):
            lines += [f"### {case.name} → {case.photo}", "",
                      f"![{case.name} onto the {case.photo}](images/gallery/{case.name}.png)", "",
                      case.note, "", "```bash", shlex.join(case.command()), "```", ""]
    path.write_text("\n".join(lines).rstrip() + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", help="comma-separated case names to run (the page lists every case)")
    args = parser.parse_args()
    cases = CASES
    if args.only:
        names = set(args.only.split(","))
        if names - {c.name for c in CASES}:
            parser.error(f"unknown case(s): {', '.join(sorted(names - {c.name for c in CASES}))}")
        cases = tuple(c for c in CASES if c.name in names)
    IMAGES.mkdir(parents=True, exist_ok=True)
    for case in cases:
        with tempfile.TemporaryDirectory() as tmp:
            frames = run_case(case, Path(tmp))
            result = read_video(Path(tmp) / f"{case.name}.mp4").frames
        width = round(result.shape[2] * frames.shape[1] / result.shape[1])
        sheet = Image.fromarray(contact_sheet(frames, width + width % 2))
        sheet.quantize(256, dither=Image.Dither.NONE).save(IMAGES / f"{case.name}.png", optimize=True)
        print(f"wrote {IMAGES / case.name}.png", file=sys.stderr)
    write_page(PAGE)
    print(f"wrote {PAGE}", file=sys.stderr)


if __name__ == "__main__":
    main()
