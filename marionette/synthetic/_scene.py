"""Synthetic source videos with exact ground truth, and synthetic target images."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import MAX_IMAGE_SIDE, Camera
from ..errors import InputError
from ..geometry import axis_angle_to_matrix, invert_transform, make_transform
from ..prior import SpatPrior
from ._motions import plan_camera, plan_motion
from ._objects import (Shape, make_box, make_car, make_cylinder, make_door, make_drawer, make_hinged_box, make_rod,
                       make_screen, make_vase)
from ._render import pixel_depth, render_shape, resolve, view_background
from ._textures import background_texture

MOTIONS = ("translation", "inplane", "outofplane", "oscillation", "hinge", "slide")
OBJECTS = ("box", "hinge", "door", "drawer", "screen")
#: Objects ``render_object_image`` can draw.
TARGET_OBJECTS = ("box", "hinge", "cylinder", "vase", "rod", "car")
BACKGROUNDS = ("textured", "plain")
CAMERA_MOTIONS = ("static", "pan", "handheld")

#: Horizontal field of view of the synthetic camera, in degrees.
FOV_DEG = 60.0
_PLAIN_BACKGROUND = np.array([0.86, 0.86, 0.84], np.float32)
#: Depth of the background plane, in units of the object's depth at frame 0:
#: far enough that a moving camera sees it turn almost like a rotation homography.
_BACKGROUND_DEPTH = 10.0
_BUILDERS = {"box": make_box, "hinge": make_hinged_box, "door": make_door, "drawer": make_drawer,
             "screen": make_screen,
             "cylinder": make_cylinder, "vase": make_vase, "rod": make_rod, "car": make_car}


@dataclass(frozen=True)
class SyntheticScene:
    """A rendered rigid motion with its exact ground truth.

    Attributes
    ----------
    frames : (T, H, W, 3) uint8
        RGB video frames.
    masks : (T, H, W) bool
        Object pixels (more than half of the pixel covered).
    part_masks : (T, H, W) int8
        Part index per object pixel, -1 for background; part 0 is the largest.
    camera : Camera
        Intrinsics and the camera of frame 0, which is the world frame
        (``world_to_camera`` is identity).
    poses : (P, T, 4, 4) float64
        ``poses[k, t]`` maps part k's points at frame 0 to frame t, in the
        world frame; ``poses[:, 0]`` is identity (the SpaT prior contract).
    part_points : list of (M_k, 3) float64
        Points on each part's surface at frame 0, on a regular grid per face
        (the box corners are among them).
    fps : float
    motion : str
        One of ``MOTIONS``.
    object : str
        One of ``OBJECTS``.
    depths : (T, H, W) float32
        z-depth of the object along each pixel centre's ray, in the camera of
        that frame; inf where the ray misses the object (the background).
    camera_poses : (T, 4, 4) float64
        ``world_to_camera`` of each frame; identity for frame 0, and for all
        frames of a static camera.
    plain : bool
        Every face one colour (its texture's mean): only shading and edges
        show the parts, as on a plain grey door.
    camera_motion : str
        One of ``CAMERA_MOTIONS``.
    """

    frames: np.ndarray
    masks: np.ndarray
    part_masks: np.ndarray
    camera: Camera
    poses: np.ndarray
    part_points: list[np.ndarray]
    fps: float
    motion: str
    object: str
    depths: np.ndarray
    camera_poses: np.ndarray
    camera_motion: str

    @property
    def num_frames(self) -> int:
        return self.poses.shape[1]

    @property
    def num_parts(self) -> int:
        return self.poses.shape[0]

    def centroids(self) -> np.ndarray:
        """(P, T, 3) each part's centroid per frame: the frame-0 mean of its points, moved by its poses."""
        c0 = np.stack([p.mean(axis=0) for p in self.part_points])  # (P, 3)
        return np.einsum("ptij,pj->pti", self.poses[..., :3, :3], c0) + self.poses[..., :3, 3]

    def radii(self) -> np.ndarray:
        """(P,) RMS distance of each part's points to their centroid at frame 0."""
        return np.array([np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()) for p in self.part_points])

    def track_truth(self, start: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where points seeded on whole pixels truly are in every frame (ground truth for 2D tracks).

        A seed's 3D point is the rendered depth at its pixel, on the part
        drawn there, moved by that part's poses and seen by each frame's camera.

        Parameters
        ----------
        start : (M,) int
            Frame where each point was seeded.
        seeds : (M, 2) float
            Its pixel (u, v) there; rounded to the nearest pixel centre.

        Returns
        -------
        positions : (T, M, 2) float64
            True pixel of each point in each frame (also where it is hidden).
        valid : (M,) bool
            Seeds that fall on the object (the others' positions are NaN).
        """
        start = np.asarray(start, dtype=np.int64)
        col, row = np.rint(np.asarray(seeds, dtype=np.float64)).astype(np.int64).T
        depth = self.depths[start, row, col].astype(np.float64)
        valid = np.isfinite(depth)
        part = np.maximum(self.part_masks[start, row, col], 0)
        k = self.camera.K
        rays = np.column_stack([(col - k[0, 2]) / k[0, 0], (row - k[1, 2]) / k[1, 1], np.ones(len(col))])
        # Camera of the seed frame → world → the part's frame-0 body → world at t → camera of t.
        seeded = invert_transform(self.camera_poses[start] @ self.poses[part, start])  # (M, 4, 4)
        body = np.einsum("mij,mj->mi", seeded[:, :3, :3], rays * np.where(valid, depth, 1.0)[:, None])
        body += seeded[:, :3, 3]
        moved = self.camera_poses[None] @ self.poses[part]  # (M, T, 4, 4)
        cam = np.einsum("mtij,mj->tmi", moved[..., :3, :3], body) + moved[..., :3, 3].transpose(1, 0, 2)
        positions = self.camera.project(cam.reshape(-1, 3))[0].reshape(cam.shape[:2] + (2,))  # frame 0 is the world
        positions[:, ~valid] = np.nan
        return positions, valid

    def ground_truth_prior(self) -> SpatPrior:
        """The exact SpaT prior of this scene, to compare extracted priors against."""
        return SpatPrior.from_poses(
            self.poses, self.centroids(), self.radii(), fps=self.fps,
            image_size=(self.camera.width, self.camera.height), intrinsics=self.camera.K,
            metadata={"synthetic": {"motion": self.motion, "object": self.object}},
        )


def _check_size(size: object) -> tuple[int, int]:
    try:
        w, h = size  # type: ignore[misc]
    except (TypeError, ValueError):
        raise InputError(f"size must be (width, height), got {size!r}") from None
    for v in (w, h):
        if isinstance(v, bool) or int(v) != v or not 16 <= int(v) <= MAX_IMAGE_SIDE:
            raise InputError(f"size must be two integers in 16..{MAX_IMAGE_SIDE}, got {size!r}")
    return int(w), int(h)


def _check_seed(seed: object) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _check_number(name: str, value: object, *, positive: bool) -> float:
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (ok and np.isfinite(value) and (value > 0 if positive else value >= 0)):
        raise InputError(f"{name} must be a {'positive' if positive else 'non-negative'} number, got {value!r}")
    return float(value)


# Random streams, one per purpose and per use, so that changing how one is
# drawn from never perturbs the others: np.random.default_rng([seed, purpose, use]).
_SCENE, _TARGET = 0, 1
_GEOMETRY, _TEXTURE, _BACKGROUND, _NOISE, _CAMERA = 0, 1, 2, 3, 4


def _rng(seed: int, purpose: int, use: int) -> np.random.Generator:
    return np.random.default_rng([seed, purpose, use])


def make_scene(motion: str, *, object: str | None = None, num_frames: int = 48,
               size: tuple[int, int] = (320, 240), seed: int = 0, fps: float = 24.0,
               background: str = "textured", noise: float = 0.0,
               camera_motion: str = "static", plain: bool = False) -> SyntheticScene:
    """Render a textured rigid object moving in front of a static or moving camera.

    Parameters
    ----------
    motion : str
        ``"translation"`` (lateral plus some depth change, no rotation),
        ``"inplane"`` (~90° about the optical axis, through the object's
        centre), ``"outofplane"`` (~90° yaw about the object's vertical axis,
        turning new faces into view), ``"oscillation"`` (a couple of periods
        of a ±20-30° twist/swing) or ``"hinge"`` (a body, static or turning
        slowly, and a lid opening 60-80° about its hinge edge) or ``"slide"``
        (a cabinet, static or turning slowly, and a drawer pulled out by
        50-80 % of its depth).
    object : str, optional
        ``"box"``, ``"hinge"`` (a body with a lid: two parts), ``"door"`` (a
        cabinet with a door on an upright hinge, for the hinge motion too),
        ``"screen"`` (a screen swivelling on its stand's post, for the hinge
        motion too) or ``"drawer"`` (a cabinet with a drawer). Defaults to the hinge object
        for the hinge motion, the drawer for the slide and ``"box"``
        otherwise; with other motions the parts of an object move together.
    num_frames : int
        T >= 2; the whole motion is spread over the clip.
    size : (int, int)
        Width, height in pixels. The camera has a 60° horizontal field of
        view. At 4:3 the object sits 3-5 units in front and spans ~30-50 % of
        the width; wider frames put it further away, so that it fits the height.
    seed : int
        Drives the object's size, start orientation, motion magnitudes,
        textures and background; equal seeds give identical scenes.
    fps : float
        Frame rate recorded in the scene (the motion is defined per clip).
    background : str
        ``"textured"`` (static, low-contrast noise) or ``"plain"`` (light grey).
    noise : float
        Standard deviation, in 8-bit intensity levels, of Gaussian pixel noise
        added to every frame (independently per pixel and channel). It does
        not touch the masks or the ground truth.
    camera_motion : str
        ``"static"``, ``"pan"`` (a smooth 10-16° yaw with 2-6° pitch over the
        clip) or ``"handheld"`` (1-3° sway, ~1 % drift of the object's depth,
        per-frame jitter); see ``scene.camera_poses``. Object poses stay in
        the world frame (the camera of frame 0), so the ground truth does not
        change. The background is a plane 10 times further than the object,
        facing the frame-0 camera: it turns with the camera (a homography,
        with slight parallax under the handheld drift).

    Returns
    -------
    SyntheticScene
    """
    if motion not in MOTIONS:
        raise InputError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
    obj = {"hinge": "hinge", "slide": "drawer"}.get(motion, "box") if object is None else object
    if obj not in OBJECTS:
        raise InputError(f"object must be one of {', '.join(OBJECTS)}, got {obj!r}")
    if motion == "hinge" and obj not in ("hinge", "door", "screen"):
        raise InputError("the hinge motion needs the hinge, door or screen object")
    if motion == "slide" and obj != "drawer":
        raise InputError("the slide motion needs the drawer object")
    if isinstance(num_frames, bool) or not isinstance(num_frames, (int, np.integer)) or num_frames < 2:
        raise InputError(f"num_frames must be an integer >= 2, got {num_frames!r}")
    width, height = _check_size(size)
    seed = _check_seed(seed)
    fps = _check_number("fps", fps, positive=True)
    if background not in BACKGROUNDS:
        raise InputError(f"background must be one of {', '.join(BACKGROUNDS)}, got {background!r}")
    noise = _check_number("noise", noise, positive=False)
    if camera_motion not in CAMERA_MOTIONS:
        raise InputError(f"camera_motion must be one of {', '.join(CAMERA_MOTIONS)}, got {camera_motion!r}")

    geom = _rng(seed, _SCENE, _GEOMETRY)
    local = _BUILDERS[obj](geom, _rng(seed, _SCENE, _TEXTURE))
    if plain:
        local = local.plain()
    camera = Camera.from_fov(width, height, FOV_DEG)
    placement, poses = plan_motion(motion, local, camera, int(num_frames), geom)
    shape = local.transformed(placement)
    if background == "textured":
        bg = background_texture(_rng(seed, _SCENE, _BACKGROUND), (height, width))
    else:
        bg = np.broadcast_to(_PLAIN_BACKGROUND, (height, width, 3))

    t_count, p_count = poses.shape[1], poses.shape[0]
    distance = _BACKGROUND_DEPTH * placement[2, 3]
    camera_poses = plan_camera(camera_motion, t_count, placement[2, 3], _rng(seed, _SCENE, _CAMERA))
    frames = np.empty((t_count, height, width, 3), np.uint8)
    masks = np.empty((t_count, height, width), bool)
    part_masks = np.empty((t_count, height, width), np.int8)
    depths = np.empty((t_count, height, width), np.float32)
    noise_rng = _rng(seed, _SCENE, _NOISE)
    for t in range(t_count):
        view = Camera(camera.K, camera_poses[t], width, height)
        color, ids, depth = render_shape(shape, poses[:, t], view, with_depth=True)
        depths[t] = pixel_depth(depth)
        back = bg if camera_motion == "static" else view_background(bg, camera.K, camera_poses[t], distance)
        image, coverage, part_masks[t] = resolve(color, ids, p_count, back)
        image *= 255.0
        if noise > 0:
            image += noise_rng.normal(0.0, noise, image.shape).astype(np.float32)
        frames[t] = np.clip(np.rint(image), 0, 255)
        masks[t] = coverage > 0.5
    return SyntheticScene(frames, masks, part_masks, camera, poses, shape.part_points(), fps, motion, obj,
                          depths, camera_poses, camera_motion)


def render_object_image(object: str = "box", *, size: tuple[int, int] = (256, 256), seed: int = 0,
                        yaw_deg: float = 30.0, pitch_deg: float = 20.0) -> np.ndarray:
    """An RGBA still (H, W, 4) uint8 of a synthetic object, for use as a target image.

    The object (``"box"``, ``"hinge"``, ``"cylinder"`` (a squat can), ``"vase"``
    (a surface of revolution), ``"rod"`` (a thin bar) or ``"car"`` (a car-like
    shape, mirror-symmetric about its long mid-plane)) gets warm colours and
    a checker of colour cells, so it looks unlike ``make_scene``'s objects. It
    is centred, turned by ``yaw_deg`` about its vertical axis and tilted
    ``pitch_deg`` towards the camera (60° horizontal field of view); its
    bounding sphere spans ~80 % of the smaller image side. Alpha is 255 on
    object pixels (coverage > 0.5) and 0 elsewhere; the transparent background
    is white. :func:`object_view` also gives the camera and the object's centre.
    """
    return object_view(object, size=size, seed=seed, yaw_deg=yaw_deg, pitch_deg=pitch_deg)[0]


def object_view(object: str = "box", *, size: tuple[int, int] = (256, 256), seed: int = 0, yaw_deg: float = 30.0,
                pitch_deg: float = 20.0, fov_deg: float = FOV_DEG, turn_deg: float = 0.0,
                plain: bool = False) -> tuple[np.ndarray, Camera, np.ndarray]:
    """:func:`render_object_image`'s still (H, W, 4), its camera and the object's centre (3,) in the camera frame.

    ``fov_deg``: the camera's horizontal field of view (the object still spans ~80 % of the image; a
    narrower field is a longer lens, with less perspective). ``turn_deg``: the posed object then turned
    about the camera's vertical axis through its centre (the truth for a single-view lift turned so).
    ``plain``: every face one colour, its texture's mean (shading alone varies it).

    The same ``object``, ``size`` and ``seed`` at other yaws show the same object turned about its own
    vertical axis (the camera's ``y`` axis tilted by ``pitch_deg``) through that centre: the truth for
    novel views.
    """
    if object not in TARGET_OBJECTS:
        raise InputError(f"object must be one of {', '.join(TARGET_OBJECTS)}, got {object!r}")
    width, height = _check_size(size)
    seed = _check_seed(seed)
    for name, value in (("yaw_deg", yaw_deg), ("pitch_deg", pitch_deg), ("fov_deg", fov_deg), ("turn_deg", turn_deg)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not np.isfinite(value):
            raise InputError(f"{name} must be a finite number, got {value!r}")
    if not 1.0 <= fov_deg <= 170.0:
        raise InputError(f"fov_deg must be between 1 and 170, got {fov_deg!r}")
    local = _BUILDERS[object](_rng(seed, _TARGET, _GEOMETRY), _rng(seed, _TARGET, _TEXTURE), target=True)
    if plain:
        local = local.plain()
    camera = Camera.from_fov(width, height, fov_deg)
    rot = (axis_angle_to_matrix([0.0, np.radians(turn_deg), 0.0])
           @ axis_angle_to_matrix([np.radians(pitch_deg), 0.0, 0.0])
           @ axis_angle_to_matrix([0.0, np.radians(yaw_deg), 0.0]))
    z = camera.fx * local.bounding_radius() / (0.8 * min(width, height) / 2)
    shape = local.transformed(make_transform(rot, [0.0, 0.0, z]))
    image, coverage, _ = resolve(*render_shape(shape, np.tile(np.eye(4), (len(shape.parts), 1, 1)), camera),
                                 len(shape.parts), None)
    mask = coverage > 0.5
    # Un-premultiply so edge pixels keep the object's colour under a hard alpha.
    rgb = np.where(mask[..., None], image / np.maximum(coverage, 1e-6)[..., None], 1.0)
    out = np.empty((height, width, 4), np.uint8)
    out[..., :3] = np.clip(np.rint(rgb * 255.0), 0, 255)
    out[..., 3] = np.where(mask, 255, 0)
    return out, camera, np.array([0.0, 0.0, z])
