"""Command line: a thin layer over :mod:`marionette.pipeline` (contract in DESIGN.md).

Every command prints one ``error: …`` line on stderr and exits with code 2 on
bad input or usage, and writes its outputs atomically.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from . import pipeline
from .camera import MAX_IMAGE_SIDE, Camera
from .errors import InputError
from .io import read_ply, read_prior, write_image, write_prior
from .io.atomic import check_output_dir, check_output_path
from .plot import plot_prior
from .progress import Reporter
from .render import render
from .render.camera_path import CAMERA_MOVES, camera_path, load_camera_path
from .source import ExtractOptions
from .transfer.controls import LOOPS

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Transfer the rigid motion of a video onto a single image, via 3D Gaussians.")

VIDEO_SUFFIXES = (".mp4", ".gif", "")

Quiet = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars or messages.")]
Output = Annotated[Path, typer.Option("--output", "-o", help="Output file.")]


def _parse_rgb(text: str) -> tuple[float, float, float]:
    """'R,G,B' with components in [0, 1] or 0..255 → floats in [0, 1]."""
    try:
        rgb = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--background must be R,G,B numbers, got {text!r}") from None
    if len(rgb) != 3 or not all(np.isfinite(rgb)) or min(rgb) < 0:
        raise InputError(f"--background must be three non-negative numbers R,G,B, got {text!r}")
    if max(rgb) > 1:
        if max(rgb) > 255:
            raise InputError(f"--background components must be at most 255, got {text!r}")
        rgb = tuple(x / 255 for x in rgb)
    return rgb


def _parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must be WIDTHxHEIGHT, got {text!r}") from None
    if not (16 <= w <= MAX_IMAGE_SIDE and 16 <= h <= MAX_IMAGE_SIDE):
        raise InputError(f"--size sides must be within 16..{MAX_IMAGE_SIDE}, got {text!r}")
    return w, h


def _parse_parts(text: str) -> int | str:
    if text == "auto":
        return "auto"
    if not text.isdigit() or not 1 <= int(text) <= 8:
        raise InputError(f"--parts must be 'auto' or an integer from 1 to 8, got {text!r}")
    return int(text)


def _parse_part_seeds(items: list[str] | None) -> dict[int, tuple[float, float]] | None:
    """['K:X,Y', …] → {K: (X, Y)}."""
    if not items:
        return None
    seeds = {}
    for item in items:
        try:
            part, xy = item.split(":")
            x, y = (float(v) for v in xy.split(","))
            seeds[int(part)] = (x, y)
        except ValueError:
            raise InputError(f"--part-seed must be K:X,Y (part, target pixel), got {item!r}") from None
    return seeds


def _video_output(path: Path) -> Path:
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"unsupported video output {path.name!r}: use .mp4, .gif or a folder name")
    return check_output_path(path)


def _transfer_checks(frames: Optional[int], speed: float, fps: Optional[float]) -> None:
    if frames is not None and not 2 <= frames <= 100_000:
        raise InputError(f"--frames must be between 2 and 100000, got {frames}")
    if not (np.isfinite(speed) and speed > 0):
        raise InputError(f"--speed must be positive, got {speed}")
    if fps is not None and not (np.isfinite(fps) and 0 < fps <= 240):
        raise InputError(f"--fps must be in (0, 240], got {fps}")


@app.command()
def demo(output: Annotated[Path, typer.Option("--output", "-o", help="Output folder.")] = Path("marionette-demo"),
         quiet: Quiet = False) -> None:
    """Run the whole method on a synthetic source and target; writes DIR/*.mp4."""
    from .demo import run_demo

    check_output_dir(output)
    run_demo(output, reporter=Reporter(quiet))


Masks = Annotated[Optional[Path], typer.Option(help="Folder of per-frame mask images (default: found automatically).")]
Depth = Annotated[Optional[Path], typer.Option(help="Folder of per-frame depth maps (16-bit PNG in mm, or .npy).")]
Focal = Annotated[Optional[float], typer.Option(help="Focal length in pixels (default: 60° horizontal FOV).")]
Parts = Annotated[str, typer.Option(help="Number of moving rigid parts, or 'auto' to choose; above 1, a static group is added when found.")]
Start = Annotated[int, typer.Option(help="First source frame to use.")]
End = Annotated[Optional[int], typer.Option(help="Source frame to stop before (default: the end).")]
Stride = Annotated[int, typer.Option(help="Use every N-th source frame.")]
MaxSide = Annotated[int, typer.Option(help="Downscale source frames to this long side (intrinsics follow).")]
Smooth = Annotated[float, typer.Option(help="Temporal smoothing of the poses (0: off).")]
Plot = Annotated[Optional[Path], typer.Option(help="Also draw each part's rotation and translation to this PNG.")]


def _extract(source: Path, masks, depth, focal, parts: str, start: int, end, stride: int, max_side: int,
             smooth: float, plot, reporter: Reporter):
    """Shared by ``extract`` and ``run``: check the options, extract, draw the plot."""
    parts_value = _parse_parts(parts)
    if not 16 <= max_side <= MAX_IMAGE_SIDE:
        raise InputError(f"--max-side must be within 16..{MAX_IMAGE_SIDE}, got {max_side}")
    if not (np.isfinite(smooth) and 0 <= smooth <= 100):
        raise InputError(f"--smooth must be within 0..100, got {smooth}")
    if plot is not None:
        if plot.suffix.lower() != ".png":
            raise InputError(f"--plot must name a .png file, got {plot.name!r}")
        check_output_path(plot)
    options = ExtractOptions(parts=parts_value, smoothing=smooth)
    prior = pipeline.extract(source, masks=masks, depth=depth, focal=focal, max_side=max_side, start=start,
                             end=end, stride=stride, options=options, reporter=reporter)
    if plot is not None:
        plot_prior(prior, plot, title=Path(source).name)
    return prior


@app.command()
def extract(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
            output: Output, masks: Masks = None, depth: Depth = None, focal: Focal = None, parts: Parts = "1",
            start: Start = 0, end: End = None, stride: Stride = 1, max_side: MaxSide = pipeline.DEFAULT_MAX_SIDE,
            smooth: Smooth = 1.0, plot: Plot = None, quiet: Quiet = False) -> None:
    """Extract the SpaT prior (per-part rigid motion) from a source video."""
    check_output_path(output)
    prior = _extract(source, masks, depth, focal, parts, start, end, stride, max_side, smooth, plot,
                     Reporter(quiet))
    write_prior(output, prior)


Frames = Annotated[Optional[int], typer.Option(help="Number of output frames (default: the source's length).")]
Speed = Annotated[float, typer.Option(help="Playback speed relative to the source.")]
Loop = Annotated[str, typer.Option(help="Past the source's end: hold, repeat or pingpong.")]
Reverse = Annotated[bool, typer.Option("--reverse", help="Play the source's motion backwards.")]
RotationScale = Annotated[float, typer.Option(help="Multiply every rotation angle.")]
TranslationScale = Annotated[float, typer.Option(help="Multiply every displacement of the parts' centres.")]
Fps = Annotated[Optional[float], typer.Option(help="Output frame rate (default: the source's).")]
Background = Annotated[str, typer.Option(help="Background colour R,G,B (0-1 or 0-255).")]
Size = Annotated[Optional[str], typer.Option(help="Output size WIDTHxHEIGHT for a .ply target (default 512x512); an image target is resized to it.")]
CameraMove = Annotated[str, typer.Option("--camera", help="Camera move: static, orbit or dolly.")]
CameraAmount = Annotated[Optional[float], typer.Option(help="Orbit degrees (default 30) or dolly share of the distance (default 0.3).")]
CameraPath = Annotated[Optional[Path], typer.Option(help="JSON list of CAMERA.json objects, one per frame (or one).")]
PartSeed = Annotated[Optional[list[str]], typer.Option(help="Seed of a part on the target, K:X,Y in target pixels (repeatable; default: matched from the source's part layout).")]
Anchor = Annotated[str, typer.Option(help="Turn each part about its own centre ('centroid') or about the source's world origin as the paper does ('world').")]
TargetMask = Annotated[Optional[Path], typer.Option(help="Image marking the target object (default: alpha, else found automatically).")]
PlyDir = Annotated[Optional[Path], typer.Option(help="Also write each frame's Gaussians as DIR/00000.ply ….")]


@dataclass(frozen=True)
class _Playback:
    """Checked options of ``transfer`` and ``run``."""

    frames: int | None
    speed: float
    loop: str
    reverse: bool
    rotation_scale: float
    translation_scale: float
    fps: float | None
    background: tuple[float, float, float]
    size: tuple[int, int] | None
    camera: str
    camera_amount: float | None
    camera_path: Path | None
    ply_dir: Path | None
    target_mask: Path | None
    anchor: str
    part_seeds: dict[int, tuple[float, float]] | None


def _playback(output: Path, frames, speed, loop, reverse, rotation_scale, translation_scale, fps, background, size,
              camera, camera_amount, camera_path, ply_dir, target_mask, anchor, part_seed) -> _Playback:
    """Check every playback option (before any work starts) and the output paths."""
    _transfer_checks(frames, speed, fps)
    if loop not in LOOPS:
        raise InputError(f"--loop must be one of {', '.join(LOOPS)}, got {loop!r}")
    for name, value in (("--rotation-scale", rotation_scale), ("--translation-scale", translation_scale)):
        if not (np.isfinite(value) and abs(value) <= 100):
            raise InputError(f"{name} must be a number within -100..100, got {value}")
    if camera not in CAMERA_MOVES:
        raise InputError(f"--camera must be one of {', '.join(CAMERA_MOVES)}, got {camera!r}")
    if camera_path is not None and camera != "static":
        raise InputError("--camera-path and --camera orbit/dolly exclude each other")
    if camera_path is not None and not camera_path.is_file():
        raise InputError(f"camera path {camera_path} does not exist")
    _video_output(output)
    if ply_dir is not None:
        check_output_dir(ply_dir)
    if anchor not in ("centroid", "world"):
        raise InputError(f"--anchor must be 'centroid' or 'world', got {anchor!r}")
    if target_mask is not None and not target_mask.is_file():
        raise InputError(f"target mask {target_mask} does not exist")
    return _Playback(frames, speed, loop, reverse, rotation_scale, translation_scale, fps, _parse_rgb(background),
                     _parse_size(size), camera, camera_amount, camera_path, ply_dir, target_mask, anchor,
                     _parse_part_seeds(part_seed))


def _transfer_and_render(prior, target: Path, output: Path, play: _Playback, reporter: Reporter) -> None:
    lifted = pipeline.load_target(target, size=play.size, mask=play.target_mask, prior=prior)
    trajectory = pipeline.transfer(prior, lifted, frames=play.frames, speed=play.speed, loop=play.loop,
                                   reverse=play.reverse, rotation_scale=play.rotation_scale,
                                   translation_scale=play.translation_scale, anchor=play.anchor,
                                   part_seeds=play.part_seeds)
    if play.camera_path is not None:
        cameras = load_camera_path(play.camera_path, trajectory.num_frames)
    else:
        cameras = camera_path(pipeline.fit_view(lifted.camera, trajectory), lifted.gaussians.means.mean(axis=0),
                              trajectory.num_frames, play.camera, play.camera_amount)
    pipeline.render_video(output, lifted.gaussians, trajectory, cameras, fps=play.fps or prior.fps,
                          background=play.background, reporter=reporter)
    if play.ply_dir is not None:
        pipeline.write_ply_frames(play.ply_dir, lifted.gaussians, trajectory)


@app.command()
def transfer(prior: Annotated[Path, typer.Argument(help="SpaT prior .npz.")],
             target: Annotated[Path, typer.Argument(help="Target image (RGB/RGBA) or 3DGS .ply.")],
             output: Output, frames: Frames = None, speed: Speed = 1.0, loop: Loop = "hold", reverse: Reverse = False,
             rotation_scale: RotationScale = 1.0, translation_scale: TranslationScale = 1.0, fps: Fps = None,
             background: Background = "1,1,1", size: Size = None, camera: CameraMove = "static",
             camera_amount: CameraAmount = None, camera_path: CameraPath = None, ply_dir: PlyDir = None,
             target_mask: TargetMask = None, anchor: Anchor = "centroid", part_seed: PartSeed = None,
             quiet: Quiet = False) -> None:
    """Apply a SpaT prior to a target image or .ply and render the video."""
    play = _playback(output, frames, speed, loop, reverse, rotation_scale, translation_scale, fps, background, size,
                     camera, camera_amount, camera_path, ply_dir, target_mask, anchor, part_seed)
    _transfer_and_render(read_prior(prior), target, output, play, Reporter(quiet))


@app.command()
def run(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
        target: Annotated[Path, typer.Argument(help="Target image (RGB/RGBA) or 3DGS .ply.")],
        output: Output, masks: Masks = None, depth: Depth = None, focal: Focal = None, parts: Parts = "1",
        start: Start = 0, end: End = None, stride: Stride = 1, max_side: MaxSide = pipeline.DEFAULT_MAX_SIDE,
        smooth: Smooth = 1.0, plot: Plot = None,
        frames: Frames = None, speed: Speed = 1.0, loop: Loop = "hold", reverse: Reverse = False,
        rotation_scale: RotationScale = 1.0, translation_scale: TranslationScale = 1.0, fps: Fps = None,
        background: Background = "1,1,1", size: Size = None, camera: CameraMove = "static",
        camera_amount: CameraAmount = None, camera_path: CameraPath = None, ply_dir: PlyDir = None,
        target_mask: TargetMask = None, anchor: Anchor = "centroid", part_seed: PartSeed = None,
        quiet: Quiet = False) -> None:
    """Extract the source's motion and transfer it onto the target in one go."""
    play = _playback(output, frames, speed, loop, reverse, rotation_scale, translation_scale, fps, background, size,
                     camera, camera_amount, camera_path, ply_dir, target_mask, anchor, part_seed)
    if not Path(target).exists():
        raise InputError(f"target {target} does not exist")
    reporter = Reporter(quiet)
    prior = _extract(source, masks, depth, focal, parts, start, end, stride, max_side, smooth, plot, reporter)
    _transfer_and_render(prior, target, output, play, reporter)


@app.command("render")
def render_cmd(scene: Annotated[Path, typer.Argument(help="3DGS .ply file.")],
               camera: Annotated[Path, typer.Option(help="CAMERA.json (DESIGN.md contract).")],
               output: Output, background: Background = "1,1,1") -> None:
    """Render a 3DGS .ply from a camera to a PNG."""
    bg = _parse_rgb(background)
    if output.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"unsupported image output {output.name!r}: use .png or .jpg")
    check_output_path(output)
    cam = Camera.load(camera)
    gaussians = read_ply(scene)
    out = render(gaussians, cam, bg)
    write_image(output, (np.clip(out.image, 0, 1) * 255 + 0.5).astype(np.uint8))


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Library warnings as one ``warning: …`` line on stderr, without source locations."""
    print(f"warning: {str(message).splitlines()[0]}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning bad input into ``error: …`` and exit code 2."""
    warnings.showwarning = _show_warning
    try:
        app(args=argv, standalone_mode=False, prog_name="marionette")
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        print("error: interrupted", file=sys.stderr)
        return 130
    except typer.TyperException as e:  # typer >= 0.29 vendors click; usage errors land here
        print(f"error: {e.format_message().splitlines()[0]}", file=sys.stderr)
        return 2
    except InputError as e:
        print(f"error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
