"""The camera's full pose per frame, rotation and translation, from background tracks (structure from motion).

:mod:`~marionette.source.camera_motion` models the background as far away,
so that its image moves by a rotation alone. A near background (a road, a
room) shows parallax when the camera travels, and that model leaves most
of it unexplained. Here the background is a set of 3D points seen by a
moving pinhole camera:

1. Two views: frame 0 and the frame with the most parallax that still sees
   half of frame 0's tracks. Their essential matrix (OpenCV's USAC with
   local optimisation: plain RANSAC returns a minimal sample's model, off by
   half a degree at 0.3 px of noise), the relative pose it gives, and the
   shared tracks triangulated.
2. Every other frame in time order: PnP (EPnP inside RANSAC, then
   Levenberg-Marquardt on the inliers) on its tracks that have a 3D point.
   Tracks without a point are triangulated from their seed frame and the
   current one once their rays part by ``min_angle_deg``, so the chain goes
   on when frame 0's tracks have left the picture.
3. Bundle adjustment by resection and intersection (:func:`_refine`): every
   track re-triangulated from all its agreeing frames, every pose refined
   on its agreeing tracks, a few rounds.

A single video fixes the translation only up to scale: it comes out in
units of the two views' baseline, and the caller sets the scale
(:func:`~marionette.source.camera_motion.estimate_camera_motion` puts the
background next to the object at the object's depth). OpenCV's RANSAC is
seeded, so results repeat.

Known limits: a single plane (a bare wall) leaves the two-view geometry
ambiguous, and on the DAVIS car-turn clip, which pans by hundreds of pixels,
the chain loses the background after about 40 frames (docs/benchmarks/
extract_real.md reports the agreement of both models).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import make_transform
from .tracks import Tracks

__all__ = ["CameraPoses", "fit_camera_poses"]


@dataclass(frozen=True)
class CameraPoses:
    """A moving camera recovered from background tracks.

    Attributes
    ----------
    world_to_camera : (T, 4, 4) float64
        Camera of frame t from the world (the camera of frame 0); translation
        in units of the initial baseline.
    points : (M, 3) float64
        World position of each track, NaN where it was not triangulated.
    inlier_ratio : (T,) float64
        Share of the frame's tracks with a point that reproject within the
        threshold; 1 at frame 0, 0 where the pose could not be found.
    residual_px : (T,) float64
        RMS reprojection error of those inliers, in pixels.
    """

    world_to_camera: np.ndarray
    points: np.ndarray
    inlier_ratio: np.ndarray
    residual_px: np.ndarray


def _project(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray, k: np.ndarray) -> np.ndarray:
    """World points (N, 3) seen by cameras (N, 3, 3), (N, 3) (or one) → pixels (N, 2); NaN behind the camera."""
    cam = np.einsum("...ij,...j->...i", rotation, points) + translation
    z = np.where(cam[..., 2] > 1e-9, cam[..., 2], np.nan)
    return np.stack([k[0, 0] * cam[..., 0] / z + k[0, 2], k[1, 1] * cam[..., 1] / z + k[1, 2]], axis=-1)


def _triangulate(pose_a: np.ndarray, pose_b: np.ndarray, uv_a: np.ndarray, uv_b: np.ndarray, k: np.ndarray,
                 threshold_px: float, min_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) seen at pixels (N, 2) by two cameras (4, 4) → world points (N, 3) and which are good (N,):
    in front of both, reprojecting within the threshold, with rays that part by ``min_angle_deg``."""
    if not len(uv_a):
        return np.empty((0, 3)), np.zeros(0, bool)
    homogeneous = cv2.triangulatePoints(k @ pose_a[:3], k @ pose_b[:3], uv_a.T.astype(np.float64),
                                        uv_b.T.astype(np.float64))
    with np.errstate(divide="ignore", invalid="ignore"):
        points = (homogeneous[:3] / homogeneous[3]).T
    good = np.all(np.isfinite(points), axis=1)
    centres = []
    for pose, uv in ((pose_a, uv_a), (pose_b, uv_b)):
        error = np.linalg.norm(_project(points, pose[:3, :3], pose[:3, 3], k) - uv, axis=1)
        good &= np.nan_to_num(error, nan=np.inf) < threshold_px
        centres.append(-pose[:3, :3].T @ pose[:3, 3])
    rays = [points - c for c in centres]
    cos = np.einsum("ij,ij->i", *rays) / np.maximum(np.linalg.norm(rays[0], axis=1) * np.linalg.norm(rays[1], axis=1),
                                                   1e-300)
    good &= cos < np.cos(np.radians(min_angle_deg))
    return points, good


def _initial_pair(tracks: Tracks, min_points: int) -> int | None:
    """The frame paired with frame 0: the most parallax (median displacement) among the frames that still see
    half of frame 0's tracks; None if no frame sees ``min_points`` of them."""
    seen = tracks.visible[0]
    best, best_shift = None, 0.0
    for t in range(1, tracks.num_frames):
        common = seen & tracks.visible[t]
        if common.sum() < max(min_points, 0.5 * seen.sum()):
            break
        shift = float(np.median(np.linalg.norm(tracks.uv[t, common] - tracks.uv[0, common], axis=1)))
        if shift > best_shift:
            best, best_shift = t, shift
    return best


def _triangulate_all(poses: np.ndarray, uv: np.ndarray, use: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Every track (M) from all its frames at once: poses (T, 4, 4), pixels (T, M, 2), which observations to
    use (T, M) → world points (M, 3) (NaN with fewer than two), by the linear (DLT) method in normalised
    coordinates: the smallest eigenvector of the sum of each observation's two constraint rows' outer products."""
    rays = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], axis=2) @ np.linalg.inv(k).T  # (T, M, 3)
    rays = np.where(use[..., None], rays, 0.0)
    p = poses[:, :3]  # (T, 3, 4)
    rows_x = rays[..., 0, None] * p[:, None, 2] - rays[..., 2, None] * p[:, None, 0]  # (T, M, 4)
    rows_y = rays[..., 1, None] * p[:, None, 2] - rays[..., 2, None] * p[:, None, 1]
    normal = np.einsum("tmi,tmj->mij", rows_x, rows_x) + np.einsum("tmi,tmj->mij", rows_y, rows_y)  # (M, 4, 4)
    _, vectors = np.linalg.eigh(normal)
    homogeneous = vectors[:, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        points = homogeneous[:, :3] / homogeneous[:, 3:]
    points[use.sum(axis=0) < 2] = np.nan
    return points


def _reprojection_errors(poses: np.ndarray, points: np.ndarray, uv: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Pixel distance (T, M) between each track's point seen by each frame's camera and where it was tracked;
    inf where either is missing or the point is behind the camera."""
    projected = _project(points[None], poses[:, None, :3, :3], poses[:, None, :3, 3], k)
    return np.nan_to_num(np.linalg.norm(projected - uv, axis=2), nan=np.inf)


def _refine(poses: np.ndarray, uv: np.ndarray, visible: np.ndarray, solved: np.ndarray, k: np.ndarray,
            threshold_px: float, min_points: int, rounds: int) -> tuple[np.ndarray, np.ndarray]:
    """Bundle adjustment by resection and intersection: ``rounds`` times, every track re-triangulated from all
    the frames where it agrees with the poses (within 3 thresholds), then every solved frame's pose refined by
    Levenberg-Marquardt on its agreeing tracks. Frame 0 stays the world. → (poses (T, 4, 4), points (M, 3))."""
    use = visible & solved[:, None]
    for _ in range(rounds):
        points = _triangulate_all(poses, uv, use, k)
        errors = _reprojection_errors(poses, points, uv, k)
        use = visible & solved[:, None] & (errors < 3 * threshold_px)
        for t in np.nonzero(solved)[0][1:]:
            sel = np.nonzero(use[t] & np.isfinite(points[:, 0]))[0]
            if len(sel) < min_points:
                continue
            rvec, tvec = cv2.solvePnPRefineLM(points[sel], uv[t, sel], k, None, cv2.Rodrigues(poses[t, :3, :3])[0],
                                              poses[t, :3, 3].copy())
            poses[t] = make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel())
    return poses, _triangulate_all(poses, uv, use, k)


def fit_camera_poses(tracks: Tracks, K: np.ndarray, *, threshold_px: float = 1.0, min_points: int = 12,
                     min_angle_deg: float = 1.0, rounds: int = 5, seed: int = 0) -> CameraPoses | None:
    """The camera's pose per frame from tracks on a static background.

    Parameters
    ----------
    tracks : Tracks
        Background tracks over T frames (the object masked out).
    K : (3, 3) float64
        Camera intrinsics.
    threshold_px : float
        Reprojection error (px) within which a track agrees with a pose.
    min_points : int
        Fewest points that fix a frame's pose; frames with fewer keep the previous one.
    min_angle_deg : float
        Smallest angle between the two rays of a triangulated point.
    rounds : int
        Rounds of the bundle adjustment (:func:`_refine`).
    seed : int
        Seed of OpenCV's RANSAC.

    Returns
    -------
    CameraPoses, or None when no two views share ``min_points`` tracks with parallax.
    """
    k = np.asarray(K, dtype=np.float64)
    uv = tracks.uv.astype(np.float64)
    num_frames, num_tracks = tracks.num_frames, tracks.num_tracks
    pair = _initial_pair(tracks, min_points)
    if pair is None:
        return None
    common = np.nonzero(tracks.visible[0] & tracks.visible[pair])[0]
    cv2.setRNGSeed(seed)
    essential, mask = cv2.findEssentialMat(uv[0, common], uv[pair, common], k, cv2.USAC_ACCURATE, 0.999, threshold_px)
    if essential is None or essential.shape != (3, 3):
        return None
    _, rotation, translation, mask = cv2.recoverPose(essential, uv[0, common], uv[pair, common], k, mask=mask)
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[pair] = make_transform(rotation, translation.ravel())
    points = np.full((num_tracks, 3), np.nan)
    inl = common[mask.ravel() > 0]
    if len(inl) < min_points:
        return None
    found, good = _triangulate(poses[0], poses[pair], uv[0, inl], uv[pair, inl], k, 2 * threshold_px, min_angle_deg)
    if good.sum() < min_points:
        return None
    points[inl[good]] = found[good]

    solved = np.zeros(num_frames, bool)
    solved[0] = True
    for t in range(1, num_frames):
        usable = np.nonzero(tracks.visible[t] & np.isfinite(points[:, 0]))[0]
        previous = poses[t - 1]
        if len(usable) >= min_points:
            # EPnP samples, no initial guess: OpenCV 5's iterative PnP started from a guess was seen to return
            # a camera a million units away (and a different one each call) with all points agreeing.
            cv2.setRNGSeed(seed + t)
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(points[usable], uv[t, usable], k, None, iterationsCount=100,
                                                         reprojectionError=2 * threshold_px, flags=cv2.SOLVEPNP_EPNP)
            if ok and inliers is not None and len(inliers) >= min_points:
                sel = usable[inliers.ravel()]
                rvec, tvec = cv2.solvePnPRefineLM(points[sel], uv[t, sel], k, None, rvec, tvec)
                poses[t] = make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel())
                solved[t] = True
        if not solved[t]:
            poses[t] = previous
            continue
        # New points: tracks seen now without one, triangulated from their seed frame if it has a pose.
        fresh = np.nonzero(tracks.visible[t] & ~np.isfinite(points[:, 0]) & solved[tracks.start]
                           & (tracks.start < t))[0]
        for seed_frame in np.unique(tracks.start[fresh]):
            sel = fresh[tracks.start[fresh] == seed_frame]
            found, good = _triangulate(poses[seed_frame], poses[t], uv[seed_frame, sel], uv[t, sel], k,
                                       2 * threshold_px, min_angle_deg)
            points[sel[good]] = found[good]

    poses, points = _refine(poses, uv, tracks.visible, solved, k, threshold_px, min_points, rounds)
    errors = _reprojection_errors(poses, points, uv, k)
    inlier_ratio, residual = np.zeros(num_frames), np.zeros(num_frames)
    for t in np.nonzero(solved)[0]:
        error = errors[t, tracks.visible[t] & np.isfinite(points[:, 0])]
        inside = error < threshold_px
        inlier_ratio[t] = inside.mean() if len(error) else 0.0
        residual[t] = float(np.sqrt(np.mean(error[inside] ** 2))) if inside.any() else 0.0
    return CameraPoses(poses, points, inlier_ratio, residual)
