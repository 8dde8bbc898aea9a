"""Joints the photometric refinement keeps: a part hinged on another turns about an axis fixed in its body.

Extraction fits a thin part that turns about one axis of another as a hinge
(:mod:`marionette.source.hinge`; the prior's ``metadata["joints"]``). Refined
freely, such a part would drift off its axis and come loose from its body;
:func:`~marionette.reconstruct.align.align_poses` given the :class:`Hinge`
moves it with its body and fits one angle about the axis instead.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError

__all__ = ["Hinge", "hinges_from_metadata", "check_hinges", "snap_to_hinges"]


@dataclass(frozen=True)
class Hinge:
    """Part ``part`` turns about a line fixed in part ``body``: ``poses[part] = poses[body] @ turn(θ)``.

    Attributes
    ----------
    part, body : int, indices of the hinged part and of the part that carries the axis.
    axis : (3,) float, unit direction of the axis in the body's frame-0 coordinates.
    point : (3,) float, a point of the axis, in the same coordinates.
    """

    part: int
    body: int
    axis: np.ndarray
    point: np.ndarray


def hinges_from_metadata(joints: Mapping[str, Mapping] | None) -> list[Hinge]:
    """The hinges of a prior's ``metadata["joints"]`` (parts kept free are left out)."""
    return [Hinge(int(index), int(note["on_part"]), np.asarray(note["axis"], float), np.asarray(note["point"], float))
            for index, note in (joints or {}).items() if note.get("model") == "hinge"]


def check_hinges(hinges: Sequence[Hinge], num_parts: int) -> list[Hinge]:
    """The hinges with unit axes; :class:`InputError` for a part hinged twice, on itself or on a hinged part,
    an index out of range or an axis that is not a finite non-zero 3-vector."""
    checked, parts = [], {h.part for h in hinges}
    for h in hinges:
        axis, point = np.asarray(h.axis, float), np.asarray(h.point, float)
        if not (0 <= h.part < num_parts and 0 <= h.body < num_parts) or h.part == h.body:
            raise InputError(f"a hinge must join two different parts of the {num_parts}, got part {h.part} on "
                             f"part {h.body}")
        if h.body in parts:
            raise InputError(f"part {h.part} is hinged on part {h.body}, which is hinged itself: chains of hinges "
                             "are not supported")
        if axis.shape != (3,) or point.shape != (3,) or not np.all(np.isfinite(np.r_[axis, point])) \
                or not np.linalg.norm(axis) > 0:
            raise InputError(f"the hinge of part {h.part} needs a finite non-zero axis and a finite point (3 each)")
        checked.append(Hinge(h.part, h.body, axis / np.linalg.norm(axis), point))
    if len(parts) < len(checked):
        raise InputError("a part can have one hinge at most")
    return checked


def snap_to_hinges(poses: np.ndarray, hinges: Sequence[Hinge]) -> np.ndarray:
    """Poses (K, T, 4, 4) with each hinged part put back on its hinge.

    Its turn relative to the body is replaced by the turn about the hinge's
    axis closest to it (the rotation vector's component along the axis), so a
    pose that drifted off the axis (smoothed, say) starts the refinement on it.
    """
    # Imported here: marionette.source imports the alignment (to recover lost frames), which imports this module.
    from ..source.hinge import hinge_poses

    out = np.array(poses, dtype=np.float64)
    for h in hinges:
        relative = np.linalg.inv(out[h.body]) @ out[h.part]  # (T, 4, 4)
        angles = Rotation.from_matrix(relative[:, :3, :3]).as_rotvec() @ h.axis
        out[h.part] = hinge_poses(out[h.body], h.axis, h.point, angles)
    return out

