"""The figures of a finished run: how faithfully the result moves like the source, and how rigidly."""

from __future__ import annotations

import warnings
from pathlib import Path

from ..errors import InputError
from ..io import read_masks, read_video
from ..trajectory import Trajectory
from ..transfer.controls import output_length, source_times
from ..transfer.metrics import trajectory_quality
from .fidelity import motion_fidelity

__all__ = ["run_report", "result_fidelity"]


def result_fidelity(source: str | Path, result: str | Path, *, speed: float | None = None, loop: str | None = None,
                    reverse: bool = False, masks: str | Path | None = None, max_side: int | None = None,
                    start: int = 0, end: int | None = None, stride: int = 1) -> float:
    """Motion fidelity (:func:`~marionette.eval.fidelity.motion_fidelity`) of a result video to its source.

    Source frames are selected as for extraction (``start``, ``end``,
    ``stride``, ``max_side``); ``masks`` is the source's mask folder
    (default: automatic masks). Result frame ``i`` is compared with the
    source at the time the playback controls ``speed``, ``loop`` and
    ``reverse`` show there (:func:`~marionette.transfer.controls.source_times`),
    so the score does not change with them. When ``speed`` and ``loop`` are
    not given (None: taken as 1 and hold) and the result's length is not
    one play of the source, a warning says how the two are lined up.
    Raises :class:`InputError` when nothing trackable lasts long enough.
    """
    video = read_video(source, max_side=max_side, start=start, end=end, stride=stride)
    t, h, w = video.frames.shape[:3]
    rendered = read_video(result, max_side=max_side).frames
    played = output_length(t, speed or 1.0)
    if speed is None and loop is None and len(rendered) != played:
        past = ("the source's first frames" if len(rendered) < played
                else "the source, then its last frame held for the rest")
        warnings.warn(f"{Path(result).name} has {len(rendered)} frames and {Path(source).name} {t}: compared with "
                      f"{past}; give the --speed, --loop and --reverse the result was made with to line them up")
    times = source_times(len(rendered), t - 1, speed=speed or 1.0, loop=loop or "hold", reverse=reverse)
    source_masks = None if masks is None else read_masks(masks, count=t, size=(w, h), indices=video.indices)
    return motion_fidelity(video.frames, source_masks, rendered, None, source_times=times)


def run_report(source: str | Path, result: str | Path, trajectory: Trajectory, *, speed: float = 1.0,
               loop: str = "hold", reverse: bool = False, masks: str | Path | None = None,
               max_side: int | None = None, start: int = 0, end: int | None = None, stride: int = 1) -> dict:
    """Motion fidelity of ``result`` to ``source`` and the quality of the ``trajectory`` that made it.

    ``speed``, ``loop`` and ``reverse`` are the playback controls the result
    was made with, and the other options select the source's frames (see
    :func:`result_fidelity`). Returns ``motion_fidelity`` (in [-1, 1], or
    None with a reason when nothing trackable lasts long enough) and the
    trajectory's ``rigidity_error``, ``boundary_separation``,
    ``detached_seam`` and ``jerk``.
    """
    report: dict = {"motion_fidelity": None}
    try:
        report["motion_fidelity"] = result_fidelity(source, result, speed=speed, loop=loop, reverse=reverse,
                                                    masks=masks, max_side=max_side, start=start, end=end,
                                                    stride=stride)
    except InputError as e:
        report["motion_fidelity_skipped"] = str(e)
    quality = trajectory_quality(trajectory)
    report.update(rigidity_error=quality.rigidity_error, boundary_separation=quality.boundary_separation,
                  detached_seam=quality.detached_seam, jerk=quality.jerk)
    return report
