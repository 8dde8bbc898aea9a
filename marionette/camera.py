"""Pinhole cameras (OpenCV convention) and their JSON form.

x right, y down, z forward; pixel (u, v) = (0, 0) is the centre of the top-left
pixel, so a centred principal point is ``((W - 1) / 2, (H - 1) / 2)``.
``world_to_camera`` maps world points to camera points.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["Camera", "focal_from_fov", "fov_from_focal", "read_camera_json", "MAX_IMAGE_SIDE"]

#: Largest image side any command accepts (a guard against absurd sizes).
MAX_IMAGE_SIDE = 8192
#: Largest camera JSON file read (a camera path of 100000 frames takes about 40 MiB).
MAX_JSON_BYTES = 64 << 20


def focal_from_fov(width: int, fov_deg: float = 60.0) -> float:
    """Focal length in pixels for a horizontal field of view in degrees."""
    return 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)


def fov_from_focal(width: float, focal: float) -> float:
    """Horizontal field of view in degrees of a focal length in pixels (the inverse of :func:`focal_from_fov`)."""
    return math.degrees(2.0 * math.atan(0.5 * width / focal))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes
    ----------
    K : (3, 3) float64
        Intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.
    world_to_camera : (4, 4) float64
        Rigid transform from world to camera coordinates.
    width, height : int
        Image size in pixels.
    """

    K: np.ndarray
    world_to_camera: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        k = np.asarray(self.K, dtype=np.float64)
        w2c = np.asarray(self.world_to_camera, dtype=np.float64)
        if k.shape != (3, 3) or w2c.shape != (4, 4):
            raise InputError(f"camera: K must be 3x3 and world_to_camera 4x4, got {k.shape} and {w2c.shape}")
        if not (np.all(np.isfinite(k)) and np.all(np.isfinite(w2c))):
            raise InputError("camera: intrinsics or pose contain NaN or infinite values")
        if not (k[0, 0] > 0 and k[1, 1] > 0):
            raise InputError(f"camera: focal lengths must be positive, got fx={k[0, 0]}, fy={k[1, 1]}")
        if np.any(k[2] != [0, 0, 1]) or k[1, 0] != 0:
            raise InputError(f"camera: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}")
        r = w2c[:3, :3]
        with np.errstate(over="ignore", invalid="ignore"):  # huge entries: inf products, caught by allclose
            proper = np.allclose(r @ r.T, np.eye(3), atol=1e-4) and np.linalg.det(r) > 0
        if not proper:
            raise InputError("camera: world_to_camera rotation is not a proper rotation")
        if np.any(w2c[3] != [0, 0, 0, 1]):
            raise InputError(f"camera: world_to_camera must end with the row [0, 0, 0, 1], got {w2c[3].tolist()}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or not 1 <= int(v) <= MAX_IMAGE_SIDE:
                raise InputError(f"camera: {name} must be an integer in 1..{MAX_IMAGE_SIDE}, got {v}")
            object.__setattr__(self, name, int(v))
        object.__setattr__(self, "K", k)
        object.__setattr__(self, "world_to_camera", w2c)

    @staticmethod
    def from_fov(width: int, height: int, fov_deg: float = 60.0,
                 world_to_camera: np.ndarray | None = None) -> "Camera":
        """A centred camera with the given horizontal field of view."""
        return Camera.from_focal(width, height, focal_from_fov(width, fov_deg), world_to_camera)

    @staticmethod
    def from_focal(width: int, height: int, focal: float,
                   world_to_camera: np.ndarray | None = None) -> "Camera":
        """A centred camera with square pixels of focal length ``focal`` (pixels)."""
        f = float(focal)
        k = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
        return Camera(k, np.eye(4) if world_to_camera is None else world_to_camera, width, height)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        r, t = self.world_to_camera[:3, :3], self.world_to_camera[:3, 3]
        return -r.T @ t

    def world_to_camera_points(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) → camera points (N, 3)."""
        return points @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) → pixels (N, 2) and depths (N,)."""
        pc = self.world_to_camera_points(np.asarray(points, dtype=np.float64))
        z = pc[:, 2]
        uv = (pc[:, :2] / np.where(np.abs(z) < 1e-12, 1e-12, z)[:, None]) * [self.fx, self.fy] + [self.cx, self.cy]
        return uv, z

    def resized(self, width: int, height: int) -> "Camera":
        """The same view at another resolution (intrinsics scaled, pixel centres kept)."""
        sx, sy = width / self.width, height / self.height
        k = self.K.copy()
        k[0, 0] *= sx
        k[1, 1] *= sy
        k[0, 2] = (k[0, 2] + 0.5) * sx - 0.5
        k[1, 2] = (k[1, 2] + 0.5) * sy - 0.5
        return replace(self, K=k, width=width, height=height)

    def framing(self, points: np.ndarray, margin: float = 0.06, near: float = 0.25) -> "Camera":
        """This camera zoomed out and re-centred just enough to keep ``points`` in view.

        ``points`` (M, 3) in world coordinates (e.g. every frame of a
        trajectory); those behind the camera are ignored, and so are those
        nearer than ``near`` times the median depth of the others: an object
        that comes up to the lens in a few frames would otherwise shrink every
        other frame to a dot (those few frames overflow the picture instead).
        The focal length only ever shrinks, and the principal point moves as
        little as needed to keep every point ``margin`` (a fraction of the
        image side) inside.
        """
        pc = self.world_to_camera_points(np.asarray(points, dtype=np.float64))
        pc = pc[pc[:, 2] > 1e-9]
        if not len(pc):
            return self
        pc = pc[pc[:, 2] >= near * np.median(pc[:, 2])]
        n = pc[:, :2] / pc[:, 2:3]  # normalised image coordinates
        lo, hi = n.min(axis=0), n.max(axis=0)
        f = np.array([self.fx, self.fy])
        room = np.array([self.width, self.height]) * (1.0 - 2.0 * margin)
        zoom = float(min(1.0, *(room / np.maximum(f * (hi - lo), 1e-12))))
        f = f * zoom
        c = np.array([self.cx, self.cy])
        size = np.array([self.width, self.height])
        # Principal points that keep [lo, hi] inside; take the one nearest the current.
        c_min = size * margin - f * lo
        c_max = size * (1.0 - margin) - f * hi
        c = np.clip(c, np.minimum(c_min, c_max), np.maximum(c_min, c_max))
        k = np.array([[f[0], 0, c[0]], [0, f[1], c[1]], [0, 0, 1.0]])
        return replace(self, K=k)

    def with_pose(self, world_to_camera: np.ndarray) -> "Camera":
        return replace(self, world_to_camera=np.asarray(world_to_camera, dtype=np.float64))

    def to_dict(self) -> dict:
        """The ``CAMERA.json`` form (docs/DESIGN.md contract)."""
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
                "cx": self.cx, "cy": self.cy, "world_to_camera": self.world_to_camera.tolist()}

    @staticmethod
    def from_dict(d: object) -> "Camera":
        """Parse the ``CAMERA.json`` form, naming the first missing or bad key."""
        if not isinstance(d, dict):
            raise InputError("camera: expected a JSON object")
        for key in ("width", "height", "fx", "fy", "cx", "cy", "world_to_camera"):
            if key not in d:
                raise InputError(f"camera: missing key '{key}'")
        for key in ("width", "height", "fx", "fy", "cx", "cy"):
            if not _is_finite_number(d[key]):
                raise InputError(f"camera: '{key}' must be a finite number, got {_short(d[key])}")
        rows = d["world_to_camera"]
        if not (isinstance(rows, list) and len(rows) == 4
                and all(isinstance(row, list) and len(row) == 4 and all(map(_is_finite_number, row)) for row in rows)):
            raise InputError(f"camera: 'world_to_camera' must be a 4x4 list of finite numbers, got {_short(rows)}")
        w2c = np.array(rows, dtype=np.float64)
        k = np.array([[d["fx"], 0, d["cx"]], [0, d["fy"], d["cy"]], [0, 0, 1]], dtype=np.float64)
        return Camera(k, w2c, d["width"], d["height"])

    @staticmethod
    def load(path: str | Path) -> "Camera":
        """Read a ``CAMERA.json`` file."""
        return Camera.from_dict(read_camera_json(path, f"camera file {path}"))


def read_camera_json(path: str | Path, what: str) -> object:
    """The parsed content of a camera JSON file; ``what`` names the file in errors.

    Every failure (missing, unreadable, too large, not UTF-8, bad syntax,
    nested too deeply) is an :class:`InputError`.
    """
    path = Path(path)
    try:
        if path.stat().st_size > MAX_JSON_BYTES:
            raise InputError(f"{what} is larger than {MAX_JSON_BYTES >> 20} MiB")
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read {what}: {e.strerror}") from None
    except UnicodeDecodeError:
        raise InputError(f"{what} is not UTF-8 text") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} is not valid JSON: {e.msg} at line {e.lineno}") from None
    except RecursionError:
        raise InputError(f"{what} is not valid JSON: nested too deeply") from None


def _is_finite_number(value: object) -> bool:
    """A JSON number (not a bool) that is finite as a float64."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond float range
        return False


def _short(value: object, limit: int = 60) -> str:
    """``repr`` cut to ``limit`` characters, for error messages."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 1] + "…"
