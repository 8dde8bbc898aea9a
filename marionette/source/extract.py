"""Source video → SpaT prior: tracks, rigid poses, prior (Motion Marionette stages 1 and 3).

The paper (Sec. 3-4.1) lifts dense 2D tracks to 3D and fits per-step rigid
transforms (Eq. 3-5). This first path treats the masked object as one rigid
part (K = 1) seen by a static camera, so the world frame is the camera frame
of frame 0:

1. :func:`~marionette.source.tracks.track`: Lucas–Kanade tracks on the object;
2. :class:`~marionette.source.rigid.ShapePrior`: the object's frame-0 volume
   inflated from its mask, scaled to an RMS radius of 1 unit (the monocular
   scale is unknowable);
3. :func:`~marionette.source.rigid.fit_rigid`: per-frame pose by RANSAC PnP and
   bundle adjustment;
4. :func:`~marionette.source.rigid.carved_centroid`: the object's centre, from
   the prior volume carved by all silhouettes;
5. :meth:`~marionette.prior.SpatPrior.from_poses`: steps ``R_t, δ_t`` from the
   poses, the centre moved by them, and the prior's radius (1 unit).

Multi-part segmentation, camera-motion removal and automatic masks slot in
before step 3 (one ``fit_rigid`` per part, on its tracks and mask).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..prior import SpatPrior
from .rigid import RigidOptions, ShapePrior, carved_centroid, fit_rigid
from .tracks import Tracks, _check_video, track

__all__ = ["ExtractOptions", "extract_prior"]

METHOD = "anchored-lk-tracks+inflated-shape+pnp-ransac+bundle-adjustment+carved-centre"


@dataclass(frozen=True)
class ExtractOptions:
    """Settings of :func:`extract_prior`.

    Attributes
    ----------
    spacing, window, levels, fb_threshold, reseed_every, min_eigen :
        Tracking settings, passed to :func:`~marionette.source.tracks.track`
        (same defaults: 6 px grid, 21 px window, 3 pyramid levels, 1 px
        forward-backward threshold, re-seeding every 4 frames, texture 2e-4).
    relief : float
        Half-thickness of the inflated shape prior relative to the mask's
        inscribed radius (1: a disc mask becomes a sphere).
    motion_threshold : float
        Pixels. When the median track displacement from its start stays below
        this at every frame, the video is declared motionless and the
        identity prior returned (with a warning).
    rigid : RigidOptions
        Pose estimation settings.
    """

    spacing: int = 6
    window: int = 21
    levels: int = 3
    fb_threshold: float = 1.0
    reseed_every: int = 4
    min_eigen: float = 2e-4
    relief: float = 1.0
    motion_threshold: float = 0.5
    rigid: RigidOptions = field(default_factory=RigidOptions)


def _motion_px(tracks: Tracks) -> float:
    """Largest, over frames, median displacement (pixels) of visible tracks from their start; 0 if none."""
    first = tracks.uv[tracks.start, np.arange(tracks.num_tracks)]  # (M, 2)
    disp = np.linalg.norm(tracks.uv - first[None], axis=2)  # (T, M), NaN where not visible
    counts = tracks.visible.sum(axis=1)
    medians = [np.median(d[v]) for d, v, c in zip(disp, tracks.visible, counts) if c]
    return float(max(medians, default=0.0))


def extract_prior(frames: np.ndarray, masks: np.ndarray, camera_K: np.ndarray, fps: float, *,
                  options: ExtractOptions = ExtractOptions(),
                  progress: Callable[[int, int], None] | None = None) -> SpatPrior:
    """Extract the SpaT prior of one rigidly moving object from a video with masks.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W, 3), uint8
        RGB frames, T >= 2, from a static camera.
    masks : ndarray, shape (T, H, W), bool or integer
        Object masks (non-zero = object); frame 0's must not be empty.
    camera_K : ndarray, shape (3, 3)
        Intrinsics of the source camera.
    fps : float
        Source frame rate.
    options : ExtractOptions
    progress : callable(done, total), optional
        Called as work proceeds, ``total = 2 T - 1`` (tracking steps, pose
        frames, refinement).

    Returns
    -------
    SpatPrior
        One part (K = 1); poses (1, T, 4, 4) in the camera frame of frame 0,
        in units where the object's shape prior has an RMS radius of
        ``radii[0]`` = 1; centroids (1, T, 3) its carved centre moved by the
        poses.
        Extras: ``tracks_uv`` (T, M, 2) float32, ``tracks_visible`` (T, M)
        bool, ``labels`` (H, W) int16 (0 on the frame-0 object, -1 elsewhere).
        Metadata: method, options, failed frames with reasons, track count,
        reprojection RMS and per-stage timings in seconds.

    Warns
    -----
    UserWarning
        When nothing moves or the object has too few trackable points (the
        identity prior is returned), or when the pose of some frames could not
        be estimated (they are interpolated).
    """
    frames, masks = _check_video(frames, masks)
    k = np.asarray(camera_K, dtype=np.float64) if isinstance(camera_K, (np.ndarray, list, tuple)) else None
    if k is None or k.shape != (3, 3) or not np.all(np.isfinite(k)) or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise InputError(f"camera_K must be a finite 3x3 matrix with positive focal lengths, got {camera_K!r}")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) or not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    num_frames, h, w = masks.shape
    if num_frames < 2:
        raise InputError(f"the source video needs at least 2 frames, got {num_frames}")
    total = 2 * num_frames - 1

    def stage(offset: int) -> Callable[[int, int], None] | None:
        return None if progress is None else (lambda done, _: progress(offset + done, total))

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    tracks = track(frames, masks, spacing=options.spacing, window=options.window, levels=options.levels,
                   fb_threshold=options.fb_threshold, reseed_every=options.reseed_every,
                   min_eigen=options.min_eigen, progress=stage(0))
    t1 = time.perf_counter()
    shape = ShapePrior.inflate(masks[0], k, relief=options.relief)
    timings["tracking"], timings["shape"] = t1 - t0, time.perf_counter() - t1

    labels = np.where(masks[0], 0, -1).astype(np.int16)
    extras = {"tracks_uv": tracks.uv, "tracks_visible": tracks.visible, "labels": labels}
    metadata = {"method": METHOD, "options": dataclasses.asdict(options), "num_tracks": tracks.num_tracks,
                "camera_motion": "assumed static", "timings": timings}
    common = dict(fps=fps, image_size=(w, h), intrinsics=k)

    motion = _motion_px(tracks)
    few = tracks.num_tracks < options.rigid.min_points
    if few or motion < options.motion_threshold:
        reason = (f"only {tracks.num_tracks} trackable points on the object (too little texture, or a tiny mask)"
                  if few else f"no motion detected (median track displacement {motion:.2f} px < "
                  f"{options.motion_threshold} px)")
        warnings.warn(f"{reason}: returning the identity prior", stacklevel=2)
        timings["total"] = time.perf_counter() - t0
        metadata.update(failed_frames={}, no_motion=not few, motion_px=motion)
        prior = SpatPrior.identity(num_frames, centroid=shape.centroid, radius=shape.radius,
                                   metadata=metadata, **common)
        if progress is not None:
            progress(total, total)
        return dataclasses.replace(prior, extras=extras)

    fit = fit_rigid(tracks, shape, options=options.rigid, progress=stage(num_frames - 1))
    timings.update(fit.timings)
    t2 = time.perf_counter()
    good = np.array([t for t in range(num_frames) if t not in fit.failed_frames])
    centre = carved_centroid(shape, masks, fit.poses, good)
    timings["centre"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    if fit.failed_frames:
        listed = ", ".join(str(t) for t in list(fit.failed_frames)[:10])
        more = "…" if len(fit.failed_frames) > 10 else ""
        warnings.warn(f"pose estimation failed at {len(fit.failed_frames)} of {num_frames} frames "
                      f"({listed}{more}); their poses are interpolated (see metadata 'failed_frames')",
                      stacklevel=2)
    poses = fit.poses[None]  # (1, T, 4, 4)
    centroids = poses[..., :3, :3] @ centre + poses[..., :3, 3]  # (1, T, 3)
    metadata.update(failed_frames={str(t): r for t, r in fit.failed_frames.items()}, no_motion=False,
                    motion_px=motion, reprojection_rms_px=fit.reprojection_rms,
                    inlier_tracks=int(fit.inliers.any(axis=0).sum()))
    return SpatPrior.from_poses(poses, centroids, np.array([shape.radius]), extras=extras, metadata=metadata,
                                **common)
