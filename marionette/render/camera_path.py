"""Camera paths for the output video: static, orbit, dolly, or a list of cameras from a file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import Camera, read_camera_json
from ..errors import InputError
from ..geometry import axis_angle_to_matrix, make_transform

__all__ = ["CAMERA_MOVES", "camera_path", "check_camera_move", "load_camera_path"]

#: Built-in camera moves and their default amount: orbit, degrees turned about the
#: object's vertical axis over the clip; dolly, share of the distance to the
#: object covered towards it.
CAMERA_MOVES = {"static": 0.0, "orbit": 30.0, "dolly": 0.3}


def camera_path(camera: Camera, centre: np.ndarray, frames: int, move: str = "static",
                amount: float | None = None) -> list[Camera]:
    """``frames`` cameras that start at ``camera`` and ``move`` relative to ``centre`` (3,) (world).

    ``orbit`` turns the camera about the vertical axis (the camera's y axis)
    through ``centre`` by ``amount`` degrees (default 30) over the clip, eased
    in and out; ``dolly`` moves it along its line of sight towards ``centre``
    by ``amount`` (default 0.3) of the distance.
    """
    amount = check_camera_move(move, amount)
    if move == "static":
        return [camera] * frames
    eased = 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, frames))  # 0 → 1, slow at both ends
    w2c = camera.world_to_camera
    centre_cam = w2c[:3, :3] @ np.asarray(centre, dtype=np.float64) + w2c[:3, 3]
    path = []
    for u in eased:
        if move == "orbit":  # turn the world about the vertical axis through the centre, as the camera sees it
            turn = axis_angle_to_matrix([0.0, np.radians(amount) * u, 0.0])
            about = make_transform(turn, centre_cam - turn @ centre_cam)
        else:  # dolly: the world comes towards the camera along the line of sight
            about = make_transform(np.eye(3), -amount * u * centre_cam)
        path.append(camera.with_pose(about @ w2c))
    return path


def check_camera_move(move: str, amount: float | None = None) -> float:
    """Check a built-in camera move and its amount (None: the default); the amount to use."""
    if move not in CAMERA_MOVES:
        raise InputError(f"camera must be one of {', '.join(CAMERA_MOVES)}, got {move!r}")
    amount = CAMERA_MOVES[move] if amount is None else float(amount)
    if not np.isfinite(amount) or (move == "dolly" and not 0 <= amount < 1):
        raise InputError(f"camera amount for {move} must be {'in [0, 1)' if move == 'dolly' else 'finite'}, "
                         f"got {amount}")
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
