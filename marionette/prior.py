"""The SpaT prior: per-part rigid steps extracted from a source video.

Motion Marionette (Sec. 4.1) stores, for each time step t, the rigid step
``μ_{t+1} = R_t μ_t + δ_t`` (its Eq. 5). We keep the contract of docs/DESIGN.md:
cumulative poses from frame 0, the steps derived from them, and each part's
centroid and size so a transfer can move parts about their own centres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from .camera import MAX_IMAGE_SIDE
from .errors import InputError
from .geometry import axis_angle_to_matrix, invert_transform

__all__ = ["SpatPrior", "PRIOR_FORMAT", "PRIOR_VERSION", "CAMERA_EXTRA", "MOTION_FRAMES"]

PRIOR_FORMAT = "marionette.spat"
PRIOR_VERSION = 1
#: Extra holding the source camera's motion, world_to_camera per frame (T, 4, 4), when extraction removed it.
CAMERA_EXTRA = "camera_world_to_camera"
#: What a transfer can move the target by: the motion as the source camera filmed it, or in the world.
MOTION_FRAMES = ("filmed", "world")


@dataclass(frozen=True)
class SpatPrior:
    """Spatial-temporal prior for K rigid parts over T frames.

    Attributes
    ----------
    fps : float
        Source frame rate.
    image_size : (2,) int
        Source width, height.
    intrinsics : (3, 3) float64
        Source camera K.
    poses : (K, T, 4, 4) float64
        ``poses[k, t]`` maps part k's points at frame 0 to frame t, in the
        source world frame (camera of frame 0); ``poses[:, 0]`` is identity.
    rotations : (K, T-1, 3, 3) float64
        Step rotations ``R_t`` with ``μ_{t+1} = R_t μ_t + δ_t``.
    translations : (K, T-1, 3) float64
        Step translations ``δ_t``.
    centroids : (K, T, 3) float64
        Part centre per frame.
    radii : (K,) float64
        Part size: RMS distance of its points to its centroid at frame 0.
    extras : dict
        Optional arrays saved alongside (``tracks``, ``labels``, ``camera_world_to_camera``
        (T, 4, 4): the source camera's removed motion, …); ``metadata`` is a
        JSON-serialisable dict.
    """

    fps: float
    image_size: np.ndarray
    intrinsics: np.ndarray
    poses: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    centroids: np.ndarray
    radii: np.ndarray
    extras: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=np.float64)
        if poses.ndim != 4 or poses.shape[2:] != (4, 4) or poses.shape[0] < 1 or poses.shape[1] < 2:
            raise InputError(f"prior key 'poses' must have shape (K, T, 4, 4) with K >= 1, T >= 2, got {poses.shape}")
        k, t = poses.shape[:2]
        expected = {
            "image_size": (2,), "intrinsics": (3, 3), "poses": (k, t, 4, 4),
            "rotations": (k, t - 1, 3, 3), "translations": (k, t - 1, 3),
            "centroids": (k, t, 3), "radii": (k,),
        }
        for name, shape in expected.items():
            try:
                value = np.asarray(getattr(self, name), dtype=np.int64 if name == "image_size" else np.float64)
            except (TypeError, ValueError):
                raise InputError(f"prior key '{name}' is not numeric") from None
            if value.shape != shape:
                raise InputError(f"prior key '{name}' must have shape {shape}, got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InputError(f"prior key '{name}' contains NaN or infinite values")
            object.__setattr__(self, name, value)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"prior key 'fps' must be a positive number, got {self.fps}")
        object.__setattr__(self, "fps", float(self.fps))
        if np.any(self.image_size <= 0):
            raise InputError(f"prior key 'image_size' must be positive, got {self.image_size.tolist()}")
        if np.any(self.image_size > MAX_IMAGE_SIDE):
            raise InputError(f"prior key 'image_size' must be at most {MAX_IMAGE_SIDE}, got {self.image_size.tolist()}")
        cam_k = self.intrinsics
        if not (cam_k[0, 0] > 0 and cam_k[1, 1] > 0 and cam_k[1, 0] == 0 and np.array_equal(cam_k[2], [0, 0, 1])):
            raise InputError("prior key 'intrinsics' must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        if np.any(self.radii <= 0):
            raise InputError("prior key 'radii' must be positive")
        for name, rotations in (("rotations", self.rotations), ("poses", self.poses[..., :3, :3])):
            if not _are_rotations(rotations):
                raise InputError(f"prior key '{name}' holds matrices that are not rotations")
        if not np.allclose(self.poses[..., 3, :], [0, 0, 0, 1], atol=1e-9):
            raise InputError("prior key 'poses' holds matrices whose last row is not [0, 0, 0, 1]")
        if not np.allclose(self.poses[:, 0], np.eye(4), atol=1e-9):
            raise InputError("prior key 'poses' must start with identity at frame 0")
        labels = self.extras.get("labels")
        if labels is not None and not _is_layout(np.asarray(labels), k):
            raise InputError(f"prior extra 'labels' must be a 2-D integer array with parts 0..{k - 1} "
                             "(negative off the object)")

    @property
    def num_parts(self) -> int:
        return self.poses.shape[0]

    @property
    def num_frames(self) -> int:
        return self.poses.shape[1]

    @staticmethod
    def from_poses(poses: np.ndarray, centroids: np.ndarray, radii: np.ndarray, *, fps: float,
                   image_size: tuple[int, int], intrinsics: np.ndarray,
                   extras: dict | None = None, metadata: dict | None = None) -> "SpatPrior":
        """Build a prior from cumulative poses (K, T, 4, 4); steps follow from them.

        The step from t to t+1 is ``poses[t+1] @ inv(poses[t])``, so that
        composing the steps reproduces the poses exactly.
        """
        poses = np.asarray(poses, dtype=np.float64)
        poses = invert_transform(poses[:, :1]) @ poses  # make frame 0 exactly identity
        steps = poses[:, 1:] @ invert_transform(poses[:, :-1])
        return SpatPrior(
            fps=fps, image_size=np.asarray(image_size), intrinsics=intrinsics, poses=poses,
            rotations=steps[..., :3, :3], translations=steps[..., :3, 3], centroids=centroids,
            radii=radii, extras=dict(extras or {}), metadata=dict(metadata or {}),
        )

    def with_poses(self, poses: np.ndarray, centres: np.ndarray) -> "SpatPrior":
        """This prior (rate, size, intrinsics, extras, metadata) with other poses (K, T, 4, 4), its centroids
        those of each part's frame-0 centre (K, 3) moved by them."""
        centroids = np.einsum("ktij,kj->kti", poses[..., :3, :3], centres) + poses[..., :3, 3]
        return SpatPrior.from_poses(poses, centroids, self.radii, fps=self.fps, image_size=tuple(self.image_size),
                                    intrinsics=self.intrinsics, extras=self.extras, metadata=self.metadata)

    @staticmethod
    def identity(num_frames: int, *, fps: float, image_size: tuple[int, int], intrinsics: np.ndarray,
                 centroid: np.ndarray, radius: float, metadata: dict | None = None) -> "SpatPrior":
        """A one-part prior with no motion (for videos where nothing moves)."""
        poses = np.tile(np.eye(4), (1, num_frames, 1, 1))
        cent = np.tile(np.asarray(centroid, dtype=np.float64), (1, num_frames, 1))
        return SpatPrior.from_poses(poses, cent, np.array([radius]), fps=fps, image_size=image_size,
                                    intrinsics=intrinsics, metadata=metadata)

    def in_view(self, rotation: np.ndarray) -> "SpatPrior":
        """The same motion seen from the source camera turned by ``rotation`` (3, 3) about its centre.

        Poses become ``C P C⁻¹`` with ``C = [rotation | 0]``; centroids turn
        with the view. Image-space layouts in ``extras`` are kept as they are.
        """
        c = np.eye(4)
        c[:3, :3] = rotation
        return SpatPrior.from_poses(c @ self.poses @ c.T, self.centroids @ np.asarray(rotation).T, self.radii,
                                    fps=self.fps, image_size=tuple(self.image_size), intrinsics=self.intrinsics,
                                    extras=self.extras, metadata=self.metadata)

    def motion_in(self, frame: str) -> "SpatPrior":
        """The motion in the world (``"world"``, the poses as they are) or as the source camera filmed it
        (``"filmed"``: the camera's own motion, ``extras[CAMERA_EXTRA]``, put back, ``C_t P_t``).

        A camera that pans to follow a car that drives past films a turn in place; in the world the car
        drives off, and a target moved that way leaves a still camera's view. A prior without a removed
        camera motion is the same in both. The camera extra is dropped either way (retimed poses no longer
        match it).
        """
        if frame not in MOTION_FRAMES:
            raise InputError(f"motion must be one of {', '.join(MOTION_FRAMES)}, got {frame!r}")
        extras = {k: v for k, v in self.extras.items() if k != CAMERA_EXTRA}
        cameras = self.extras.get(CAMERA_EXTRA)
        if cameras is None or frame == "world":
            return self if len(extras) == len(self.extras) else replace(self, extras=extras)
        cameras = np.asarray(cameras, dtype=np.float64)
        if cameras.shape != (self.num_frames, 4, 4) or not np.all(np.isfinite(cameras)) \
                or not _are_rotations(cameras[:, :3, :3]):
            raise InputError(f"prior extra '{CAMERA_EXTRA}' must be {self.num_frames} finite rigid 4x4 transforms, "
                             f"got shape {cameras.shape}")
        centroids = np.einsum("tij,ktj->kti", cameras[:, :3, :3], self.centroids) + cameras[:, :3, 3]
        return SpatPrior.from_poses(cameras[None] @ self.poses, centroids, self.radii, fps=self.fps,
                                    image_size=tuple(self.image_size), intrinsics=self.intrinsics, extras=extras,
                                    metadata=self.metadata)

    def aimed_at_object(self) -> "SpatPrior":
        """The motion seen from the source camera turned to look straight at the object at frame 0.

        A target photo is a straight view of its object; an object off the
        source's optical axis moves differently on screen (perspective), so
        its motion is re-expressed for a camera aimed at it (no roll).
        """
        d = self.centroids[:, 0].mean(axis=0)
        d = d / max(np.linalg.norm(d), 1e-12)
        axis = np.cross(d, [0.0, 0.0, 1.0])
        sin = np.linalg.norm(axis)
        if sin < 1e-12:
            return self
        return self.in_view(axis_angle_to_matrix(axis / sin * np.arctan2(sin, d[2])))

    def metadata_json(self) -> str:
        return json.dumps(self.metadata, sort_keys=True)


def _are_rotations(r: np.ndarray) -> bool:
    """Whether every (..., 3, 3) matrix of finite ``r`` is a proper rotation (to 1e-5)."""
    with np.errstate(over="ignore", invalid="ignore"):  # huge entries overflow to inf: not rotations
        return bool(np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-5) and np.all(np.linalg.det(r) > 0))


def _is_layout(labels: np.ndarray, parts: int) -> bool:
    """Whether ``labels`` is an (H, W) integer part layout of ``parts`` parts with some object pixel."""
    return (labels.ndim == 2 and labels.dtype.kind in "iu" and labels.size > 0
            and labels.max() >= 0 and labels.max() < parts)
