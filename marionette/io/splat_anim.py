"""Animated-splat files: one ``.npz`` holding a whole transfer result, loaded without pickle.

Keys (format ``"marionette.splats"``, version 1; N Gaussians, C SH
coefficients, T frames, P parts)::

    format          str scalar   "marionette.splats"
    version         int scalar   1
    fps             float scalar frames per second, > 0
    means           (N, 3)       rest-pose Gaussians (marionette.gaussians.Gaussians)
    quats           (N, 4)
    log_scales      (N, 3)
    opacity_logits  (N,)
    sh              (N, C, 3)    C in 1, 4, 9, 16
    frame_means     (T, N, 3)    Gaussian centres per frame (Trajectory.means)
    part_rotations  (T, P, 3, 3) accumulated rotation of each part since frame 0
    labels          (N,) int     part of each Gaussian, in 0 … P-1

Frame ``t`` is ``Trajectory.frame(gaussians, t)``: centres ``frame_means[t]``,
orientations turned by ``part_rotations[t][labels]``. Float arrays are stored
as float32 (float16 is accepted on reading).

The per-frame ``.ply`` folders written by ``--ply-dir`` (``00000.ply`` …) are
read by :func:`read_ply_frames`.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..gaussians import Gaussians
from ..trajectory import Trajectory
from .atomic import atomic_path
from .ply import read_ply

__all__ = ["SplatAnimation", "read_splat_animation", "write_splat_animation", "read_ply_frames",
           "SPLATS_FORMAT", "SPLATS_VERSION"]

SPLATS_FORMAT = "marionette.splats"
SPLATS_VERSION = 1

_GAUSSIAN_KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")
_REQUIRED = ("format", "version", "fps", *_GAUSSIAN_KEYS, "frame_means", "part_rotations", "labels")


@dataclass(frozen=True)
class SplatAnimation:
    """Rest-pose Gaussians moved over time.

    Attributes
    ----------
    gaussians : Gaussians, N of them, in their rest pose.
    trajectory : Trajectory with means (T, N, 3), part_rotations (T, P, 3, 3), labels (N,).
    fps : float
        Playback rate.
    """

    gaussians: Gaussians
    trajectory: Trajectory
    fps: float

    @property
    def num_frames(self) -> int:
        return self.trajectory.num_frames

    def frame(self, t: int) -> Gaussians:
        """The Gaussians at frame ``t``."""
        return self.trajectory.frame(self.gaussians, t)


def _check_fps(fps: float) -> float:
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps}")
    return fps


def write_splat_animation(path: str | Path, gaussians: Gaussians, trajectory: Trajectory, fps: float) -> None:
    """Write an animated result to ``path`` (.npz), atomically.

    Uncompressed: per-frame float32 centres barely compress, and an
    uncompressed archive loads quickly.
    """
    fps = _check_fps(fps)
    if trajectory.means.shape[1] != len(gaussians):
        raise InputError(f"trajectory moves {trajectory.means.shape[1]} Gaussians, "
                         f"but {len(gaussians)} were given")
    gaussians.check_finite()
    for name in ("means", "part_rotations"):
        if not np.all(np.isfinite(getattr(trajectory, name))):
            raise InputError(f"Trajectory.{name} contains NaN or infinite values")
    arrays = {
        "format": np.array(SPLATS_FORMAT), "version": np.array(SPLATS_VERSION), "fps": np.array(fps),
        **{key: getattr(gaussians, key) for key in _GAUSSIAN_KEYS},
        "frame_means": trajectory.means, "part_rotations": trajectory.part_rotations,
        "labels": trajectory.labels,
    }
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)


def _scalar(data, key: str, kind: type):
    value = data[key]
    if value.shape != ():
        raise InputError(f"splat animation key '{key}' must be a scalar, got shape {value.shape}")
    try:
        return kind(value.item())
    except (TypeError, ValueError):
        raise InputError(f"splat animation key '{key}' has the wrong type ({value.dtype})") from None


def _array(data, key: str, shape: tuple[int | None, ...], kind: str = "f") -> np.ndarray:
    """``data[key]`` checked against ``shape`` (None: any size) and dtype kind ('f' float, 'i' integer)."""
    value = data[key]
    kinds = "f" if kind == "f" else "iu"
    if value.dtype.kind not in kinds:
        raise InputError(f"splat animation key '{key}' must be {'floats' if kind == 'f' else 'integers'}, "
                         f"got {value.dtype}")
    if value.ndim != len(shape) or any(s is not None and s != v for s, v in zip(shape, value.shape)):
        expected = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"splat animation key '{key}' must have shape {expected}, got {value.shape}")
    if kind == "f" and not np.all(np.isfinite(value)):
        raise InputError(f"splat animation key '{key}' contains NaN or infinite values")
    return value


def _read_arrays(data, path: Path) -> SplatAnimation:
    missing = [k for k in _REQUIRED if k not in data.files]
    if missing:
        raise InputError(f"splat animation {path} lacks key '{missing[0]}'")
    fmt = _scalar(data, "format", str)
    if fmt != SPLATS_FORMAT:
        raise InputError(f"splat animation key 'format' is '{fmt}', expected '{SPLATS_FORMAT}'")
    version = _scalar(data, "version", int)
    if version != SPLATS_VERSION:
        raise InputError(f"splat animation key 'version' is {version}; this tool reads version {SPLATS_VERSION}")
    fps = _scalar(data, "fps", float)
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"splat animation key 'fps' must be a positive number, got {fps}")

    means = _array(data, "means", (None, 3))
    n = len(means)
    if n == 0:
        raise InputError("splat animation key 'means' holds no Gaussians")
    sh = _array(data, "sh", (n, None, 3))
    if sh.shape[1] not in (1, 4, 9, 16):
        raise InputError(f"splat animation key 'sh' must have 1, 4, 9 or 16 coefficients, got {sh.shape[1]}")
    gaussians = Gaussians(means, _array(data, "quats", (n, 4)), _array(data, "log_scales", (n, 3)),
                          _array(data, "opacity_logits", (n,)), sh)
    frame_means = _array(data, "frame_means", (None, n, 3))
    t = len(frame_means)
    if t == 0:
        raise InputError("splat animation key 'frame_means' holds no frames")
    rotations = _array(data, "part_rotations", (t, None, 3, 3))
    labels = _array(data, "labels", (n,), kind="i")
    p = rotations.shape[1]
    if labels.min() < 0 or labels.max() >= p:
        raise InputError(f"splat animation key 'labels' must be part indices in 0..{p - 1}")
    return SplatAnimation(gaussians, Trajectory(frame_means, rotations, labels), fps)


def read_splat_animation(path: str | Path) -> SplatAnimation:
    """Read and validate an animated-splat file; errors name the offending key."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"splat animation {path} does not exist")
    if not zipfile.is_zipfile(path):
        raise InputError(f"splat animation {path} is not a readable .npz file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            return _read_arrays(data, path)
    except InputError:
        raise
    except ValueError as e:
        # np.load refuses object arrays (pickle) with a ValueError.
        raise InputError(f"splat animation {path} holds pickled objects or bad data: {e}") from None
    except (OSError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise InputError(f"splat animation {path} is not a readable .npz file ({type(e).__name__})") from None


def read_ply_frames(folder: str | Path) -> list[Gaussians]:
    """Read a folder of per-frame 3DGS ``.ply`` files (``00000.ply`` …), in name order.

    Every frame must hold the same number of Gaussians.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder")
    paths = sorted(folder.glob("*.ply"))
    if not paths:
        raise InputError(f"folder {folder} holds no .ply files")
    frames = [read_ply(p) for p in paths]
    for p, g in zip(paths, frames):
        if len(g) != len(frames[0]):
            raise InputError(f"{p} holds {len(g)} Gaussians, but {paths[0].name} holds {len(frames[0])}")
    return frames
