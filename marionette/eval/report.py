"""The figures of a finished run: how faithfully the result moves like the source, and how rigidly."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import read_masks, read_video
from ..trajectory import Trajectory
from ..transfer.metrics import trajectory_quality
from .fidelity import motion_fidelity

__all__ = ["run_report"]


def run_report(source: str | Path, result: str | Path, trajectory: Trajectory, source_times: np.ndarray, *,
               masks: str | Path | None = None, max_side: int | None = None, start: int = 0, end: int | None = None,
               stride: int = 1) -> dict:
    """Motion fidelity of ``result`` to ``source`` and the quality of the ``trajectory`` that made it.

    Source frames are selected as for extraction and shown at
    ``source_times`` (T_out,) (output frame t shows source frame
    ``source_times[t]``, rounded), so a retimed result is compared with the
    motion it plays. ``masks`` is the source's mask folder (default:
    automatic masks). Returns ``motion_fidelity`` (in [-1, 1], or None with a
    reason when nothing trackable lasts long enough) and the trajectory's
    ``rigidity_error``, ``boundary_separation``, ``detached_seam`` and ``jerk``.
    """
    video = read_video(source, max_side=max_side, start=start, end=end, stride=stride)
    t, h, w = video.frames.shape[:3]
    index = np.clip(np.rint(np.asarray(source_times)).astype(int), 0, t - 1)
    source_masks = None if masks is None else read_masks(masks, count=t, size=(w, h), indices=video.indices)[index]
    report: dict = {"motion_fidelity": None}
    try:
        report["motion_fidelity"] = motion_fidelity(video.frames[index], source_masks, read_video(result).frames, None)
    except InputError as e:
        report["motion_fidelity_skipped"] = str(e)
    quality = trajectory_quality(trajectory)
    report.update(rigidity_error=quality.rigidity_error, boundary_separation=quality.boundary_separation,
                  detached_seam=quality.detached_seam, jerk=quality.jerk)
    return report
