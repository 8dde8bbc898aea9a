"""Object placement and ground-truth motions.

The world frame is the camera frame (x right, y down, z forward). A motion
gives the object's placement at frame 0 (object-local → world) and, per part,
poses (P, T, 4, 4) mapping frame-0 world points to frame t. Magnitudes are
drawn from the generator so that seeds give distinct cases; the clip always
covers the whole motion, whatever the number of frames.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..geometry import axis_angle_to_matrix, make_transform
from ._objects import Shape

#: Projected bounding radius of the object at frame 0, as a fraction of half
#: the smaller image side. Smaller where the motion needs room to move.
_FILL = {"translation": 0.58, "inplane": 0.75, "outofplane": 0.72, "oscillation": 0.62, "hinge": 0.64, "slide": 0.6}


def rotation_about(point: np.ndarray, axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations by ``angles`` (T,) radians about the line through ``point`` along ``axis`` → (T, 4, 4)."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    r = axis_angle_to_matrix(np.asarray(angles, dtype=np.float64)[:, None] * axis)
    return make_transform(r, point - r @ point)


def _initial_rotation(rng: np.random.Generator, hinged: bool) -> np.ndarray:
    """Object-local → world rotation (3, 3): a yaw to show a side face, then a tilt to show the top."""
    yaw = np.radians(rng.uniform(20, 40) * rng.choice([-1, 1]))
    pitch = np.radians(rng.uniform(25, 35) if hinged else rng.uniform(15, 30))
    roll = np.radians(rng.uniform(-8, 8))
    # Positive pitch about +x turns the top face (normal -y) towards the camera (-z).
    return (axis_angle_to_matrix([0.0, 0.0, roll]) @ axis_angle_to_matrix([pitch, 0.0, 0.0])
            @ axis_angle_to_matrix([0.0, yaw, 0.0]))


def plan_motion(motion: str, shape: Shape, camera: Camera, num_frames: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Place ``shape`` and move it.

    Returns
    -------
    placement : (4, 4) float64
        Object-local → world transform at frame 0.
    poses : (P, T, 4, 4) float64
        Part k's frame-0 world points → frame t; ``poses[:, 0]`` is identity.
    """
    num_parts = len(shape.parts)
    rot0 = _initial_rotation(rng, shape.hinge is not None or shape.slide is not None)
    up = rot0 @ np.array([0.0, -1.0, 0.0])  # the object's vertical axis in the world
    radius = shape.bounding_radius()
    z0 = camera.fx * radius / (_FILL[motion] * min(camera.width, camera.height) / 2) * rng.uniform(0.95, 1.05)
    half_w, half_h = z0 * camera.width / 2 / camera.fx, z0 * camera.height / 2 / camera.fy
    centre = np.array([rng.uniform(-0.05, 0.05) * half_w, rng.uniform(-0.05, 0.05) * half_h, z0])
    s = np.linspace(0.0, 1.0, num_frames)
    sign = rng.choice([-1.0, 1.0])

    if motion == "translation":
        # Lateral travel is a share of the room the object leaves in the frame.
        room_x, room_y = max(half_w - radius, 0.0), max(half_h - radius, 0.0)
        shift = np.array([sign * rng.uniform(0.7, 0.95) * room_x, rng.uniform(-0.3, 0.3) * room_y,
                          rng.choice([-1.0, 1.0]) * rng.uniform(0.12, 0.2) * z0])
        centre = centre - shift / 2  # the path is centred on the frame
        poses = make_transform(np.eye(3), s[:, None] * shift)
    elif motion == "inplane":
        # On the optical axis, so the image turns rigidly about the principal point.
        centre = np.array([0.0, 0.0, z0])
        poses = rotation_about(centre, [0.0, 0.0, 1.0], sign * np.radians(rng.uniform(75, 105)) * s)
    elif motion == "outofplane":
        poses = rotation_about(centre, up, sign * np.radians(rng.uniform(80, 100)) * s)
    elif motion == "oscillation":
        # A random mix of twist (about the vertical) and swing (about the horizontal
        # image axis), pivoting at or above the centre like a hanging object.
        mix = rng.normal(size=3) * [1.0, 0.7, 0.4]
        axis = mix[0] * up + mix[1] * np.array([1.0, 0.0, 0.0]) + mix[2] * np.array([0.0, 0.0, 1.0])
        pivot = centre + up * rng.uniform(0.0, 0.5) * radius
        periods = rng.uniform(1.75, 2.5)
        angles = np.radians(rng.uniform(20, 30)) * np.sin(2 * np.pi * periods * s)
        poses = rotation_about(pivot, axis, angles)
    elif motion == "hinge":
        # Lower in the frame: the opening lid rises above the body.
        centre[1] += 0.12 * half_h
        body_turn = 0.0 if rng.random() < 0.5 else sign * np.radians(rng.uniform(6, 12))
        body = rotation_about(centre, up, body_turn * s)
        smooth = s * s * (3 - 2 * s)  # the lid starts and ends at rest
        placement = make_transform(rot0, centre)
        point = placement[:3, :3] @ shape.hinge[0] + centre
        lid = body @ rotation_about(point, rot0 @ shape.hinge[1], np.radians(rng.uniform(60, 80)) * smooth)
        return placement, np.stack([body, lid])
    elif motion == "slide":
        # The drawer pulls out by 50-80 % of its depth, towards the camera's side of the object.
        body_turn = 0.0 if rng.random() < 0.5 else sign * np.radians(rng.uniform(6, 12))
        body = rotation_about(centre, up, body_turn * s)
        smooth = s * s * (3 - 2 * s)
        travel = rng.uniform(0.5, 0.8) * 0.9 * _extent(shape, shape.slide)
        drawer = body @ make_transform(np.eye(3), (smooth * travel)[:, None] * (rot0 @ shape.slide))
        return make_transform(rot0, centre), np.stack([body, drawer])
    else:
        raise ValueError(f"unknown motion {motion!r}")
    return make_transform(rot0, centre), np.repeat(poses[None], num_parts, axis=0)


def _extent(shape: Shape, direction: np.ndarray) -> float:
    """The object's extent along ``direction`` (3,), local units."""
    points = np.concatenate(shape.part_points()) @ direction
    return float(points.max() - points.min())


def plan_camera(kind: str, num_frames: int, distance: float, rng: np.random.Generator) -> np.ndarray:
    """World-to-camera transforms (T, 4, 4) of a moving camera; frame 0 is identity.

    ``"static"``: identity throughout. ``"pan"``: a smooth (ease-in, ease-out)
    turn of 10-16° yaw and 2-6° pitch over the clip, about the camera centre.
    ``"handheld"``: a slow sway of 1-3° about each axis (less roll) and a
    drift of ~1 % of ``distance`` (the object's depth), plus per-frame jitter
    of ~0.08° and ~0.1 %.
    """
    s = np.linspace(0.0, 1.0, num_frames)
    if kind == "static":
        return np.tile(np.eye(4), (num_frames, 1, 1))
    if kind == "pan":
        amplitude = np.radians([rng.uniform(2, 6), rng.uniform(10, 16), 0.0]) * rng.choice([-1.0, 1.0], 3)
        rotvec = (s * s * (3 - 2 * s))[:, None] * amplitude
        centre = np.zeros((num_frames, 3))
    elif kind == "handheld":
        def sway(scale: np.ndarray, jitter: float) -> np.ndarray:
            # Two slow sinusoids per axis plus white jitter, shifted so frame 0 sits at zero.
            freq = rng.uniform(0.4, 1.6, (2, 3))
            phase = rng.uniform(0, 2 * np.pi, (2, 3))
            wave = np.sin(2 * np.pi * freq[:, None] * s[None, :, None] + phase[:, None]).sum(axis=0) / 2
            path = wave * scale + rng.normal(0.0, jitter, (num_frames, 3))
            return path - path[0]

        rotvec = sway(np.radians([rng.uniform(1, 3), rng.uniform(1, 3), rng.uniform(0.5, 1.5)]), np.radians(0.08))
        centre = sway(np.full(3, 0.01 * distance), 0.001 * distance)
    else:
        raise ValueError(f"unknown camera motion {kind!r}")
    to_world = axis_angle_to_matrix(rotvec)  # camera orientation in the world
    return make_transform(np.swapaxes(to_world, 1, 2), -np.einsum("tji,tj->ti", to_world, centre))
