"""Camera motion from background tracks, and its removal from object poses.

The world frame is the camera frame of source frame 0 (docs/DESIGN.md). When the
camera moves, a pose fitted in the camera of frame t mixes the object's
motion with the camera's; this module estimates the camera's motion from
the background and takes it out again (:func:`to_world`).

Model: the background is far from the camera compared with how far the
camera travels (hand-held footage, pans), so its image moves by the rotation
homography ``H_t = K R_t K^-1`` and each background point keeps one viewing
direction ``w`` in the world: its bearing at frame t is ``b_t = R_t w``.
Per frame we fit ``R_t`` to those bearing pairs (Wahba's problem, solved by
an SVD: Kabsch without centring) inside RANSAC on two-point samples. Each
track gets its world direction where it is first seen: tracks seeded at
frame 0 anchor ``R_t`` to frame 0 directly, re-seeded ones bridge frames
that no frame-0 track reaches (their error is that of one earlier frame,
not a sum over all steps).

On a far background the parallax of the camera's travel is a fraction of a
pixel, and this model is all there is to fit. When it leaves much of a near
background unexplained (fewer than ``full_below`` of the tracks agree in some
frames) and an object depth is given, the camera's full pose is fitted too
(:func:`~marionette.source.camera_pose.fit_camera_poses`) and kept if the
background agrees with it better. Its translation is known only up to scale
from one video; the scale puts the background points next to the object in
frame 0 (the nearest quarter of them) at the object's depth, the usual case
of an object standing on the ground or in its surroundings.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..geometry import invert_transform, make_transform, rotation_between_directions
from ..io.video import PackedMasks
from ..reproducible import snap_pose
from .camera_pose import CameraPoses, bearings_of, fit_camera_poses
from .tracks import Tracks, _check_video, track

__all__ = ["CameraMotion", "estimate_camera_motion", "to_world"]

#: Grid of the rotations (radians of their rotation vectors): far finer than their accuracy, far coarser than
#: the last bits another machine's SVD changes.
_STEP = 2.0 ** -20


@dataclass(frozen=True)
class CameraMotion:
    """The source camera's motion.

    Attributes
    ----------
    world_to_camera : (T, 4, 4) float64
        Camera of frame t from the world (the camera of frame 0): identity at
        frame 0, and everywhere for a static camera. Rotation only (see the
        module notes).
    static : bool
        The background does not move (median displacement below the threshold).
    inlier_ratio : (T,) float64
        Share of the frame's usable background tracks that agree with its
        rotation; 1 at frame 0 and for a static camera, 0 where too few
        background tracks were left (the previous rotation is kept).
    residual_px : (T,) float64
        RMS distance in pixels between the inliers' tracked positions and
        where the rotation puts them (includes parallax from translation).
    displacement_px : float
        Largest per-frame median displacement of the background tracks since
        they were seeded, in pixels: the static test's statistic.
    num_tracks : int
        Background tracks used.
    model : str
        ``"static"``, ``"rotation"``, or ``"rotation and translation"``.
    rotation_agreement : float
        10th percentile over frames 1.. of the share of background tracks the
        rotation model explains (1 for a static camera): the statistic that
        decides whether the full model is tried.
    full_agreement : float or None
        The same for the full pose when it was tried (0 when no two views fixed
        it), None when it was not.
    """

    world_to_camera: np.ndarray
    static: bool
    inlier_ratio: np.ndarray
    residual_px: np.ndarray
    displacement_px: float
    num_tracks: int
    model: str = "rotation"
    rotation_agreement: float = 1.0
    full_agreement: float | None = None

    @property
    def agreement(self) -> float:
        """10th percentile over frames 1.. of the share of background tracks the chosen model explains."""
        return _agreement(self.inlier_ratio)


def _agreement(inlier_ratio: np.ndarray) -> float:
    """Per-frame shares of agreeing background tracks (T,) → their 10th percentile over frames 1.. (1 for one
    frame)."""
    return float(np.percentile(inlier_ratio[1:], 10)) if len(inlier_ratio) > 1 else 1.0


def _ransac_rotation(src: np.ndarray, dst: np.ndarray, threshold: float, iterations: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Robust ``dst ≈ R src`` on unit directions (N, 3), inliers within ``threshold`` (radians) → (R, inliers)."""
    pairs = np.stack([rng.choice(len(src), 2, replace=False) for _ in range(iterations)])  # (I, 2)
    hypotheses = rotation_between_directions(src[pairs], dst[pairs])  # (I, 3, 3)
    errors = np.linalg.norm(dst[None] - src @ np.swapaxes(hypotheses, 1, 2), axis=2)  # (I, N)
    inliers = errors[np.argmax((errors < threshold).sum(axis=1))] < threshold
    for _ in range(3):  # refit on the consensus, then re-select it
        r = _snapped(rotation_between_directions(src[inliers], dst[inliers]))
        inliers = np.linalg.norm(dst - src @ r.T, axis=1) < threshold
        if inliers.sum() < 2:
            break
    return r, inliers


def _snapped(rotation: np.ndarray) -> np.ndarray:
    """``rotation`` (3, 3) rounded onto :data:`_STEP`'s grid: it places the directions of the tracks found in
    its frame, which later frames' RANSAC starts from, so its last bits (another machine's SVD) would carry on."""
    return snap_pose(make_transform(rotation, np.zeros(3)), _STEP)[:3, :3]


def _displacement(tracks: Tracks, min_tracks: int) -> float:
    """Largest over frames of the median distance (px) the visible tracks moved since their seed frame.

    Frames with fewer than ``min_tracks`` visible tracks do not count: in a motion-blurred frame the few
    tracks that survive slide along the smear, and a static camera would be taken for a moving one.
    """
    seed_uv = tracks.uv[tracks.start, np.arange(tracks.num_tracks)]  # (M, 2)
    moved = np.linalg.norm(tracks.uv - seed_uv[None], axis=2)  # (T, M), NaN where not visible
    counts = np.isfinite(moved).sum(axis=1)
    medians = [np.nanmedian(row) for row, n in zip(moved[1:], counts[1:]) if n >= max(min_tracks, 1)]
    return float(max(medians, default=0.0))


def estimate_camera_motion(frames: np.ndarray, object_masks: np.ndarray, K: np.ndarray, *, margin: int = 8,
                           spacing: int = 20, min_eigen: float = 5e-5, threshold_px: float = 1.0,
                           static_px: float = 0.5, min_tracks: int = 8, iterations: int = 200,
                           object_depth: float | None = None, full_below: float = 0.5,
                           seed: int = 0) -> CameraMotion:
    """Estimate the camera's motion per frame from tracks on the background: a rotation, or a full pose
    where a near background shows parallax (see the module notes).

    Parameters
    ----------
    frames : (T, H, W, 3) uint8
        RGB frames.
    object_masks : (T, H, W) bool or integer
        Moving-object masks (non-zero = object); everything at least
        ``margin`` pixels away from them is background.
    K : (3, 3) float64
        Camera intrinsics.
    margin : int
        Dilation (px) of the object masks before inverting them: boundary
        pixels belong to neither.
    spacing, min_eigen :
        Background track grid spacing (px) and texture floor, passed to
        :func:`~marionette.source.tracks.track` (plain LK, no refinement: a
        few hundred tracks fix a rotation); the floor is lower than on
        objects because backgrounds are often low in contrast.
    threshold_px : float
        RANSAC inlier threshold, in pixels at the focal length.
    static_px : float
        The camera is static when the median background displacement stays
        below this many pixels in every frame.
    min_tracks : int
        Fewest inlier tracks to trust a frame's rotation, and fewest visible
        tracks for a frame to count in telling a static camera.
    iterations : int
        RANSAC hypotheses per frame.
    object_depth : float, optional
        Camera depth of the object's centre in frame 0 (world units): sets the scale of a translation.
        Without it only rotations are estimated.
    full_below : float
        The full pose is tried when the rotation explains fewer than this share of the background tracks
        in a tenth of the frames.
    seed : int
        RANSAC random seed (results are deterministic).

    Returns
    -------
    CameraMotion
    """
    frames, object_masks = _check_video(frames, object_masks)
    k = np.asarray(K, dtype=np.float64)
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise InputError(f"K must be a 3x3 intrinsics matrix with positive focal lengths, got {k.tolist()}")
    num_frames = len(frames)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1,) * 2)
    background = PackedMasks(num_frames, *object_masks[0].shape)  # bits, not bools: long videos stay small
    for t, mask in enumerate(object_masks):
        background[t] = cv2.dilate(mask.view(np.uint8), disc) == 0
    tracks = track(frames, background, spacing=spacing, min_eigen=min_eigen, refine=False)
    identity = np.tile(np.eye(4), (num_frames, 1, 1))
    displacement = _displacement(tracks, min_tracks)
    if displacement < static_px:
        return CameraMotion(identity, True, np.ones(num_frames), np.zeros(num_frames), displacement,
                            tracks.num_tracks, "static")

    bearings = bearings_of(tracks.uv.astype(np.float64), k)  # (T, M, 3), NaN where not visible
    world = np.where((tracks.start == 0)[:, None], bearings[0], np.nan)  # (M, 3) direction in the world
    rotations = np.tile(np.eye(3), (num_frames, 1, 1))
    inlier_ratio, residual = np.ones(num_frames), np.zeros(num_frames)
    focal = np.sqrt(k[0, 0] * k[1, 1])
    rng = np.random.default_rng(seed)
    for t in range(1, num_frames):
        usable = np.nonzero(tracks.visible[t] & np.isfinite(world[:, 0]))[0]
        rotations[t], inlier_ratio[t] = rotations[t - 1], 0.0
        if len(usable) >= max(min_tracks, 2):
            r, inliers = _ransac_rotation(world[usable], bearings[t, usable], threshold_px / focal, iterations, rng)
            if inliers.sum() >= min_tracks:
                rotations[t], inlier_ratio[t] = r, inliers.mean()
                err = np.linalg.norm(bearings[t, usable[inliers]] - world[usable[inliers]] @ r.T, axis=1)
                residual[t] = focal * np.sqrt(np.mean(err ** 2))
        fresh = tracks.visible[t] & ~np.isfinite(world[:, 0])
        world[fresh] = bearings[t, fresh] @ rotations[t]  # R^T b, row-wise
    agreement = _agreement(inlier_ratio)
    rotation_only = CameraMotion(make_transform(rotations, np.zeros(3)), False, inlier_ratio, residual,
                                 displacement, tracks.num_tracks, "rotation", agreement)
    if object_depth is None or agreement >= full_below:
        return rotation_only
    try:
        full = fit_camera_poses(tracks, k, threshold_px=threshold_px, seed=seed)
    except cv2.error:  # a degenerate background (OpenCV refuses it): the rotation stays
        full = None
    scale = None if full is None else _scale(full, tracks, object_masks[0], object_depth)
    if scale is None:
        return dataclasses.replace(rotation_only, full_agreement=0.0)
    full_agreement = _agreement(full.inlier_ratio)
    if full_agreement <= agreement:
        return dataclasses.replace(rotation_only, full_agreement=full_agreement)
    return dataclasses.replace(rotation_only, world_to_camera=make_transform(
        full.world_to_camera[:, :3, :3], scale * full.world_to_camera[:, :3, 3]), inlier_ratio=full.inlier_ratio,
        residual_px=full.residual_px, model="rotation and translation", full_agreement=full_agreement)


def _scale(full: CameraPoses, tracks: Tracks, object_mask: np.ndarray, object_depth: float) -> float | None:
    """World units per unit of ``full``'s translation: the background points nearest the object in frame 0
    (the closest quarter of those seen there, by image distance to its mask) put at the object's depth;
    None when frame 0 sees no point in front of the camera."""
    seen = np.nonzero(tracks.visible[0] & np.isfinite(full.points[:, 0]) & (full.points[:, 2] > 0))[0]
    if not len(seen):
        return None
    distance = ndimage.distance_transform_edt(~object_mask.astype(bool))
    h, w = distance.shape
    u = np.clip(np.rint(tracks.uv[0, seen, 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(tracks.uv[0, seen, 1]).astype(int), 0, h - 1)
    nearest = seen[np.argsort(distance[v, u], kind="stable")[:max(1, len(seen) // 4)]]
    return float(object_depth / np.median(full.points[nearest, 2]))


def to_world(poses_cam: np.ndarray, camera_motion: CameraMotion) -> np.ndarray:
    """Remove the camera's motion from object poses.

    A pose measured in the camera of frame t, ``P_cam_t`` (frame-0 points,
    in camera 0 = world coordinates, to their camera-t coordinates), becomes
    ``P_world_t = C_t^-1 P_cam_t`` with ``C_t`` the camera's world_to_camera.

    Parameters
    ----------
    poses_cam : (..., T, 4, 4) float64
        E.g. (K, T, 4, 4) per part.
    camera_motion : CameraMotion
        With T frames.

    Returns
    -------
    (..., T, 4, 4) float64
    """
    c = camera_motion.world_to_camera
    poses_cam = np.asarray(poses_cam, dtype=np.float64)
    if poses_cam.shape[-3:] != c.shape:
        raise ValueError(f"to_world: poses (..., {len(c)}, 4, 4) expected, got {poses_cam.shape}")
    return invert_transform(c) @ poses_cam
