"""The camera's full pose per frame, rotation and translation, from background tracks (structure from motion).

:mod:`~marionette.source.camera_motion` models the background as far away,
so that its image moves by a rotation alone. A near background (a road, a
room) shows parallax when the camera travels, and that model leaves most
of it unexplained. Here the background is a set of 3D points seen by a
moving pinhole camera:

1. Two views: of the four pairs of frames with the most shared tracks that
   part by ``min_angle_deg`` once the best rotation between the two frames
   is taken out (the parallax a translation makes; frame 0 and its
   neighbours may have none, as when a hand-held camera starts still), the
   one that triangulates the most tracks. Their essential matrix
   (OpenCV's USAC with local optimisation: plain RANSAC returns a minimal
   sample's model, off by half a degree at 0.3 px of noise), the relative
   pose it gives, and the shared tracks triangulated.
2. Every other frame, forward in time from the pair's first frame and then
   backward from it: PnP (EPnP inside RANSAC, then Levenberg-Marquardt on
   the inliers) on its tracks that have a 3D point. Tracks without a point
   are triangulated from the current frame and the farthest frame in time
   that has a pose and sees them, once their rays part by ``min_angle_deg``,
   so the chain goes on when the first tracks have left the picture.
3. Bundle adjustment by resection and intersection (:func:`_refine`): every
   track re-triangulated from all its agreeing frames, every pose refined
   on its agreeing tracks, a few rounds. The result is then re-expressed
   with frame 0's camera as the world.

A single video fixes the translation only up to scale: it comes out in
units of the two views' baseline, and the caller sets the scale
(:func:`~marionette.source.camera_motion.estimate_camera_motion` puts the
background next to the object at the object's depth). OpenCV's RANSAC is
seeded, so results repeat; what each step hands on is rounded onto a fine
grid (``_STEP``), so they repeat under another machine's BLAS kernel too.

Known limits: a single plane (a bare wall) leaves the two-view geometry
ambiguous; the intrinsics are taken as given (a wrong focal length is
absorbed into the poses as best it can be). docs/benchmarks/extract_real.md
compares it with the rotation model on the real clips.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import invert_transform, make_transform, rotation_between_directions
from ..reproducible import snap, snap_pose
from .tracks import Tracks

__all__ = ["CameraPoses", "bearings_of", "fit_camera_poses"]

#: Every point and pose the chain hands on (a triangulation, a PnP fit, a round of the bundle adjustment) is
#: rounded to this grid (units of the first two views' baseline; radians): each frame's RANSAC keeps its best
#: random sample, and which one wins can follow the last bits of its input, which the matrix products and
#: LAPACK solves in between take from the BLAS kernel (docs/benchmarks/reproducibility_real.md). Their
#: rounding noise is about 1e-13 (:mod:`~marionette.reproducible`).
_STEP = 2.0 ** -20


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
        points = snap((homogeneous[:3] / homogeneous[3]).T, _STEP)
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


def bearings_of(uv: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) → unit viewing directions (..., 3) in the camera."""
    rays = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(k).T
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def _candidate_pairs(bearings: np.ndarray, visible: np.ndarray, min_angle_deg: float, min_shared: int,
                     count: int, max_frames: int = 40) -> list[tuple[int, int]]:
    """Up to ``count`` pairs of frames (a < b) to start from, best first: ranked by how many of their shared
    tracks (bearings (T, M, 3)) part by ``min_angle_deg`` once the best rotation between the two frames is taken
    out (the parallax a translation makes), among pairs sharing ``min_shared`` tracks. At most ``max_frames``
    evenly spaced frames are compared."""
    num_frames = len(bearings)
    frames = np.unique(np.linspace(0, num_frames - 1, min(num_frames, max_frames)).astype(int))
    chord = 2 * np.sin(np.radians(min_angle_deg) / 2)  # the angle as a distance between unit vectors
    scored = []
    for i, a in enumerate(frames):
        for b in frames[i + 1:]:
            shared = np.nonzero(visible[a] & visible[b])[0]
            if len(shared) < min_shared:
                continue
            rotation = rotation_between_directions(bearings[a, shared], bearings[b, shared])
            parted = int(np.sum(np.linalg.norm(bearings[b, shared] - bearings[a, shared] @ rotation.T, axis=1)
                                >= chord))
            scored.append((-parted, int(a), int(b)))
    return [(a, b) for _, a, b in sorted(scored)[:count]]


def _two_views(uv: np.ndarray, visible: np.ndarray, first: int, second: int, k: np.ndarray, threshold_px: float,
               min_angle_deg: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame ``second``'s pose (4, 4) relative to ``first`` from their essential matrix, and the shared tracks
    it triangulates: their indices (P,) and points (P, 3) (none if the pair fixes nothing)."""
    common = np.nonzero(visible[first] & visible[second])[0]
    cv2.setRNGSeed(seed)
    essential, mask = cv2.findEssentialMat(uv[first, common], uv[second, common], k, cv2.USAC_ACCURATE, 0.999,
                                           threshold_px)
    if essential is None or essential.shape != (3, 3):
        return np.eye(4), np.empty(0, int), np.empty((0, 3))
    _, rotation, translation, mask = cv2.recoverPose(essential, uv[first, common], uv[second, common], k, mask=mask)
    pose = snap_pose(make_transform(rotation, translation.ravel()), _STEP)
    inl = common[mask.ravel() > 0]
    found, good = _triangulate(np.eye(4), pose, uv[first, inl], uv[second, inl], k, 2 * threshold_px, min_angle_deg)
    return pose, inl[good], found[good]


def _triangulate_fresh(t: int, poses: np.ndarray, points: np.ndarray, uv: np.ndarray, visible: np.ndarray,
                       solved: np.ndarray, k: np.ndarray, threshold_px: float, min_angle_deg: float) -> None:
    """Give a point (in ``points`` (M, 3), in place) to the tracks frame ``t`` sees without one, each triangulated
    from ``t`` and the solved frame farthest from ``t`` in time that sees it (the widest baseline, as a rule)."""
    fresh = np.nonzero(visible[t] & ~np.isfinite(points[:, 0]))[0]
    if not len(fresh):
        return
    usable = visible[:, fresh] & solved[:, None]
    usable[t] = False
    gap = np.where(usable, np.abs(np.arange(len(poses)) - t)[:, None], -1)  # (T, F)
    reference, has = gap.argmax(axis=0), gap.max(axis=0) > 0
    for r in np.unique(reference[has]):
        sel = fresh[has & (reference == r)]
        found, good = _triangulate(poses[r], poses[t], uv[r, sel], uv[t, sel], k, 2 * threshold_px, min_angle_deg)
        points[sel[good]] = found[good]


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
    errors = np.full(uv.shape[:2], np.inf)
    t, m = np.nonzero(np.isfinite(uv[..., 0]) & np.isfinite(points[:, 0])[None])  # only the observations
    projected = _project(points[m], poses[t, :3, :3], poses[t, :3, 3], k)
    errors[t, m] = np.nan_to_num(np.linalg.norm(projected - uv[t, m], axis=1), nan=np.inf)
    return errors


def _refine(poses: np.ndarray, points: np.ndarray, uv: np.ndarray, visible: np.ndarray, solved: np.ndarray,
            anchor: int, k: np.ndarray, threshold_px: float, min_points: int,
            rounds: int) -> tuple[np.ndarray, np.ndarray]:
    """Bundle adjustment by resection and intersection: ``rounds`` times, every track re-triangulated from all
    the frames where it agrees (within 3 thresholds) with the poses (T, 4, 4) and its current point (M, 3), then
    every solved frame's pose refined by Levenberg-Marquardt on its agreeing tracks. Frame ``anchor`` stays
    where it is. Only agreeing observations count: a background holds things that move (a person, a shadow),
    and the linear triangulation has no defence against them. → (poses (T, 4, 4), points (M, 3))."""
    for _ in range(rounds):
        use = visible & solved[:, None] & (_reprojection_errors(poses, points, uv, k) < 3 * threshold_px)
        points = snap(_triangulate_all(poses, uv, use, k), _STEP)
        use &= _reprojection_errors(poses, points, uv, k) < 3 * threshold_px
        for t in np.nonzero(solved & (np.arange(len(poses)) != anchor))[0]:
            sel = np.nonzero(use[t] & np.isfinite(points[:, 0]))[0]
            if len(sel) < min_points:
                continue
            # Column vectors: given a (3,) translation, OpenCV 5 leaves it where it was.
            rvec, tvec = cv2.solvePnPRefineLM(points[sel], uv[t, sel], k, None, cv2.Rodrigues(poses[t, :3, :3])[0],
                                              poses[t, :3, 3].reshape(3, 1).copy())
            poses[t] = snap_pose(make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()), _STEP)
    use = visible & solved[:, None] & (_reprojection_errors(poses, points, uv, k) < 3 * threshold_px)
    return poses, snap(_triangulate_all(poses, uv, use, k), _STEP)


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
    CameraPoses, or None when no two frames sharing ``2 min_points`` tracks triangulate ``min_points``
    of them, or frame 0's pose cannot be found.
    """
    k = np.asarray(K, dtype=np.float64)
    uv = tracks.uv.astype(np.float64)
    num_frames, num_tracks = tracks.num_frames, tracks.num_tracks
    # The candidate pair that triangulates the most tracks starts the chain; frame `first` is the world
    # until the end.
    best = (0, 0, np.eye(4), np.empty(0, int), np.empty((0, 3)))
    for first, second in _candidate_pairs(bearings_of(uv, k), tracks.visible, min_angle_deg, 2 * min_points, 4):
        pose, index, found = _two_views(uv, tracks.visible, first, second, k, threshold_px, min_angle_deg, seed)
        if len(index) > len(best[3]):
            best = (first, second, pose, index, found)
    first, second, pose, index, found = best
    if len(index) < min_points:
        return None
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    poses[second] = pose
    points = np.full((num_tracks, 3), np.nan)
    points[index] = found

    solved = np.zeros(num_frames, bool)
    solved[[first, second]] = True
    # Forward from the pair's first frame, then backward from it; a frame whose pose is not found keeps
    # its predecessor's in that order.
    order = [*range(first + 1, num_frames), *range(first - 1, -1, -1)]
    for i, t in enumerate(order):
        previous = poses[first] if t == first + 1 or t == first - 1 else poses[order[i - 1]]
        usable = np.nonzero(tracks.visible[t] & np.isfinite(points[:, 0]))[0]
        if not solved[t] and len(usable) >= min_points:
            # EPnP samples, no initial guess: OpenCV 5's iterative PnP started from a guess was seen to return
            # a camera a million units away (and a different one each call) with all points agreeing.
            cv2.setRNGSeed(seed + t)
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(points[usable], uv[t, usable], k, None, iterationsCount=100,
                                                         reprojectionError=2 * threshold_px, flags=cv2.SOLVEPNP_EPNP)
            if ok and inliers is not None and len(inliers) >= min_points:
                sel = usable[inliers.ravel()]
                rvec, tvec = cv2.solvePnPRefineLM(points[sel], uv[t, sel], k, None, rvec, tvec)
                poses[t] = snap_pose(make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()), _STEP)
                solved[t] = True
        if not solved[t]:
            poses[t] = previous
            continue
        _triangulate_fresh(t, poses, points, uv, tracks.visible, solved, k, threshold_px, min_angle_deg)
    if not solved[0]:  # frame 0 is the world: without its pose nothing can be said in it
        return None
    poses, points = _refine(poses, points, uv, tracks.visible, solved, first, k, threshold_px, min_points, rounds)
    # Frame 0's camera becomes the world.
    to_world = poses[0].copy()
    poses = poses @ invert_transform(to_world)
    points = points @ to_world[:3, :3].T + to_world[:3, 3]
    errors = _reprojection_errors(poses, points, uv, k)
    inlier_ratio, residual = np.zeros(num_frames), np.zeros(num_frames)
    for t in np.nonzero(solved)[0]:
        error = errors[t, tracks.visible[t] & np.isfinite(points[:, 0])]
        inside = error < threshold_px
        inlier_ratio[t] = inside.mean() if len(error) else 0.0
        residual[t] = float(np.sqrt(np.mean(error[inside] ** 2))) if inside.any() else 0.0
    return CameraPoses(poses, points, inlier_ratio, residual)
