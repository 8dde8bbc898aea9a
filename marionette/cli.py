"""Command line: a thin layer over :mod:`marionette.pipeline` (contract in docs/DESIGN.md).

Every command prints one ``error: …`` line on stderr and exits with code 2 on
bad input or usage, and writes its outputs as one unit: all under temporary
names, put in place together when the command succeeds
(:class:`~marionette.io.atomic.StagedOutputs`); no output may be one of its
inputs (:func:`_check_overwrites`). A command imports the stages it
runs when it runs (not at start-up), so that ``--help`` and a mistyped option
answer at once.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
import tomllib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import numpy as np
import typer

from .camera import MAX_IMAGE_SIDE, Camera
from .errors import InputError
from .geometry import rotation_angle_deg
from .io import read_ply, read_prior, write_gltf_animation, write_image, write_ply, write_prior, write_splat_animation
from .io.atomic import StagedOutputs, check_output_dir, check_output_folder, check_output_path, staged_outputs
from .io.ply import PLY_FRAME_NAME
from .io.video import DEFAULT_MAX_PIXELS, DEFAULT_MAX_SIDE, MASK_FRAME_NAME
from .options import (
    checked,
    parse_background,
    parse_box,
    parse_focal,
    parse_part_seeds,
    parse_parts,
    parse_point,
    parse_scene_background,
    parse_size,
)
from .prior import CAMERA_EXTRA, MOTION_FRAMES
from .progress import Reporter, interrupt_requested, sigterm_as_interrupt
from .transfer.controls import LOOPS, output_length, source_times

if TYPE_CHECKING:
    from .segment import Prompt

#: Help panels, in the order shown: a command's options grouped by what they are for.
PANELS = SOURCE, SELECTION, MOTION, PLAYBACK, TARGET, CAMERA, OUTPUT, PERFORMANCE, SERVER, GENERAL = (
    "Source", "Object selection", "Motion", "Playback", "Target", "Camera", "Output", "Performance", "Server",
    "General")

#: Options that name an output; every other path a command takes is one of its inputs.
OUTPUT_OPTIONS = ("output", "plot", "save_masks", "ply_dir", "splats", "gltf", "preview", "side_by_side", "report")


def _check_overwrites(ctx: typer.Context) -> None:
    """Refuse an output that is an input or another output, lies inside an input folder or holds one.

    Paths are compared resolved (``./a/../b.mp4`` is ``b.mp4``, links followed), so that nothing a command
    reads is lost to what it writes.
    """
    labels = {p.name: p.opts[0] if p.param_type_name == "option" else p.name.upper() for p in ctx.command.params}
    given = {name: value for name, value in ctx.params.items() if isinstance(value, Path)}
    resolved = {name: path.resolve() for name, path in given.items()}
    for out in (name for name in given if name in OUTPUT_OPTIONS):
        place = resolved[out]
        for name, path in resolved.items():
            if name == out:
                continue
            if path == place:
                how = "is also"
            elif name not in OUTPUT_OPTIONS and place.is_relative_to(path):
                how = "is inside"
            elif name not in OUTPUT_OPTIONS and path.is_relative_to(place) and path.is_dir():
                how = "holds"
            else:
                continue
            raise InputError(f"{labels[out]} {given[out]} {how} {labels[name]} {given[name]}; "
                             "give it a path of its own")


@contextlib.contextmanager
def _output_folders(ctx: typer.Context) -> Iterator[None]:
    """Make the missing folders the outputs go in (``-o results/out.mp4``); remove them again if the command
    fails or is interrupted."""
    made: list[Path] = []
    try:
        for name in OUTPUT_OPTIONS:
            path = ctx.params.get(name)
            for folder in reversed([f for f in (path.parents if path else ()) if not f.exists()]):
                try:
                    folder.mkdir()
                except OSError as e:
                    raise InputError(f"cannot make output folder {folder}: {e.strerror}") from None
                made.append(folder)
        yield
    except BaseException:
        for folder in reversed(made):
            with contextlib.suppress(OSError):  # only if nothing is in it
                folder.rmdir()
        raise


class _PlainHelp:
    """``--help`` as a plain flag among the general options (typer's rich help lists it as ``--help <bool>``)."""

    def get_help_option(self, ctx: typer.Context):
        option = super().get_help_option(ctx)
        if option is not None:
            option.metavar, option.rich_help_panel = "", GENERAL
        return option


class _Group(_PlainHelp, typer.core.TyperGroup):
    """The command group, with a plain ``--help``."""


class _Command(_PlainHelp, typer.core.TyperCommand):
    """A command with a plain ``--help``, its options in panel order; before it runs, its outputs are checked
    against its inputs and their missing folders made."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.params.sort(key=lambda p: PANELS.index(p.rich_help_panel) if p.rich_help_panel else -1)

    def invoke(self, ctx: typer.Context):
        _check_overwrites(ctx)
        with _output_folders(ctx):
            return super().invoke(ctx)


app = typer.Typer(cls=_Group, add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="Transfer the rigid motion of a video onto a single image, via 3D Gaussians.")

VIDEO_SUFFIXES = (".mp4", ".gif", "")

Output = Annotated[Path, typer.Option("--output", "-o", help="Output file.", rich_help_panel=OUTPUT)]
OutputDir = Annotated[Path, typer.Option("--output", "-o", help="Output folder.", rich_help_panel=OUTPUT)]


def _load_config(ctx: typer.Context, value: Optional[Path]) -> Optional[Path]:
    """``--config FILE``: option defaults from a TOML file; the command line wins.

    Top-level keys are options (``max-side = 640`` or ``max_side = 640``);
    a table named after a command (``[run]``) applies to that command only.
    Keys that are options of other commands are ignored, unknown keys are an
    error. Relative paths are taken from the file's folder.
    """
    if value is None or ctx.resilient_parsing:
        return value
    try:
        table = tomllib.loads(Path(value).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"config file {value} does not exist") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"config file {value} is not valid TOML: {e}") from None
    commands = {c.name: c for c in typer.main.get_command(app).commands.values()}
    known = {p.name for c in commands.values() for p in c.params}
    params = {p.name: p for p in ctx.command.params if p.name != "config"}
    options: dict[str, Any] = {}
    for key, item in table.items():
        if key in commands and isinstance(item, dict):
            if key == ctx.command.name:
                sections = {k.replace("-", "_"): v for k, v in item.items()}
                unknown = sorted(set(sections) - set(params))
                if unknown:
                    raise InputError(f"config file {value}: [{key}] has no option {unknown[0]!r}")
                options.update(sections)
            continue
        name = key.replace("-", "_")
        if name not in known or name == "config":
            raise InputError(f"config file {value}: unknown option {key!r}")
        if name in params:
            options.setdefault(name, item)
    for name, item in options.items():
        if params[name].param_type_name == "argument":
            raise InputError(f"config file {value}: {name!r} is an argument, give it on the command line")
        if getattr(params[name].type_descriptor, "annotation", None) is Path and isinstance(item, str):
            item = str(Path(value).parent / Path(item).expanduser())
        options[name] = item
    ctx.default_map = {**(ctx.default_map or {}), **options}
    return value


Config = Annotated[Optional[Path], typer.Option(
    help="TOML file of option defaults ([COMMAND] tables allowed).", rich_help_panel=GENERAL,
    is_eager=True, callback=_load_config)]
Quiet = Annotated[bool, typer.Option("--quiet", "-q", metavar="", help="No progress bars or messages.",
                                     rich_help_panel=GENERAL)]
Verbose = Annotated[bool, typer.Option("--verbose", "-v", metavar="",
                                       help="Also print each stage's time and the figures.", rich_help_panel=GENERAL)]
Json = Annotated[bool, typer.Option("--json", metavar="", help="Print a JSON summary, or the error, on stdout.",
                                    rich_help_panel=GENERAL)]


@dataclass
class _Session:
    """One command's reporter, its staged outputs and the summary it prints at the end."""

    command: str
    reporter: Reporter
    staged: StagedOutputs
    outputs: dict[str, str] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    start: float = field(default_factory=time.perf_counter)

    def summary(self) -> dict[str, Any]:
        """Outputs, figures, warnings and stage timings so far (the ``--json`` summary)."""
        timings = {k: round(v, 3) for k, v in self.reporter.timings.items()}
        timings["total"] = round(time.perf_counter() - self.start, 3)
        return {"command": self.command, "outputs": self.outputs, "figures": self.figures,
                "warnings": self.warnings, "timings": timings}

    def stage(self, path: Path) -> Path:
        """The temporary name to write output ``path`` to; a folder for a video without suffix (frame folder)."""
        return self.staged.folder(path) if not path.suffix else self.staged.file(path)

    def output(self, kind: str, path: Path) -> None:
        """List output ``path`` in the summary."""
        self.outputs[kind] = str(path)

    def warn(self, message, category=UserWarning, filename="", lineno=0, file=None, line=None) -> None:
        """Show a warning as one ``warning: …`` line and keep it for the summary (``warnings.showwarning``)."""
        _show_warning(message, category, filename, lineno)
        self.warnings.append(str(message).splitlines()[0])


@contextlib.contextmanager
def _session(command: str, quiet: bool, verbose: bool, as_json: bool) -> Iterator[_Session]:
    """Run a command body; then put its outputs in place and print its summary (JSON on stdout, or lines on stderr).

    If the body fails or is interrupted, none of its outputs is put in place.
    """
    if quiet and verbose:
        raise InputError("--quiet and --verbose exclude each other")
    with staged_outputs() as staged, warnings.catch_warnings():
        session = _Session(command, Reporter(quiet=quiet, verbose=verbose), staged)
        warnings.showwarning = session.warn
        yield session
    summary = session.summary()
    if as_json:
        print(json.dumps(summary, indent=2, default=float))
        return
    for kind, path in session.outputs.items():
        session.reporter.message(f"wrote {kind}: {path}")
    for name, value in session.figures.items():
        session.reporter.detail(f"  {name}: {value}")
    session.reporter.detail(f"  total: {summary['timings']['total']:.2f} s")


def _prior_line(prior) -> str:
    """One line on an extracted prior: per part, how far it turns and how far its centre travels."""
    figures = _prior_figures(prior)
    parts = []
    for k in range(prior.num_parts):
        if np.allclose(prior.poses[k], np.eye(4)):
            parts.append(f"part {k} static")
        else:
            parts.append(f"part {k} turns up to {figures['max_rotation_deg'][k]:.1f}° and travels "
                         f"{figures['centre_path_in_radii'][k]:.2f} radii")
    plural = "s" if prior.num_parts > 1 else ""
    return f"motion: {prior.num_parts} part{plural} over {prior.num_frames} frames; " + "; ".join(parts)


def _prior_figures(prior) -> dict[str, Any]:
    """What a user wants to know about an extracted prior, JSON-ready."""
    turned = rotation_angle_deg(prior.poses[:, :, :3, :3])  # (K, T)
    path = np.linalg.norm(np.diff(prior.centroids, axis=1), axis=2).sum(axis=1) / prior.radii
    return {"frames": prior.num_frames, "fps": round(float(prior.fps), 3), "parts": prior.num_parts,
            "rotation_deg_at_end": [round(float(a), 2) for a in turned[:, -1]],
            "max_rotation_deg": [round(float(a), 2) for a in turned.max(axis=1)],
            "centre_path_in_radii": [round(float(d), 3) for d in path],
            "camera_motion": prior.metadata.get("camera_motion"),
            "focal_px": round(float(prior.intrinsics[0, 0]), 2),
            "tracks": prior.metadata.get("num_tracks"),
            "recovered_frames": len(prior.metadata.get("recovered_frames") or {}),
            "failed_frames": len(prior.metadata.get("failed_frames") or {})}


def _output_file(path: Optional[Path], suffix: str, option: str) -> None:
    """Check an output file (None: not asked for): the right suffix and a writable place."""
    if path is None:
        return
    if path.suffix.lower() != suffix:
        raise InputError(f"{option} must name a {suffix} file, got {path.name!r}")
    check_output_path(path)


def _video_output(path: Path) -> Path:
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"unsupported video output {path.name!r}: use .mp4, .gif or a folder name")
    return check_output_path(path)


def _check_loop(loop: str) -> None:
    if loop not in LOOPS:
        raise InputError(f"--loop must be one of {', '.join(LOOPS)}, got {loop!r}")


def _transfer_checks(frames: Optional[int], speed: float, fps: Optional[float]) -> None:
    if frames is not None and not 2 <= frames <= 100_000:
        raise InputError(f"--frames must be between 2 and 100000, got {frames}")
    if not (np.isfinite(speed) and speed > 0):
        raise InputError(f"--speed must be positive, got {speed}")
    if fps is not None and not (np.isfinite(fps) and 0 < fps <= 240):
        raise InputError(f"--fps must be in (0, 240], got {fps}")


@app.command(cls=_Command)
def demo(output: OutputDir = Path("marionette-demo"),
         quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Run the whole method on a synthetic source and target; writes DIR/*.mp4."""
    from .demo import run_demo

    check_output_dir(output)
    with _session("demo", quiet, verbose, json_summary) as session:
        written = run_demo(session.staged.folder(output), reporter=session.reporter)
        for kind, path in written.items():
            session.output(kind, output / path.name)
        session.figures["source"] = _prior_figures(read_prior(written["prior"]))


Masks = Annotated[Optional[Path], typer.Option(
    help="Folder of per-frame object masks (default: found automatically).", rich_help_panel=SELECTION)]
Depth = Annotated[Optional[Path], typer.Option(
    help="Folder of per-frame depth maps (16-bit PNG in mm, or .npy).", rich_help_panel=SOURCE)]
Focal = Annotated[Optional[str], typer.Option(
    help="Focal length in pixels, or 'auto' (default: a 60° wide view).", rich_help_panel=SOURCE)]
EvalFocal = Annotated[str, typer.Option(
    help="Focal length in pixels, or 'auto' to estimate it from the motion.", rich_help_panel=SOURCE)]
Parts = Annotated[str, typer.Option(help="Rigid parts in all, a static one included, or 'auto'.",
                                     rich_help_panel=MOTION)]
Start = Annotated[int, typer.Option(help="First source frame to use.", rich_help_panel=SOURCE)]
End = Annotated[Optional[int], typer.Option(help="Source frame to stop before (default: the end).",
                                            rich_help_panel=SOURCE)]
Stride = Annotated[int, typer.Option(help="Use every N-th source frame.", rich_help_panel=SOURCE)]
MaxSide = Annotated[int, typer.Option(help="Downscale source frames to this long side.",
                                      rich_help_panel=PERFORMANCE)]
MaxPixels = Annotated[int, typer.Option(help="Downscale further when all frames hold more pixels than this.",
                                        rich_help_panel=PERFORMANCE)]
Smooth = Annotated[float, typer.Option(help="Temporal smoothing of the poses (0: off).", rich_help_panel=MOTION)]
Plot = Annotated[Optional[Path], typer.Option(help="Also draw each part's rotation and translation to this PNG.",
                                              rich_help_panel=OUTPUT)]
RecoverFrames = Annotated[bool, typer.Option(
    metavar="", help="Pose a frame the tracks lose by aligning the object's model.", rich_help_panel=MOTION)]
Joints = Annotated[bool, typer.Option(
    metavar="", help="Fit a part turning about a fixed axis as a hinge (lid, door).", rich_help_panel=MOTION)]
JointFit = Annotated[bool, typer.Option(
    "--joint-fit/--no-joint-fit", metavar="",
    help="Fit poses and object together to masks, pixels and tracks.",
    rich_help_panel=MOTION)]
StrictTracks = Annotated[Optional[bool], typer.Option(
    "--strict-tracks/--anchored-tracks", show_default="auto", metavar="",
    help="End a track where it stops matching, or align it again.", rich_help_panel=MOTION)]
SourcePoint = Annotated[Optional[list[str]], typer.Option(
    metavar="X,Y", help="A point on the object in the first source frame (repeatable).", rich_help_panel=SELECTION)]
SourceBox = Annotated[Optional[str], typer.Option(
    metavar="X0,Y0,X1,Y1", help="A box around the object in the first source frame.", rich_help_panel=SELECTION)]
SourceExclude = Annotated[Optional[list[str]], typer.Option(
    metavar="X,Y", help="A point off the object in the first source frame (repeatable).",
    rich_help_panel=SELECTION)]
SaveMasks = Annotated[Optional[Path], typer.Option(
    help="Also write the source masks used to this folder (as --masks reads).", rich_help_panel=OUTPUT)]


def _prompt(prefix: str, points: Optional[list[str]], box: Optional[str],
            exclude: Optional[list[str]]) -> Prompt | None:
    """The ``--{prefix}-point/-box/-exclude`` options as a Prompt; None when none is given."""
    from .segment import Prompt

    if not points and box is None and not exclude:
        return None
    prompt = Prompt(tuple(checked(f"--{prefix}-point", parse_point, p) for p in points or ()),
                    checked(f"--{prefix}-box", parse_box, box),
                    tuple(checked(f"--{prefix}-exclude", parse_point, p) for p in exclude or ()))
    if not prompt:
        raise InputError(f"--{prefix}-exclude needs a --{prefix}-point or --{prefix}-box on the object too")
    return prompt


def _check_max_side(max_side: int) -> None:
    if not 16 <= max_side <= MAX_IMAGE_SIDE:
        raise InputError(f"--max-side must be within 16..{MAX_IMAGE_SIDE}, got {max_side}")


def _extract(source: Path, masks, depth, focal, parts: str, start: int, end, stride: int, max_side: int,
             max_pixels: int, smooth: float, plot, prompt: Prompt | None, save_masks: Path | None, session: _Session,
             recover_frames: bool = True, joints: bool = True, strict_tracks: bool | None = None,
             joint_fit: bool = True):
    """Shared by ``extract`` and ``run``: check the options, extract, draw the plot."""
    from . import pipeline
    from .plot import plot_prior
    from .source import ExtractOptions
    from .source.extract import HINGE_NOTE, SLIDER_NOTE
    from .source.rigid import RETRIED_NOTE

    parts_value = checked("--parts", parse_parts, parts)
    focal = checked("--focal", parse_focal, focal)
    _check_max_side(max_side)
    if max_pixels < 16 * 16 * 2:
        raise InputError(f"--max-pixels must be at least {16 * 16 * 2}, got {max_pixels}")
    if not (np.isfinite(smooth) and 0 <= smooth <= 100):
        raise InputError(f"--smooth must be within 0..100, got {smooth}")
    _output_file(plot, ".png", "--plot")
    options = ExtractOptions(parts=parts_value, smoothing=smooth, recover_frames=recover_frames, joints=joints,
                             strict_tracks="auto" if strict_tracks is None else strict_tracks, joint_fit=joint_fit)
    prior = pipeline.extract(source, masks=masks, depth=depth, focal=focal, max_side=max_side,
                             max_pixels=max_pixels, start=start, end=end, stride=stride, options=options,
                             prompt=prompt, reporter=session.reporter,
                             masks_out=None if save_masks is None else session.staged.folder(save_masks,
                                                                                            MASK_FRAME_NAME))
    if save_masks is not None:
        session.output("masks", save_masks)
    session.figures["source"] = _prior_figures(prior)
    session.reporter.message(_prior_line(prior))
    if prior.metadata.get("focal"):
        session.reporter.message(f"focal length: {prior.metadata['focal']['note']}")
    tracks = prior.metadata.get("tracks") or {}
    if tracks.get("anchor_match") is not None:
        kind = "strict" if tracks["strict"] else "anchored (strict ones tried first)"
        session.reporter.detail(f"tracks: {kind}; {tracks['anchor_match']:.0%} of the windows aligned matched "
                                "their anchor closely")
    recovered = prior.metadata.get("recovered_frames") or {}
    if recovered:
        hinged = sum(note.startswith((HINGE_NOTE, SLIDER_NOTE)) for note in recovered.values())
        retried = sum(note.startswith(RETRIED_NOTE) for note in recovered.values())
        seconds = prior.metadata.get("timings", {}).get("recover", 0.0)
        ways = [f"by alignment ({seconds:.2f} s)"] if hinged + retried < len(recovered) else []
        if hinged:
            ways.append("on a joint")
        if retried:
            ways.append("by PnP after the refinement")
        how = " or ".join(ways)
        session.reporter.detail(f"  {len(recovered)} part-frames the tracks lost were recovered {how}: "
                                f"{', '.join(recovered)}")
    for part, fit in (prior.metadata.get("part_fits") or {}).items():
        if fit != "free":
            session.reporter.detail(f"  part {part}: {fit}")
    for part, joint in (prior.metadata.get("joints") or {}).items():
        session.reporter.detail(f"  part {part}: {_joint_line(joint)}")
    if plot is not None:
        plot_prior(prior, session.stage(plot), title=Path(source).name)
        session.output("plot", plot)
    return prior


def _joint_line(joint: dict) -> str:
    """How a part moves on its joint, from its note in the prior's ``metadata["joints"]``."""
    if joint["model"] == "free":
        return f"free: {joint['reason']}" + (f"; in its pixels: {joint['pixels']}" if "pixels" in joint else "")
    span = (f"turning {joint['range_deg'][0]:.1f}° to {joint['range_deg'][1]:.1f}°" if joint["model"] == "hinge"
            else f"travelling {joint['range'][0]:.3f} to {joint['range'][1]:.3f} in the poses' units")
    axis = ", ".join(f"{v:.2f}" for v in joint["axis"])
    why = (f"fitted to its pixels and the masks, {joint['cost_ratio']:.2f} of its free poses' cost"
           if "fitted_to" in joint else
           f"{joint['residual_px']:.2f} px against {joint['free_residual_px']:.2f} px free")
    return f"a {joint['model']} on part {joint['on_part']} along ({axis}), {span} ({why})"


@app.command(cls=_Command)
def extract(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
            output: Output, masks: Masks = None, depth: Depth = None, focal: Focal = None, parts: Parts = "1",
            start: Start = 0, end: End = None, stride: Stride = 1, max_side: MaxSide = DEFAULT_MAX_SIDE,
            max_pixels: MaxPixels = DEFAULT_MAX_PIXELS, smooth: Smooth = 1.0, plot: Plot = None,
            source_point: SourcePoint = None, source_box: SourceBox = None, source_exclude: SourceExclude = None,
            save_masks: SaveMasks = None, recover_frames: RecoverFrames = True, joints: Joints = True,
            strict_tracks: StrictTracks = None, joint_fit: JointFit = True,
            quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Extract the SpaT prior (per-part rigid motion) from a source video."""
    _output_file(output, ".npz", "--output")
    prompt = _prompt("source", source_point, source_box, source_exclude)
    with _session("extract", quiet, verbose, json_summary) as session:
        prior = _extract(source, masks, depth, focal, parts, start, end, stride, max_side, max_pixels, smooth, plot,
                         prompt, save_masks, session, recover_frames, joints, strict_tracks, joint_fit)
        write_prior(session.stage(output), prior)
        session.output("prior", output)


Frames = Annotated[Optional[int], typer.Option(help="Number of output frames (default: the source's length).",
                                               rich_help_panel=PLAYBACK)]
Speed = Annotated[float, typer.Option(help="Playback speed relative to the source.", rich_help_panel=PLAYBACK)]
Loop = Annotated[str, typer.Option(help="Past the source's end: hold, repeat or pingpong.", rich_help_panel=PLAYBACK)]
Reverse = Annotated[bool, typer.Option("--reverse", metavar="", help="Play the source's motion backwards.",
                                       rich_help_panel=PLAYBACK)]
RotationScale = Annotated[float, typer.Option(help="Multiply every rotation angle.", rich_help_panel=PLAYBACK)]
TranslationScale = Annotated[float, typer.Option(help="Multiply every displacement of the parts' centres.",
                                                 rich_help_panel=PLAYBACK)]
Fps = Annotated[Optional[float], typer.Option(help="Output frame rate (default: the source's).",
                                              rich_help_panel=OUTPUT)]
Background = Annotated[str, typer.Option(help="Background colour R,G,B (0-1 or 0-255).", rich_help_panel=OUTPUT)]
SceneBackground = Annotated[str, typer.Option(
    "--background", help="Background R,G,B (0-1 or 0-255), or 'scene': the photo's own.", rich_help_panel=OUTPUT)]
Size = Annotated[Optional[str], typer.Option(
    metavar="WxH", help="Output size (default: the photo's; 512x512 for 3D).", rich_help_panel=OUTPUT)]
CameraMove = Annotated[str, typer.Option("--camera", help="Camera move: static, orbit or dolly.",
                                         rich_help_panel=CAMERA)]
CameraAmount = Annotated[Optional[float], typer.Option(
    help="Orbit degrees (30; within ±360) or dolly share (0.3; 0 to 0.9).", rich_help_panel=CAMERA)]
CameraPath = Annotated[Optional[Path], typer.Option(help="JSON list of CAMERA.json objects, one per frame (or one).",
                                                    rich_help_panel=CAMERA)]
PartSeed = Annotated[Optional[list[str]], typer.Option(
    metavar="K:X,Y", help="Seed part K at target pixel X,Y (repeatable; default: matched).",
    rich_help_panel=SELECTION)]
Refine = Annotated[bool, typer.Option(
    "--refine/--no-refine", metavar="", help="Refine a multi-part motion: parts turn about their joints.",
    rich_help_panel=MOTION)]
Anchor = Annotated[str, typer.Option(
    help="Turn parts about their own centre ('centroid') or the 'world' origin.", rich_help_panel=PLAYBACK)]
Motion = Annotated[str, typer.Option(
    help="Move as the source camera saw it ('filmed') or as in the 'world'.", rich_help_panel=PLAYBACK)]
TargetDepth = Annotated[Optional[Path], typer.Option(
    help="Depth map of the photo (16-bit PNG in mm, or .npy) to shape it.", rich_help_panel=TARGET)]
TargetShape = Annotated[str, typer.Option(
    "--shape", help="Shape: auto, cuboid (box), revolve (pot), mirror (car), extrude, inflate",
    rich_help_panel=TARGET)]
Polish = Annotated[int, typer.Option(
    help="Steps fitting the lifted photo's colours to it (sharper; 0: off).", rich_help_panel=TARGET)]
Relight = Annotated[bool, typer.Option(
    "--relight/--no-relight", metavar="",
    help="Relight a rebuilt box or pot: a side turned to the light brightens.",
    rich_help_panel=TARGET)]
TargetMask = Annotated[Optional[Path], typer.Option(
    help="Image marking the target object (default: alpha, else found).", rich_help_panel=SELECTION)]
TargetPoint = Annotated[Optional[list[str]], typer.Option(
    metavar="X,Y", help="A point on the object in the target image (repeatable).", rich_help_panel=SELECTION)]
TargetBox = Annotated[Optional[str], typer.Option(
    metavar="X0,Y0,X1,Y1", help="A box around the object in the target image.", rich_help_panel=SELECTION)]
TargetExclude = Annotated[Optional[list[str]], typer.Option(
    metavar="X,Y", help="A point off the object in the target image (repeatable).", rich_help_panel=SELECTION)]
PlyDir = Annotated[Optional[Path], typer.Option(help="Also write each frame's Gaussians to this folder, a .ply each.",
                                                rich_help_panel=OUTPUT)]
Splats = Annotated[Optional[Path], typer.Option(
    help="Also write the animated Gaussians (.npz) for `marionette view`.", rich_help_panel=OUTPUT)]
Gltf = Annotated[Optional[Path], typer.Option(
    help="Also write the moving parts as glTF (.glb), a node per part.", rich_help_panel=OUTPUT)]
Preview = Annotated[Optional[Path], typer.Option(help="Also write a small looping GIF preview.",
                                                 rich_help_panel=OUTPUT)]
Report = Annotated[Optional[Path], typer.Option(
    help="Also write a JSON report: motion fidelity, rigidity, jerk.", rich_help_panel=OUTPUT)]
SideBySide = Annotated[Optional[Path], typer.Option(help="Also write the source beside the result (.mp4 or .gif).",
                                                    rich_help_panel=OUTPUT)]


TargetPath = Annotated[Path, typer.Argument(
    help="Target image (RGB/RGBA), 3DGS .ply or mesh (.glb, .gltf, .obj, .ply).")]


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
    background: tuple[float, float, float] | str  # a colour or "scene"
    size: tuple[int, int] | None
    camera: str
    camera_amount: float | None
    camera_path: Path | None
    ply_dir: Path | None
    target_mask: Path | np.ndarray | None  # a mask file, or the (H, W) bool mask found in the photo
    target_prompt: Prompt | None
    target_depth: Path | None
    shape: str
    polish: int
    relight: bool
    anchor: str
    motion: str
    part_seeds: dict[int, tuple[float, float]] | None
    refine: bool
    preview: Path | None
    splats: Path | None
    gltf: Path | None


def _playback(output: Path, target: Path, frames, speed, loop, reverse, rotation_scale, translation_scale, fps,
              background, size,
              camera, camera_amount, camera_path, ply_dir, target_mask, target_prompt, target_depth, shape, polish,
              relight, anchor, motion, part_seed, refine, preview, splats, gltf) -> _Playback:
    """Check every playback option (before any work starts) and the output paths."""
    from . import pipeline
    from .render.camera_path import CAMERA_MOVES, check_camera_move, load_camera_path
    from .target.shapes import SHAPES

    _transfer_checks(frames, speed, fps)
    _check_loop(loop)
    for name, value in (("--rotation-scale", rotation_scale), ("--translation-scale", translation_scale)):
        if not (np.isfinite(value) and abs(value) <= 100):
            raise InputError(f"{name} must be a number within -100..100, got {value}")
    if camera not in CAMERA_MOVES:
        raise InputError(f"--camera must be one of {', '.join(CAMERA_MOVES)}, got {camera!r}")
    check_camera_move(camera, camera_amount)
    if camera_path is not None and camera != "static":
        raise InputError("--camera-path and --camera orbit/dolly exclude each other")
    if camera_path is not None:
        load_camera_path(camera_path, None)  # the frame count is checked once it is known
    _video_output(output)
    _output_file(preview, ".gif", "--preview")
    _output_file(splats, ".npz", "--splats")
    _output_file(gltf, ".glb", "--gltf")
    if ply_dir is not None:
        check_output_folder(ply_dir, PLY_FRAME_NAME)
    if anchor not in ("centroid", "world"):
        raise InputError(f"--anchor must be 'centroid' or 'world', got {anchor!r}")
    if motion not in MOTION_FRAMES:
        raise InputError(f"--motion must be one of {', '.join(MOTION_FRAMES)}, got {motion!r}")
    if shape != "auto" and shape not in SHAPES:
        raise InputError(f"--shape must be auto or one of {', '.join(SHAPES)}, got {shape!r}")
    if not 0 <= polish <= 10_000:
        raise InputError(f"--polish must be a number of steps within 0..10000, got {polish}")
    if target_mask is not None and not target_mask.is_file():
        raise InputError(f"target mask {target_mask} does not exist")
    background = checked("--background", parse_scene_background, background)
    if background == "scene" and pipeline.is_3d_target(target):
        raise InputError(f"--background scene needs an image target: {target.name} has no scene around it")
    found = pipeline.check_target(target, target_mask, target_depth, target_prompt)  # the last check: the slowest
    return _Playback(frames, speed, loop, reverse, rotation_scale, translation_scale, fps,
                     background, checked("--size", parse_size, size),
                     camera, camera_amount, camera_path, ply_dir, target_mask if found is None else found,
                     target_prompt, target_depth, shape, polish, relight, anchor, motion,
                     checked("--part-seed", parse_part_seeds, part_seed or None), refine, preview, splats, gltf)


def _transfer_and_render(prior, target: Path, output: Path, play: _Playback, session: _Session):
    """Lift, transfer, render and stage the outputs the options ask for; the trajectory and the staged video."""
    from . import pipeline
    from .render.camera_path import load_camera_path
    from .target.lift import LiftOptions
    from .transfer.refine import RefineOptions

    if play.part_seeds:
        pipeline.check_part_seeds(prior, play.part_seeds)
    path_cameras = (None if play.camera_path is None
                    else load_camera_path(play.camera_path, output_length(prior.num_frames, play.speed, play.frames)))
    with session.reporter.stage("lifting target", 1) as progress:
        lifted = pipeline.load_target(target, size=play.size, mask=play.target_mask, depth=play.target_depth,
                                      options=LiftOptions(shape=play.shape, polish=play.polish, relight=play.relight),
                                      prior=prior,
                                      prompt=play.target_prompt)
        progress(1, 1)
    if lifted.shape is not None:
        session.reporter.detail(lifted.shape.describe())
    with session.reporter.stage("transfer", 1) as progress:
        trajectory = pipeline.transfer(prior, lifted, frames=play.frames, speed=play.speed, loop=play.loop,
                                       reverse=play.reverse, rotation_scale=play.rotation_scale,
                                       translation_scale=play.translation_scale, anchor=play.anchor,
                                       motion=play.motion,
                                       part_seeds=play.part_seeds, refine=RefineOptions() if play.refine else None)
        progress(1, 1)
    scene = play.background == "scene"
    if play.motion == "world" and CAMERA_EXTRA in prior.extras and not scene:
        away = pipeline.frames_outside(lifted.gaussians, trajectory, [lifted.camera] * trajectory.num_frames)
        if away:
            warnings.warn(f"moved as in the world, the object leaves the photo's view in {away} of "
                          f"{trajectory.num_frames} frames and the view zooms out to follow it; --motion filmed "
                          "moves it as the source camera saw it", stacklevel=1)
    cameras = path_cameras or pipeline.output_cameras(lifted, trajectory, play.camera, play.camera_amount,
                                                      framed=not scene)
    background = play.background
    if scene:
        with session.reporter.stage("clean plate", 1) as progress:
            background = pipeline.scene_compositor(lifted)
            progress(1, 1)
        outside = pipeline.frames_outside(lifted.gaussians, trajectory, cameras)
        if outside:
            warnings.warn(f"the object's centre leaves the photo in {outside} of {trajectory.num_frames} frames; "
                          "--translation-scale 0 keeps it in place", stacklevel=1)
    video = session.stage(output)
    pipeline.render_video(video, lifted, trajectory, cameras, fps=play.fps or prior.fps,
                          background=background, reporter=session.reporter)
    session.output("video", output)
    session.figures["target"] = {"gaussians": len(lifted.gaussians), "frames": trajectory.num_frames,
                                 "size": [cameras[0].width, cameras[0].height], "fps": play.fps or prior.fps,
                                 "shape": None if lifted.shape is None else lifted.shape.as_dict(),
                                 "motion": play.motion if CAMERA_EXTRA in prior.extras else "still camera"}
    if CAMERA_EXTRA in prior.extras:
        session.reporter.detail(f"motion {play.motion}: the source camera's own motion "
                                + ("put back, as it filmed the object" if play.motion == "filmed" else "left out"))
    if play.preview is not None:
        pipeline.write_preview(session.stage(play.preview), video, fps=play.fps or prior.fps)
        session.output("preview", play.preview)
    if play.ply_dir is not None:
        pipeline.write_ply_frames(session.staged.folder(play.ply_dir, PLY_FRAME_NAME), lifted.gaussians,
                                  trajectory)
        session.output("ply_dir", play.ply_dir)
    if play.splats is not None:
        write_splat_animation(session.stage(play.splats), lifted.gaussians, trajectory, play.fps or prior.fps)
        session.output("splats", play.splats)
    if play.gltf is not None:
        write_gltf_animation(session.stage(play.gltf), lifted.gaussians, trajectory, play.fps or prior.fps)
        session.output("gltf", play.gltf)
    return trajectory, video


@app.command(cls=_Command)
def transfer(prior: Annotated[Path, typer.Argument(help="SpaT prior .npz.")],
             target: TargetPath,
             output: Output, frames: Frames = None, speed: Speed = 1.0, loop: Loop = "hold", reverse: Reverse = False,
             rotation_scale: RotationScale = 1.0, translation_scale: TranslationScale = 1.0, fps: Fps = None,
             background: SceneBackground = "1,1,1", size: Size = None, camera: CameraMove = "static",
             camera_amount: CameraAmount = None, camera_path: CameraPath = None, ply_dir: PlyDir = None,
             target_mask: TargetMask = None, target_point: TargetPoint = None, target_box: TargetBox = None,
             target_exclude: TargetExclude = None, target_depth: TargetDepth = None, shape: TargetShape = "auto",
             polish: Polish = 0, relight: Relight = True, anchor: Anchor = "centroid", motion: Motion = "filmed",
             part_seed: PartSeed = None, refine: Refine = True,
             preview: Preview = None, splats: Splats = None, gltf: Gltf = None, quiet: Quiet = False,
             verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Apply a SpaT prior to a target image, .ply or mesh and render the video."""
    play = _playback(output, target, frames, speed, loop, reverse, rotation_scale, translation_scale, fps,
                     background, size, camera, camera_amount, camera_path, ply_dir, target_mask,
                     _prompt("target", target_point, target_box, target_exclude), target_depth, shape,
                     polish, relight, anchor, motion, part_seed, refine, preview, splats, gltf)
    with _session("transfer", quiet, verbose, json_summary) as session:
        _transfer_and_render(read_prior(prior), target, output, play, session)


@app.command(cls=_Command)
def run(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
        target: TargetPath,
        output: Output, masks: Masks = None, depth: Depth = None, focal: Focal = None, parts: Parts = "1",
        start: Start = 0, end: End = None, stride: Stride = 1, max_side: MaxSide = DEFAULT_MAX_SIDE,
        max_pixels: MaxPixels = DEFAULT_MAX_PIXELS, smooth: Smooth = 1.0, plot: Plot = None,
        source_point: SourcePoint = None, source_box: SourceBox = None, source_exclude: SourceExclude = None,
        save_masks: SaveMasks = None, recover_frames: RecoverFrames = True, joints: Joints = True,
        strict_tracks: StrictTracks = None, joint_fit: JointFit = True, frames: Frames = None,
        speed: Speed = 1.0, loop: Loop = "hold",
        reverse: Reverse = False,
        rotation_scale: RotationScale = 1.0, translation_scale: TranslationScale = 1.0, fps: Fps = None,
        background: SceneBackground = "1,1,1", size: Size = None, camera: CameraMove = "static",
        camera_amount: CameraAmount = None, camera_path: CameraPath = None, ply_dir: PlyDir = None,
        target_mask: TargetMask = None, target_point: TargetPoint = None, target_box: TargetBox = None,
        target_exclude: TargetExclude = None, target_depth: TargetDepth = None, shape: TargetShape = "auto",
        polish: Polish = 0, relight: Relight = True, anchor: Anchor = "centroid", motion: Motion = "filmed",
        part_seed: PartSeed = None, refine: Refine = True,
        preview: Preview = None, splats: Splats = None, gltf: Gltf = None, side_by_side: SideBySide = None,
        report: Report = None,
        quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Extract the source's motion and transfer it onto the target in one go."""
    from . import pipeline

    play = _playback(output, target, frames, speed, loop, reverse, rotation_scale, translation_scale, fps,
                     background, size, camera, camera_amount, camera_path, ply_dir, target_mask,
                     _prompt("target", target_point, target_box, target_exclude), target_depth, shape,
                     polish, relight, anchor, motion, part_seed, refine, preview, splats, gltf)
    prompt = _prompt("source", source_point, source_box, source_exclude)
    if side_by_side is not None:
        _video_output(side_by_side)
    _output_file(report, ".json", "--report")
    with _session("run", quiet, verbose, json_summary) as session:
        prior = _extract(source, masks, depth, focal, parts, start, end, stride, max_side, max_pixels, smooth, plot,
                         prompt, save_masks, session, recover_frames, joints, strict_tracks, joint_fit)
        trajectory, video = _transfer_and_render(prior, target, output, play, session)
        if side_by_side is not None:
            times = source_times(trajectory.num_frames, prior.num_frames - 1, speed=speed, loop=loop, reverse=reverse)
            pipeline.write_side_by_side(session.stage(side_by_side), source, video, times, fps=play.fps or prior.fps,
                                        max_side=max_side, start=start, end=end, stride=stride)
            session.output("side_by_side", side_by_side)
        if report is not None:
            from .eval import run_report

            with session.reporter.stage("report", 1) as progress:
                figures = run_report(source, video, trajectory, speed=speed, loop=loop, reverse=reverse, masks=masks,
                                     max_side=max_side, start=start, end=end, stride=stride)
                progress(1, 1)
            session.stage(report).write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
            session.figures["report"] = figures
            session.output("report", report)


@app.command(cls=_Command)
def reconstruct(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
                output: Annotated[Path, typer.Option("--output", "-o", help="Output 3DGS .ply file.",
                                                     rich_help_panel=OUTPUT)],
                masks: Masks = None,
                prior: Annotated[Optional[Path], typer.Option(
                    help="SpaT prior .npz of the same frames (default: extracted first).",
                    rich_help_panel=SOURCE)] = None,
                focal: Focal = None, parts: Parts = "1", start: Start = 0, end: End = None,
                stride: Annotated[int, typer.Option(
                    help="Fit every N-th frame (the others can test the result).", rich_help_panel=SOURCE)] = 1,
                iterations: Annotated[int, typer.Option(
                    help="Optimisation steps, one frame each.", rich_help_panel=PERFORMANCE)] = 900,
                max_side: Annotated[int, typer.Option(
                    help="Long side of the frames the fit works on.", rich_help_panel=PERFORMANCE)] = 960,
                source_point: SourcePoint = None, source_box: SourceBox = None,
                source_exclude: SourceExclude = None, joint_fit: JointFit = True,
                quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False,
                config: Config = None) -> None:
    """Reconstruct the source object as 3D Gaussians at frame 0, with each Gaussian's part."""
    from . import pipeline
    from .reconstruct import ReconstructOptions
    from .source import ExtractOptions

    _output_file(output, ".ply", "--output")
    if not 1 <= iterations <= 1_000_000:
        raise InputError(f"--iterations must be within 1..1000000, got {iterations}")
    if stride < 1:
        raise InputError(f"--stride must be at least 1, got {stride}")
    _check_max_side(max_side)
    if masks is not None and not masks.is_dir():
        raise InputError(f"mask folder {masks} does not exist")
    options = ReconstructOptions(iterations=iterations, max_side=max_side)
    extract_options = ExtractOptions(parts=checked("--parts", parse_parts, parts), joint_fit=joint_fit)
    focal = checked("--focal", parse_focal, focal)
    prompt = _prompt("source", source_point, source_box, source_exclude)
    with _session("reconstruct", quiet, verbose, json_summary) as session:
        given = None if prior is None else read_prior(prior)
        result, used = pipeline.reconstruct(source, masks=masks, prior=given, focal=focal, start=start, end=end,
                                            stride=stride, extract_options=extract_options, options=options,
                                            prompt=prompt, reporter=session.reporter)
        write_ply(session.stage(output), result.gaussians, extra={"part": result.parts})
        session.output("object", output)
        losses = result.losses
        session.figures.update(gaussians=len(result.gaussians), parts=used.num_parts,
                               frames_fitted=len(result.frames_used), frames=used.num_frames,
                               loss_initial=round(losses["initial"], 5), loss_final=round(losses["final"], 5))
        session.reporter.detail(f"  loss at start: {losses['initial']:.5f} ({losses['gaussians_initial']} Gaussians)")
        block, coarse = options.densify_every, options.coarse_steps
        for i, value in enumerate(losses["fit"]):
            last = min((i + 1) * block, iterations)
            where = " (half resolution)" if last <= coarse else ""
            session.reporter.detail(f"  loss over iterations {i * block + 1}-{last}{where}: {value:.5f}")
        session.reporter.detail(f"  loss at end: {losses['final']:.5f} ({losses['gaussians_final']} Gaussians)")
        fit = result.quality.summary()
        session.figures["fit"] = fit
        session.reporter.detail(f"  fit over {len(result.quality.frames)} of its frames: silhouette IoU "
                                f"{fit['silhouette_iou']:.3f} median ({fit['silhouette_iou_worst']:.3f} at frame "
                                f"{fit['worst_frame']}), object pixels {fit['masked_psnr_db']:.1f} dB median")
        if result.shading is not None:
            light = result.shading.lighting
            session.figures.update(light_direction=[round(float(v), 4) for v in light.direction],
                                   light_diffuse=round(light.diffuse, 4))
            session.reporter.detail(f"  light: towards ({', '.join(f'{v:.2f}' for v in light.direction)}) in the "
                                    f"frame-0 camera's axes, diffuse share {light.diffuse:.2f}")


@app.command("eval-self", cls=_Command)
def eval_self_cmd(source: Annotated[Path, typer.Argument(help="Video file or folder of frames.")],
                  output: OutputDir, masks: Masks = None, parts: Parts = "1", max_side: MaxSide = DEFAULT_MAX_SIDE,
                  focal: EvalFocal = "auto",
                  target: Annotated[str, typer.Option(
                      help="What moves: 'reconstruction' (fitted to the video) or 'frame0'.",
                      rich_help_panel=TARGET)] = "reconstruction",
                  iterations: Annotated[Optional[int], typer.Option(
                      help="Optimisation steps of the reconstruction (default 900).",
                      rich_help_panel=PERFORMANCE)] = None,
                  source_point: SourcePoint = None, source_box: SourceBox = None,
                  source_exclude: SourceExclude = None, save_masks: SaveMasks = None, joint_fit: JointFit = True,
                  quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False,
                  config: Config = None) -> None:
    """Self-transfer (the paper's Table 1): the source object as the target, scored against the masked source."""
    from .eval import EVAL_EXTRACT, EVAL_SELF_OUTPUTS, eval_self
    from .eval.self_eval import EVAL_TARGETS
    from .reconstruct import ReconstructOptions

    if target not in EVAL_TARGETS:
        raise InputError(f"--target must be one of {', '.join(EVAL_TARGETS)}, got {target!r}")
    if iterations is not None and target != "reconstruction":
        raise InputError("--iterations sets the reconstruction's fit; it needs --target reconstruction")
    if iterations is not None and not 1 <= iterations <= 1_000_000:
        raise InputError(f"--iterations must be within 1..1000000, got {iterations}")
    reconstruct_options = ReconstructOptions() if iterations is None else ReconstructOptions(iterations=iterations)

    _check_max_side(max_side)
    options = replace(EVAL_EXTRACT, parts=checked("--parts", parse_parts, parts), joint_fit=joint_fit)
    focal_value = checked("--focal", parse_focal, focal)
    if masks is not None and not masks.is_dir():
        raise InputError(f"mask folder {masks} does not exist")
    prompt = _prompt("source", source_point, source_box, source_exclude)
    check_output_dir(output)
    with _session("eval-self", quiet, verbose, json_summary) as session:
        masks_out = None if save_masks is None else session.staged.folder(save_masks, MASK_FRAME_NAME)
        metrics = eval_self(source, masks, session.staged.folder(output), max_side=max_side, focal=focal_value,
                            options=options, target=target, prompt=prompt, masks_out=masks_out,
                            reporter=session.reporter, reconstruct_options=reconstruct_options)
        for kind, name in EVAL_SELF_OUTPUTS.items():
            session.output(kind, output / name)
        if save_masks is not None:
            session.output("masks", save_masks)
        session.figures.update({k: metrics[k] for k in ("psnr", "ssim", "lpips", "motion_fidelity", "focal_px")})
        if not json_summary:
            fidelity = "n/a" if metrics["motion_fidelity"] is None else f"{metrics['motion_fidelity']:.3f}"
            lpips = "skipped (no weights on this machine)" if metrics["lpips"] is None else f"{metrics['lpips']:.3f}"
            session.reporter.message(f"PSNR {metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.3f}, "
                                     f"LPIPS {lpips}, motion fidelity {fidelity}")


@app.command("eval", cls=_Command)
def eval_cmd(source: Annotated[Path, typer.Argument(help="Source video file or folder of frames.")],
             result: Annotated[Path, typer.Argument(help="Transferred video, e.g. from `marionette run`.")],
             masks: Masks = None, max_side: MaxSide = DEFAULT_MAX_SIDE,
             speed: Annotated[Optional[float], typer.Option(
                 help="The --speed the result was made with (default 1).", rich_help_panel=PLAYBACK)] = None,
             loop: Annotated[Optional[str], typer.Option(
                 help="The --loop the result was made with (default hold).", rich_help_panel=PLAYBACK)] = None,
             reverse: Annotated[bool, typer.Option("--reverse", metavar="", help="The result was made with --reverse.",
                                                   rich_help_panel=PLAYBACK)] = False,
             quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False,
             config: Config = None) -> None:
    """Motion fidelity of RESULT to SOURCE: 1 the same motion, 0 unrelated, -1 opposite (at the times it shows)."""
    from .eval import result_fidelity

    _check_max_side(max_side)
    _transfer_checks(None, 1.0 if speed is None else speed, None)
    if loop is not None:
        _check_loop(loop)
    with _session("eval", quiet, verbose, json_summary) as session:
        with session.reporter.stage("motion fidelity", 1) as progress:
            fidelity = result_fidelity(source, result, speed=speed, loop=loop, reverse=reverse, masks=masks,
                                       max_side=max_side)
            progress(1, 1)
        session.figures["motion_fidelity"] = fidelity
        if not json_summary:
            print(f"motion fidelity {fidelity:.4f}")


@app.command(cls=_Command)
def batch(jobs: Annotated[Path, typer.Argument(help="Job file (TOML; the format is in marionette.batch's docstring).")],
          scheduler: Annotated[Optional[str], typer.Option(
              help="Address of a Dask scheduler (default: a local cluster).", rich_help_panel=PERFORMANCE)] = None,
          workers: Annotated[int, typer.Option(help="Worker processes of the local cluster.",
                                               rich_help_panel=PERFORMANCE)] = 2,
          output: Annotated[Optional[Path], typer.Option(
              "--output", "-o", help="Output folder (default: the job file's 'output').",
              rich_help_panel=OUTPUT)] = None,
          quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Run many source × target jobs on Dask: one prior per source, finished jobs skipped, a results table.

    Exit code 1 if some job failed (its error is in the table; the other jobs still run).
    """
    from .batch import run_batch

    with _session("batch", quiet, verbose, json_summary) as session:
        rows = run_batch(jobs, scheduler=scheduler, workers=workers, reporter=session.reporter, output=output)
        session.output("results", rows[0].output.parent / "results.md")
        session.figures["jobs"] = {s: sum(r.status == s for r in rows) for s in ("ran", "skipped", "failed")}
    if any(row.status == "failed" for row in rows):
        raise typer.Exit(1)


@app.command(cls=_Command)
def view(result: Annotated[Path, typer.Argument(
             help="Animated splats (.npz from --splats), a --ply-dir folder, or one .ply.")],
         host: Annotated[str, typer.Option(
             help="Address to listen on; 0.0.0.0 lets other machines connect.", rich_help_panel=SERVER)] = "127.0.0.1",
         port: Annotated[int, typer.Option(help="Port (0: any free port).",
                                           rich_help_panel=SERVER)] = 8080,
         fps: Annotated[Optional[float], typer.Option(help="Playback rate (default: the result's own).",
                                                      rich_help_panel=OUTPUT)] = None,
         quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """Play animated Gaussians in the browser: time slider, play/pause, free camera (until Ctrl-C)."""
    from .viewer import run as run_viewer  # viser loads only for this command

    with _session("view", quiet, verbose, json_summary) as session:
        def announce(viewer) -> None:
            """Once serving: the page's address (the JSON summary, with --json)."""
            session.figures.update(url=viewer.url, frames=viewer.num_frames)
            if json_summary:
                print(json.dumps(session.summary(), indent=2, default=float), flush=True)
            else:
                session.reporter.message(f"viewer at {viewer.url} (Ctrl-C to stop)")
                session.reporter.detail(f"  frames: {viewer.num_frames}")

        run_viewer(result, host, port, fps=fps, announce=announce, verbose=verbose)


@app.command("app", cls=_Command)
def app_cmd(host: Annotated[str, typer.Option(
                help="Address to listen on; 0.0.0.0 lets other machines connect.",
                rich_help_panel=SERVER)] = "127.0.0.1",
            port: Annotated[int, typer.Option(help="Port (0: any free port).", rich_help_panel=SERVER)] = 8765,
            workdir: Annotated[Optional[Path], typer.Option(
                help="Folder for uploads and results (default: a temporary one).",
                rich_help_panel=SERVER)] = None,
            quiet: Quiet = False, verbose: Verbose = False, json_summary: Json = False, config: Config = None) -> None:
    """A local web page: upload a clip and a photo, click the objects, get the video (until Ctrl-C)."""
    from .app import run_app

    if workdir is not None and workdir.exists() and not workdir.is_dir():
        raise InputError(f"--workdir {workdir} is a file, not a folder")
    with _session("app", quiet, verbose, json_summary) as session:
        def announce(server) -> None:
            session.figures.update(url=server.url, workdir=str(server.sessions.root))
            if json_summary:
                print(json.dumps(session.summary(), indent=2, default=float), flush=True)
            else:
                session.reporter.message(f"app at {server.url} (Ctrl-C to stop)")

        run_app(host, port, workdir, announce=announce)


@app.command("render", cls=_Command)
def render_cmd(scene: Annotated[Path, typer.Argument(help="3DGS .ply file.")],
               camera: Annotated[Path, typer.Option(help="CAMERA.json (docs/DESIGN.md contract).",
                                                    rich_help_panel=CAMERA)],
               output: Output, background: Background = "1,1,1", quiet: Quiet = False, verbose: Verbose = False,
               json_summary: Json = False, config: Config = None) -> None:
    """Render a 3DGS .ply from a camera to a PNG (a warning when nothing of it is in view)."""
    from .render import render

    bg = checked("--background", parse_background, background)
    if output.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"unsupported image output {output.name!r}: use .png or .jpg")
    check_output_path(output)
    with _session("render", quiet, verbose, json_summary) as session:
        cam = Camera.load(camera)
        gaussians = read_ply(scene)
        with session.reporter.stage("rendering", 1) as progress:
            out = render(gaussians, cam, bg)
            progress(1, 1)
        if out.alpha.max() < 0.5 / 255:  # not one pixel differs from the background
            behind = int((cam.project(gaussians.means)[1] <= 0).sum())
            session.warn(f"nothing of the scene is in view: none of its {len(gaussians)} Gaussians reaches the "
                         f"image ({behind} of them behind the camera); the image holds only the background")
        write_image(session.stage(output), (np.clip(out.image, 0, 1) * 255 + 0.5).astype(np.uint8))
        session.output("image", output)
        session.figures["gaussians"] = len(gaussians)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Library warnings as one ``warning: …`` line on stderr, without source locations."""
    print(f"warning: {str(message).splitlines()[0]}", file=sys.stderr)


def _interrupted(error: BaseException) -> bool:
    """Whether a KeyboardInterrupt is among the causes of ``error``."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


def _failed(argv: list[str] | None, message: str, code: int) -> int:
    """Say why a command failed: one ``error: …`` line on stderr and, with ``--json``, a JSON object
    ``{"command", "error", "exit_code"}`` on stdout; ``code`` back."""
    print(f"error: {message}", file=sys.stderr)
    args = sys.argv[1:] if argv is None else list(argv)
    args = args[:args.index("--")] if "--" in args else args
    if "--json" in args:
        commands = typer.main.get_command(app).commands
        command = next((arg for arg in args if arg in commands), None)
        print(json.dumps({"command": command, "error": message, "exit_code": code}), flush=True)
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning bad input into ``error: …`` and exit code 2.

    Ctrl-C and SIGTERM alike stop a command with nothing partial left, ``error: interrupted`` and exit code 130.
    """
    warnings.showwarning = _show_warning
    try:
        with sigterm_as_interrupt():
            code = app(args=argv, standalone_mode=False, prog_name="marionette")
    except typer.Exit as e:
        code = e.exit_code
    except typer.Abort:
        code = 130
    except typer.TyperException as e:  # typer >= 0.29 vendors click; usage errors land here
        message = e.format_message().splitlines()
        # none for a bare `marionette`: the help is printed instead, and click's exit code 2 kept
        return _failed(argv, message[0], 2) if message else 2
    except InputError as e:
        return _failed(argv, str(e).splitlines()[0], 2)
    except KeyboardInterrupt:
        code = 130
    except Exception as e:
        # Ctrl-C inside a compiled library surfaces wrapped (numba: SystemError), or as the broken pipe of the
        # ffmpeg it stopped too.
        if not (_interrupted(e) or interrupt_requested()):
            raise
        code = 130
    if code == 130:  # typer turns Ctrl-C into exit code 130
        return _failed(argv, "interrupted", 130)
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
