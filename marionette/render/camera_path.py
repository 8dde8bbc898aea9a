"""Camera paths for the output video: static, orbit, dolly, or a list of cameras from a file."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..camera import Camera, read_camera_json
from ..errors import InputError
from ..geometry import axis_angle_to_matrix, invert_transform, make_transform, transform_points

__all__ = ["CAMERA_AMOUNTS", "CAMERA_MOVES", "camera_path", "check_camera_move", "keep_in_view", "load_camera_path"]

#: Built-in camera moves and their default amount: orbit, degrees turned about the
#: vertical axis through the object's path over the clip; dolly, share of the
#: distance to the object covered towards it.
CAMERA_MOVES = {"static": 0.0, "orbit": 30.0, "dolly": 0.3}
#: The amounts that make sense: up to a full turn either way; up to nine tenths of the way
#: (the object ten times larger), closer than that the camera is soon inside it.
CAMERA_AMOUNTS = {"orbit": (-360.0, 360.0), "dolly": (0.0, 0.9)}


def camera_path(camera: Camera, centres: np.ndarray, move: str = "static", amount: float | None = None) -> list[Camera]:
    """One camera per row of ``centres`` (T, 3), the object's centre in each frame (world), from ``camera``.

    ``orbit`` turns the camera about the vertical axis (the camera's y axis)
    through the centre of the object's path (the mean of ``centres``) by
    ``amount`` degrees (default 30) over the clip, eased in and out: an object
    that travels is turned about with its path rather than swung out of view
    (:func:`keep_in_view` then fits the turned path). ``dolly`` moves it
    towards the object, ``amount`` (default 0.3) of the distance, following
    it: the object grows while its centre stays where ``camera`` shows it.
    """
    amount = check_camera_move(move, amount)
    if move == "static":
        return [camera] * len(centres)
    eased = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, len(centres)))  # 0 → 1, slow at both ends
    w2c = camera.world_to_camera
    seen = transform_points(w2c, np.asarray(centres, dtype=np.float64))  # (T, 3) as the camera sees them
    pivot = seen.mean(axis=0)
    path = []
    for u, centre in zip(eased, seen):
        if move == "orbit":  # turn the world about the vertical axis through the pivot, as the camera sees it
            turn = axis_angle_to_matrix([0.0, np.radians(amount) * u, 0.0])
            about = make_transform(turn, pivot - turn @ pivot)
        else:  # dolly: the object comes towards the camera along its line of sight, so stays on its pixel
            about = make_transform(np.eye(3), -amount * u * centre)
        path.append(camera.with_pose(about @ w2c))
    return path


def keep_in_view(cameras: Sequence[Camera], points: np.ndarray, margin: float = 0.06) -> list[Camera]:
    """``cameras`` (one intrinsics) zoomed out and re-centred alike, just enough that each keeps its frame's
    ``points`` (T, M, 3) (world) in view; see :meth:`~marionette.camera.Camera.framing`."""
    first = cameras[0]
    back = invert_transform(first.world_to_camera)
    # Each frame's points moved to where the first camera sees them as that frame's camera does.
    seen = np.concatenate([transform_points(back @ cam.world_to_camera, p) for cam, p in zip(cameras, points)])
    k = first.framing(seen, margin).K
    return [replace(cam, K=k) for cam in cameras]


def check_camera_move(move: str, amount: float | None = None) -> float:
    """Check a built-in camera move and its amount (None: the default); the amount to use."""
    if move not in CAMERA_MOVES:
        raise InputError(f"camera must be one of {', '.join(CAMERA_MOVES)}, got {move!r}")
    amount = CAMERA_MOVES[move] if amount is None else float(amount)
    lo, hi = CAMERA_AMOUNTS.get(move, (-np.inf, np.inf))
    if not (np.isfinite(amount) and lo <= amount <= hi):
        raise InputError(f"camera amount for {move} must be a number within {lo:g}..{hi:g}, got {amount:g}"
                         if move in CAMERA_AMOUNTS else f"camera amount must be a number, got {amount}")
    return amount


def load_camera_path(path: str | Path, frames: int | None) -> list[Camera]:
    """Cameras from a JSON list of CAMERA.json objects: one per output frame, or one for all.

    ``frames`` None checks the file and returns its cameras, however many
    (to validate it before the frame count is known).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"camera path {path} does not exist")
    items = read_camera_json(path, f"camera path {path}")
    if not isinstance(items, list) or not items:
        raise InputError(f"camera path {path} must hold a non-empty JSON list of cameras")
    if frames is not None and len(items) not in (1, frames):
        raise InputError(f"camera path {path} has {len(items)} cameras for {frames} frames")
    cameras = []
    for i, item in enumerate(items):
        try:
            cameras.append(Camera.from_dict(item))
        except InputError as exc:
            raise InputError(f"camera path {path}, camera {i}: {str(exc).removeprefix('camera: ')}") from None
    if len(cameras) == 1 and frames is not None:
        return cameras * frames
    if len({(c.width, c.height) for c in cameras}) != 1:
        raise InputError(f"cameras in {path} differ in image size")
    return cameras
