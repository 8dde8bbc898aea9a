"""Per-frame rigid pose of one rigid body from its 2D tracks.

Motion Marionette (Sec. 3, Eq. 1) lifts 2D tracks to 3D with learned metric
depth and bundle-adjusted cameras (MoSca), then fits per-step rigid
transforms with Umeyama's method (Eq. 3-4). Without a depth network we use
the rigidity itself, the classical structure-from-motion route:

1. **Shape prior.** The monocular scale is unknowable, so we fix it: the
   object's frame-0 shape is a rounded volume inflated from its mask
   (:meth:`ShapePrior.inflate`), placed at the depth where its RMS radius is
   exactly 1 unit. The volume is as thick as the mask is wide at its widest
   inscribed disc (a disc mask gives a sphere): for a rigid object seen once,
   "about as deep as it is wide" is the least committal guess, and a rounded
   front surface, unlike a flat plane, keeps PnP well posed under
   out-of-plane rotation.
2. **Sequential PnP.** Tracks alive at frame 0 are lifted onto the volume's
   front surface. At each frame t the pose follows from the lifted tracks
   visible at t by RANSAC PnP (``cv2.solvePnPRansac``, started from the pose
   predicted at constant velocity) and Levenberg–Marquardt refinement on the
   inliers (``cv2.solvePnPRefineLM``). Tracks first seen at t (re-seeded on
   surface that turned into view) are then lifted by casting their pixel ray
   into the volume moved by the pose at t, so they carry the pose once the
   frame-0 surface has turned away.
3. **Joint refinement.** A bundle adjustment
   (:mod:`marionette.source.bundle`; Triggs et al., "Bundle adjustment — a
   modern synthesis", 1999) over all poses and a subset of the 3D points,
   with a Huber loss and a weak prior keeping each point's depth near its
   starting value. The scale is a gauge freedom that reprojections cannot
   see: at the end it is reset so that the tracks lifted at frame 0 keep
   their median depth, the shape prior's scale (left to the depth prior, it
   drifts with the shape guessed for surface that turns into view later).
   Where the object turns out of plane, parallax corrects the guessed shape
   and the poses with it; where it does not (translation, in-plane rotation)
   the shape stays the prior's and is irrelevant to the motion anyway. It
   runs every ``refine_every`` frames on the frames so far (so that the next
   PnP uses corrected points) and over the whole clip at the end, where
   tracks are then cut where they start to disagree with the fit (drift) and
   it runs once more. With clean strict tracks (median residual under a
   quarter pixel), that second pass leaves out the brief pieces restarted at
   a cut (``RigidOptions.min_piece_frames``), whose lag adds up to a tilt.
4. **Centre.** :func:`carved_centroid` carves the prior volume, widened to
   the depth range of the points the fit triangulated, with the silhouettes
   of all frames under the fitted poses; its centroid is the body's centre
   (what the SpaT prior rotates parts about).

Frames where the pose cannot be estimated (fewer than ``min_points`` tracks
or inliers) are expected outcomes, not errors. They are tried once more
after the refinement, from its corrected points and poses (a few poorly
posed frames before one can leave it a guess too far off for PnP); those it
places are listed in ``RigidFit.retried_frames``. Given a ``recover``
function (:mod:`~marionette.source.recover` aligns a model of the body to
the frame), their pose is found without tracks, as is the pose of a frame
where only a few tracks survive; those frames are listed in
``RigidFit.recovered_frames`` and held in the refinement. The others are
interpolated between the nearest good frames (held after the last one) and
reported with a reason in ``RigidFit.failed_frames``. Tracks born at such a
frame are lifted with the pose found or predicted there, so that the frames
after it can go on.

Poses map points of the body at frame 0, expressed in the camera frame of
frame 0, to the camera frame of frame t (``X_t = R X_0 + t``); with a static
camera this is the SpaT prior's world frame.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..geometry import invert_transform, make_transform, se3_interpolate, transform_points
from ..reproducible import snap, snap_pose
from .bundle import bundle_adjust
from .tracks import Tracks

__all__ = ["ShapePrior", "RigidOptions", "RigidFit", "fit_rigid", "carved_centroid", "RETRIED_NOTE"]

# Ray-casting: samples along each ray through the volume's depth range, then
# bisection steps on the first entry (each halves a step of ~3 % of the radius).
_RAY_SAMPLES = 64
_RAY_BISECTIONS = 16
#: A point's depth counts as measured when its viewing direction turned by at
#: least this much between its first and last inlier observation (the usual
#: structure-from-motion triangulation-angle test; COLMAP's default is 1.5°).
_MIN_TRIANGULATION_DEG = 2.0


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) bilinearly at pixels ``uv`` (N, 2) → (N,); NaN outside or next to NaN."""
    h, w = image.shape
    u, v = uv[:, 0], uv[:, 1]
    inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    u, v = np.where(inside, u, 0.0), np.where(inside, v, 0.0)
    i0 = np.minimum(np.floor(v).astype(np.int64), h - 2)
    j0 = np.minimum(np.floor(u).astype(np.int64), w - 2)
    a, b = v - i0, u - j0
    out = ((1 - a) * ((1 - b) * image[i0, j0] + b * image[i0, j0 + 1])
           + a * ((1 - b) * image[i0 + 1, j0] + b * image[i0 + 1, j0 + 1]))
    return np.where(inside, out, np.nan)


def _rays(k: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) → camera rays (N, 3) with z = 1."""
    return np.column_stack([(uv[:, 0] - k[0, 2]) / k[0, 0], (uv[:, 1] - k[1, 2]) / k[1, 1], np.ones(len(uv))])


def _project(k: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Camera points (N, 3) → pixels (N, 2)."""
    z = points[:, 2:3]
    return points[:, :2] / z * [k[0, 0], k[1, 1]] + [k[0, 2], k[1, 2]]


@dataclass(frozen=True)
class ShapePrior:
    """A body's frame-0 volume: every pixel ray of its mask, between a front and a back depth.

    Attributes
    ----------
    K : (3, 3) float64
        Intrinsics of frame 0.
    front, back : (H, W) float64
        Camera depth (z) where each pixel's ray enters and leaves the body at
        frame 0; NaN outside the mask.
    centroid : (3,) float64
        Centroid of the volume (camera frame 0).
    radius : float
        RMS distance of the front and back surface points of all mask pixels
        to ``centroid``.
    extent : float
        Largest distance of those points to ``centroid`` (bounds ray casting).
    """

    K: np.ndarray
    front: np.ndarray
    back: np.ndarray
    centroid: np.ndarray
    radius: float
    extent: float

    @staticmethod
    def from_depths(front: np.ndarray, back: np.ndarray, K: np.ndarray) -> "ShapePrior":
        """The volume between two depth maps (H, W) (NaN outside), e.g. a given depth and a thickness.

        Each mask pixel contributes the frustum column ``front <= z <= back``,
        of volume ∝ ``back³ - front³`` and centroid depth
        ``3/4 (back⁴ - front⁴) / (back³ - front³)`` along its ray.
        """
        front = np.asarray(front, dtype=np.float64)
        back = np.asarray(back, dtype=np.float64)
        k = np.asarray(K, dtype=np.float64)
        if front.shape != back.shape or front.ndim != 2:
            raise ValueError(f"ShapePrior: front and back must be equal (H, W) maps, got {front.shape}, {back.shape}")
        inside = np.isfinite(front) & np.isfinite(back)
        if not inside.any() or np.any(front[inside] <= 0) or np.any(back[inside] < front[inside]):
            raise ValueError("ShapePrior: needs pixels with 0 < front <= back")
        v, u = np.nonzero(inside)
        rays = _rays(k, np.column_stack([u, v]).astype(np.float64))
        zf, zb = front[inside], back[inside]
        vol = zb**3 - zf**3
        zc = np.where(vol > 0, 0.75 * (zb**4 - zf**4) / np.where(vol > 0, vol, 1.0), zf)
        weight = np.where(vol > 0, vol, 1e-12 * zf**3)
        centroid = (weight * zc) @ rays / weight.sum()
        surface = np.concatenate([rays * zf[:, None], rays * zb[:, None]])
        dist = np.linalg.norm(surface - centroid, axis=1)
        front, back = np.where(inside, front, np.nan), np.where(inside, back, np.nan)
        return ShapePrior(k, front, back, centroid, float(np.sqrt(np.mean(dist**2))), float(dist.max()))

    @staticmethod
    def inflate(mask: np.ndarray, K: np.ndarray, *, relief: float = 1.0, radius: float = 1.0) -> "ShapePrior":
        """Silhouette inflation of a frame-0 mask (H, W) bool, scaled to a given RMS radius.

        With ``d`` the distance (pixels) of a mask pixel to the background and
        ``D`` its maximum, the half-thickness is ``relief * sqrt(d (2D - d))``
        pixels, an ellipsoidal cap: for a disc of radius ``D`` it is
        ``sqrt(D² - r²)``, a sphere when ``relief = 1``. At mid-depth ``z0``
        a pixel spans ``z0 / f`` units, so ``front, back = z0 (1 ∓ h / f)``;
        ``z0`` is set so that the volume's RMS radius equals ``radius`` (the
        monocular scale is unknowable; this fixes it).
        """
        mask = np.asarray(mask, dtype=bool)
        k = np.asarray(K, dtype=np.float64)
        d = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5).astype(np.float64)
        h = relief * np.sqrt(d * (2 * d.max() - d)) / np.sqrt(k[0, 0] * k[1, 1])
        # Keep the front in front of the camera even for huge masks or relief.
        h = np.minimum(h, 0.9)
        unit = ShapePrior.from_depths(np.where(mask, 1 - h, np.nan), np.where(mask, 1 + h, np.nan), k)
        z0 = radius / unit.radius
        return ShapePrior.from_depths(unit.front * z0, unit.back * z0, k)

    def raycast(self, uv: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Lift pixels of a frame where the body has moved by ``pose`` onto its surface.

        Parameters
        ----------
        uv : (N, 2) pixels at that frame.
        pose : (4, 4) body pose at that frame (frame 0 → that frame).

        Returns
        -------
        (N, 3) float64
            The first point where each pixel's ray enters the moved volume,
            in body (frame-0 camera) coordinates; NaN where the ray misses.
        """
        n = len(uv)
        inv = invert_transform(pose)
        centre = transform_points(pose, self.centroid[None])[0]
        near = max(centre[2] - 1.05 * self.extent, 1e-3 * self.extent)
        far = centre[2] + 1.05 * self.extent
        lam = np.linspace(near, far, _RAY_SAMPLES)  # camera depth along each ray (rays have z = 1)
        rays = _rays(self.K, np.asarray(uv, dtype=np.float64))

        def inside(depth: np.ndarray, which: np.ndarray) -> np.ndarray:
            body = transform_points(inv, rays[which] * depth[:, None])
            p = _project(self.K, body)
            return (body[:, 2] >= _bilinear(self.front, p)) & (body[:, 2] <= _bilinear(self.back, p))

        rows = np.repeat(np.arange(n), _RAY_SAMPLES)
        hits = inside(np.tile(lam, n), rows).reshape(n, _RAY_SAMPLES)
        found = hits.any(axis=1)
        first = hits.argmax(axis=1)
        # Bisect between the last sample outside and the first inside.
        lo = np.where(first > 0, lam[np.maximum(first - 1, 0)], lam[0])[found]
        hi = lam[first][found]
        idx = np.nonzero(found)[0]
        for _ in range(_RAY_BISECTIONS):
            mid = 0.5 * (lo + hi)
            ins = inside(mid, idx)
            hi, lo = np.where(ins, mid, hi), np.where(ins, lo, mid)
        out = np.full((n, 3), np.nan)
        out[idx] = transform_points(inv, rays[idx] * hi[:, None])
        return out


def carved_centroid(shape: ShapePrior, masks: np.ndarray, poses: np.ndarray, frames: np.ndarray, *,
                    points: np.ndarray | None = None, tolerance: int = 2, agreement: float = 0.95,
                    depth_samples: int = 32, max_rays: int = 8000) -> np.ndarray:
    """Centroid of the prior volume carved by the silhouettes of the other frames (visual hull).

    The inflated prior guesses the hidden back of the body. Once the body has
    turned, the masks of later frames say where it is not (Laurentini, "The
    visual hull concept", PAMI 1994): samples of the volume (up to
    ``max_rays`` frame-0 pixel rays, ``depth_samples`` per ray) are kept when
    they project inside the mask (dilated by ``tolerance`` pixels) at no
    fewer than ``agreement`` of ``frames``, and their volume-weighted mean
    (``z² dz`` per sample, the frustum element) is the centroid. Without
    out-of-plane motion nothing is carved and this is the prior's centroid.

    The guess can also be too shallow (a car seen from the front is longer
    than it is wide) or start behind the true front (a box's corner pointing
    at the camera). Triangulated body points (``points``, e.g. the
    :attr:`RigidFit.triangulated` ones of :attr:`RigidFit.points`) show how
    far the body really reaches: every ray is then sampled over at least
    their depth range (2nd to 98th percentile), and the silhouettes carve
    that too.

    Parameters
    ----------
    shape : ShapePrior
    masks : (T, H, W) bool
    poses : (T, 4, 4) body poses, frame 0 → t
    frames : (F,) int
        Frames whose pose is trusted.
    points : (N, 3) float, optional
        Body points whose depth was measured, camera-frame-0 coordinates.

    Returns
    -------
    (3,) float64, in camera-frame-0 coordinates; the prior's centroid if carving removes everything.
    """
    v, u = np.nonzero(np.isfinite(shape.front))
    stride = max(1, int(np.ceil(np.sqrt(len(v) / max_rays))))
    keep = (v % stride == 0) & (u % stride == 0)
    v, u = v[keep], u[keep]
    front, back = shape.front[v, u], shape.back[v, u]
    if points is not None and len(points):
        near, far = np.percentile(points[:, 2], [2, 98])
        front, back = np.minimum(front, near), np.maximum(back, far)
    frac = (np.arange(depth_samples) + 0.5) / depth_samples
    z = front[:, None] + (back - front)[:, None] * frac[None]  # (R, L)
    samples = (_rays(shape.K, np.column_stack([u, v]).astype(np.float64))[:, None] * z[..., None]).reshape(-1, 3)
    weight = (z**2 * (back - front)[:, None]).ravel()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tolerance + 1,) * 2)
    h, w = masks.shape[1:]
    votes = np.zeros(len(samples))
    for t in frames:
        wide = cv2.dilate(masks[t].astype(np.uint8), kernel).astype(bool)
        cam = transform_points(poses[t], samples)
        pix = np.rint(_project(shape.K, cam)).astype(np.int64)
        inside = (cam[:, 2] > 0) & (pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
        inside[inside] = wide[pix[inside, 1], pix[inside, 0]]
        votes += inside
    kept = votes >= agreement * len(frames)
    if not kept.any():
        return shape.centroid.copy()
    return (weight[kept] @ samples[kept]) / weight[kept].sum()


@dataclass(frozen=True)
class RigidOptions:
    """Settings of :func:`fit_rigid`.

    Attributes
    ----------
    ransac_threshold : float
        PnP inlier threshold, pixels of reprojection error.
    ransac_iterations : int
        RANSAC iterations per frame.
    min_points : int
        Fewest lifted tracks (and PnP inliers) for a frame's pose; below it
        the frame is reported as failed and interpolated. 6 is the minimum of
        the linear (DLT) PnP solution.
    refine : bool
        Run the joint refinement (bundle adjustment); off, the poses are the
        sequential PnP's.
    refine_every : int
        Also refine all frames so far every this many frames during the
        sequential pass (0: only at the end), so that errors of the guessed
        shape are corrected before they steer the next poses.
    refine_window : int
        The refinements during the sequential pass move only the last this
        many frames' poses, the earlier ones held with their tracks (0: all
        frames): a long clip's refinements cost what a short one's do. The
        final refinement moves every frame.
    refine_tracks : int
        About this many tracks, drawn at random (plus the longest ones where
        a frame has fewer than 30), enter the refinement; a few hundred
        constrain 6-DoF poses well and keep it to about a second. Strict
        tracks count by chain (all the pieces of one surface's track).
    refine_loss_scale : float
        Huber loss scale in pixels: residuals above it count linearly.
    prune_threshold : float
        After a first refinement, each track is cut from the first frame where
        its reprojection error exceeds this many pixels, or 4 σ of the
        residuals if that is larger (LK tracks drift rather than jump, so what
        follows is suspect too), and the refinement runs again. 0 disables it.
    weak_fraction : float
        A PnP pose with fewer inliers than this fraction of the median of the
        last 8 tracked frames' counts is weak (a blurred frame where few tracks
        survive): with ``recover``, it is replaced by an alignment.
    depth_prior_weight : float
        A point whose depth moves by one radius away from its value before the
        refinement costs as much as this many pixels of reprojection error in
        one frame. Weak on purpose: it only decides what the tracks cannot;
        at 1 it already biases in-plane rotations by ~0.2°.
    min_piece_frames : int
        A piece of a strict track that starts where the one before it was cut
        and lasts fewer frames is brief: it sits where windows keep failing to
        match (a crease under changing shading, an occluding edge), and it lags
        the motion by a few hundredths of a pixel a step. Where the refinement's
        median reprojection error shows tracks that close (below 0.25 px), brief
        pieces are left out of its second pass at the frames 30 other tracks
        see: over a turn their lags add up to a tilt
        (``docs/benchmarks/extract.md``). Noisier tracks keep them, where their
        number counts. 0: always kept.
    seed : int
        Seed of the refinement's track sample.
    """

    ransac_threshold: float = 2.0
    ransac_iterations: int = 200
    min_points: int = 6
    refine: bool = True
    refine_every: int = 8
    refine_window: int = 200
    refine_tracks: int = 400
    refine_loss_scale: float = 1.0
    prune_threshold: float = 1.0
    weak_fraction: float = 0.25
    depth_prior_weight: float = 0.1
    min_piece_frames: int = 12
    seed: int = 0


@dataclass(frozen=True)
class RigidFit:
    """Poses of one rigid body over T frames, from M tracks.

    Attributes
    ----------
    poses : (T, 4, 4) float64
        Frame 0 → frame t, in camera-frame-0 coordinates; ``poses[0]`` is identity.
    points : (M, 3) float64
        Each track's point on the body at frame 0; NaN for tracks never lifted.
    inliers : (T, M) bool
        Observations within ``ransac_threshold`` pixels of their reprojection.
    triangulated : (M,) bool
        Points whose depth the tracks measure: their viewing direction turned
        by at least 2° over their inlier observations. The others keep about
        the depth they were lifted at.
    failed_frames : dict[int, str]
        Frames whose pose was interpolated, with the reason.
    recovered_frames : dict[int, str]
        Frames the tracks lost, or kept too few of for a sound pose, whose
        pose ``recover`` found instead, with why and how.
    retried_frames : dict[int, str]
        Frames PnP lost in the sequential pass that it placed when tried again
        after the refinement, with why it lost them (their poses are then
        refined like any other's).
    reprojection_rms : float
        RMS reprojection error of the inliers, pixels.
    timings : dict[str, float]
        Seconds spent in ``"pose"`` (sequential PnP) and ``"refine"``.
    """

    poses: np.ndarray
    points: np.ndarray
    inliers: np.ndarray
    triangulated: np.ndarray
    failed_frames: dict[int, str] = field(default_factory=dict)
    recovered_frames: dict[int, str] = field(default_factory=dict)
    retried_frames: dict[int, str] = field(default_factory=dict)
    reprojection_rms: float = float("nan")
    timings: dict[str, float] = field(default_factory=dict)


#: Point-frames per chunk of :func:`_reprojection_errors`.
_ERROR_CHUNK = 1 << 20
#: Points per call of :func:`_refine_points` for the points left out of a refinement: all of them at once, a
#: long clip's observations took several hundred megabytes of temporaries.
_POINT_CHUNK = 2048
#: What a frame's PnP starts from, the lifted points (N, 3) and the guessed pose, is rounded to this grid
#: (the shape prior's units, its RMS radius 1; radians): RANSAC keeps its best random sample, and where two
#: poses have about the same support (a fast, blurred frame) which one wins follows the last bits of its input
#: (:mod:`~marionette.reproducible`). Their rounding noise is about 1e-12.
_PNP_STEP = 2.0 ** -16
#: A fitted point farther than this many shape radii from the body's centre is dropped, with its track.
_MAX_REACH = 10.0
#: A recovered pose is rounded to this coarser grid (at most 0.1°, against the alignment's own error of 0.5-4°):
#: the alignment renders in float32, whose last bits follow the CPU, and stops after a fixed number of steps
#: (docs/benchmarks/reproducibility_real.md).
_RECOVERED_STEP = 2.0 ** -9


def _pnp(points: np.ndarray, uv: np.ndarray, k: np.ndarray, guess: np.ndarray,
         options: RigidOptions) -> tuple[np.ndarray | None, np.ndarray, str]:
    """RANSAC PnP from a guessed pose (4, 4), then LM on the inliers; points (N, 3) and guess rounded first.

    Returns (pose or None, inlier mask (N,), reason for a failure).
    """
    points, guess = snap(points, _PNP_STEP), snap_pose(guess, _PNP_STEP)
    rvec = cv2.Rodrigues(guess[:3, :3])[0]
    tvec = guess[:3, 3:].copy()
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        points, uv.astype(np.float64), k, None, rvec, tvec, useExtrinsicGuess=True,
        iterationsCount=options.ransac_iterations, reprojectionError=options.ransac_threshold,
        confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
    count = 0 if inl is None else len(inl)
    if not ok or count < options.min_points:
        return None, np.zeros(len(points), bool), f"PnP RANSAC found {count} inliers, need {options.min_points}"
    inl = inl[:, 0]
    rvec, tvec = cv2.solvePnPRefineLM(points[inl], uv[inl].astype(np.float64), k, None, rvec, tvec)
    pose = make_transform(cv2.Rodrigues(rvec)[0], tvec[:, 0])
    cam = transform_points(pose, points)
    err = np.linalg.norm(_project(k, cam) - uv, axis=1)
    inliers = (cam[:, 2] > 0) & (err <= options.ransac_threshold)
    if inliers.sum() < options.min_points:
        return None, inliers, f"PnP refinement kept {inliers.sum()} inliers, need {options.min_points}"
    return pose, inliers, ""


def _lift_by_neighbours(uv: np.ndarray, known_uv: np.ndarray, known_depth: np.ndarray, pose: np.ndarray,
                        k: np.ndarray) -> np.ndarray:
    """Back-project pixels (N, 2) at the median depth of the 4 nearest known pixels → body points (N, 3)."""
    nearest = cKDTree(known_uv).query(uv, k=min(4, len(known_uv)))[1].reshape(len(uv), -1)
    depth = np.median(known_depth[nearest], axis=1)
    return transform_points(invert_transform(pose), _rays(k, uv) * depth[:, None])


def _extrapolate(poses: np.ndarray, good: list[int], t: int) -> np.ndarray:
    """Pose (4, 4) at frame t from the last two good frames' poses at constant velocity (held with one)."""
    if len(good) < 2:
        return poses[good[-1]].copy()
    a, b = good[-2], good[-1]
    return se3_interpolate(poses[a], poses[b], (t - a) / (b - a))


def _fill_failed(poses: np.ndarray, failed: dict[int, str]) -> np.ndarray:
    """Interpolate failed frames' poses (T, 4, 4) in SE(3) between good neighbours; hold after the last."""
    good = np.array([t for t in range(len(poses)) if t not in failed])
    out = poses.copy()
    for t in failed:
        before = good[good < t].max()
        after = good[good > t]
        if len(after):
            out[t] = se3_interpolate(poses[before], poses[after[0]], (t - before) / (after[0] - before))
        else:
            out[t] = poses[before]
    return out


def _huber_weights(norms: np.ndarray, scale: float) -> tuple[np.ndarray, float]:
    """IRLS weights (O,) of the Huber loss on residual norms (O,), and the total Huber cost."""
    big = norms > scale
    cost = np.where(big, 2 * scale * norms - scale**2, norms**2).sum()
    return np.where(big, scale / np.maximum(norms, 1e-300), 1.0), float(cost)


def _bundle_adjust(observed: np.ndarray, uv: np.ndarray, k: np.ndarray, poses: np.ndarray, points: np.ndarray,
                   directions: np.ndarray, free: np.ndarray, radius: float, options: RigidOptions,
                   iterations: int = 30, held: np.ndarray | None = None,
                   prior_share: np.ndarray | float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Jointly refine the poses of frames ``free`` (F,) and N points (N, 3) observed at ``uv`` (T, N, 2).

    :func:`~marionette.source.bundle.bundle_adjust` with the options' Huber
    scale (``refine_loss_scale``) and the depth prior
    ``depth_prior_weight * n·(X - X_lift) / radius`` per point, ``n`` (N, 3)
    the point's unit lifting ray in body coordinates, times ``prior_share``
    (N,) (each piece of a strict track its share, so that a chain weighs as
    one track); frame 0 and the frames ``held`` keep their poses,
    ``iterations`` bounds the cost evaluations.
    Returns refined poses (T, 4, 4) (other frames unchanged) and points (N, 3).
    """
    return bundle_adjust(observed, uv, k, poses, points, directions, free,
                         options.depth_prior_weight / radius * prior_share,
                         options.refine_loss_scale, iterations, held)


def _choose_tracks(visible: np.ndarray, count: int, seed: int, ids: np.ndarray, chains: np.ndarray,
                   per_frame: int = 30) -> np.ndarray:
    """Pick the tracks ``ids`` (M,) with visibility (T, M) of about ``count`` chains for the bundle adjustment.

    A random sample of the chains ``chains`` (M,) (:meth:`Tracks.chains`: strict
    tracks cut into pieces come back whole, so the sample holds as many
    observations as one of long tracks), topped up with the longest remaining
    tracks at frames where it has fewer than ``per_frame`` (or all there are):
    those carry the poses across occlusions and turns, where few tracks live.
    Returns sorted ids.
    """
    rng = np.random.default_rng(seed)
    groups, member = np.unique(chains, return_inverse=True)
    drawn = np.zeros(len(groups), bool)
    drawn[rng.choice(len(groups), min(count, len(groups)), replace=False)] = True
    pick = drawn[member]
    length = visible.sum(axis=0)
    for t in range(len(visible)):
        need = min(per_frame, visible[t].sum()) - (visible[t] & pick).sum()
        if need > 0:
            spare = np.nonzero(visible[t] & ~pick)[0]
            pick[spare[np.argsort(-length[spare], kind="stable")[:need]]] = True
    return ids[pick]


def _refine_points(observed: np.ndarray, uv: np.ndarray, k: np.ndarray, poses: np.ndarray, points: np.ndarray,
                   loss_scale: float, iterations: int = 5) -> np.ndarray:
    """Gauss–Newton on each point (N, 3) alone, poses (T, 4, 4) fixed, Huber-weighted; observed (T, N), uv (T, N, 2)."""
    obs_t, obs_i = np.nonzero(observed)
    fxy = np.array([k[0, 0], k[1, 1]])
    pts = points.copy()
    for _ in range(iterations):
        cam = np.einsum("oij,oj->oi", poses[obs_t, :3, :3], pts[obs_i]) + poses[obs_t, :3, 3]
        z = cam[:, 2]
        err = _project(k, cam) - uv[obs_t, obs_i]
        weights, _ = _huber_weights(np.linalg.norm(err, axis=1), loss_scale)
        j_proj = np.zeros((len(z), 2, 3))
        j_proj[:, 0, 0], j_proj[:, 1, 1] = fxy[0] / z, fxy[1] / z
        j_proj[:, :, 2] = -fxy * cam[:, :2] / z[:, None] ** 2
        j = j_proj @ poses[obs_t, :3, :3]  # (O, 2, 3)
        c = np.zeros((len(pts), 3, 3))
        h = np.zeros((len(pts), 3))
        np.add.at(c, obs_i, weights[:, None, None] * np.einsum("oki,okj->oij", j, j))
        np.add.at(h, obs_i, weights[:, None] * np.einsum("oki,ok->oi", j, err))
        # A point seen from one direction only is known along its ray only as well as its lift: damp.
        c += 1e-6 * np.trace(c, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 1e-12 * np.eye(3)
        pts -= np.linalg.solve(c, h[..., None])[..., 0]
    return pts


def _rescale(poses: np.ndarray, points: np.ndarray, anchors: np.ndarray, depths: np.ndarray) -> None:
    """Fix the scale gauge in place: the median depth of the anchor points (A,) returns to ``depths`` (A,).

    Scaling all points (N, 3) and the translations of all poses (T, 4, 4) by
    one factor leaves every reprojection as it is: within the bundle
    adjustment only the weak depth prior holds the scale, and tracks lifted
    after frame 0 onto a wrong guess of the hidden shape pull it as much as
    the frame-0 ones (on a car turning from a front to a side view, by 20 %).
    The prior's scale is defined at frame 0, so it is restored from the
    frame-0 tracks, by the median ratio (robust to the odd track that
    another part or a reflection carries to any depth).
    """
    scale = float(np.median(depths / points[anchors, 2])) if len(anchors) else np.nan
    if np.isfinite(scale) and scale > 0:
        points *= scale
        poses[:, :3, 3] *= scale


def _triangulated(poses: np.ndarray, points: np.ndarray, inliers: np.ndarray) -> np.ndarray:
    """Points (N, 3) whose viewing directions at their first and last inlier frame (inliers (T, N)) differ enough."""
    seen = inliers.any(axis=0)
    first = inliers.argmax(axis=0)
    last = len(inliers) - 1 - inliers[::-1].argmax(axis=0)
    # Camera centres in body coordinates: -Rᵀ t.
    centres = -np.einsum("tji,tj->ti", poses[:, :3, :3], poses[:, :3, 3])
    a, b = points - centres[first], points - centres[last]
    with np.errstate(invalid="ignore"):
        cos = np.einsum("ni,ni->n", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return seen & (cos < np.cos(np.radians(_MIN_TRIANGULATION_DEG)))


def _chain_errors(observed: np.ndarray, uv: np.ndarray, k: np.ndarray, poses: np.ndarray, points: np.ndarray,
                  chains: np.ndarray, loss_scale: float) -> np.ndarray:
    """Pixel distances (T, N) as :func:`_reprojection_errors`, a piece of a strict track scored by one point
    fitted to all the pieces of its chain ``chains`` (N,): a short piece on a part that moves otherwise (a lid on
    the body) fits any motion over its few frames with a point of its own, its chain does not. observed (T, N),
    uv (T, N, 2), points (N, 3)."""
    err = _reprojection_errors(k, poses, points, uv)
    groups, member, counts = np.unique(chains, return_inverse=True, return_counts=True)
    pieced = counts[member] > 1
    if not pieced.any():
        return err
    frame, piece = np.nonzero(observed & pieced[None])  # the chains' observations, one column per chain
    joined_seen = np.zeros((len(observed), len(groups)), bool)
    joined_uv = np.full((len(observed), len(groups), 2), np.nan)
    joined_seen[frame, member[piece]] = True
    joined_uv[frame, member[piece]] = uv[frame, piece]
    first = np.unique(member, return_index=True)[1]  # each chain's first piece: its point starts the fit
    joined = _refine_points(joined_seen, joined_uv, k, poses, points[first], loss_scale)
    err[:, pieced] = _reprojection_errors(k, poses, joined, joined_uv)[:, member[pieced]]
    return err


def _reprojection_errors(k: np.ndarray, poses: np.ndarray, points: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Pixel distances (T, N) between points (N, 3) moved by poses (T, 4, 4) and observations uv (T, N, 2).

    Infinite where a point is unknown (NaN), behind the camera or unobserved. Computed a few frames at a time:
    a long clip's (T, N, 3) camera points would take gigabytes.
    """
    err = np.empty(uv.shape[:2])
    step = max(1, _ERROR_CHUNK // max(len(points), 1))
    for a in range(0, len(poses), step):
        cam = np.einsum("tij,nj->tni", poses[a:a + step, :3, :3], points) + poses[a:a + step, None, :3, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            dist = np.linalg.norm(cam[..., :2] / cam[..., 2:] * [k[0, 0], k[1, 1]] + [k[0, 2], k[1, 2]]
                                  - uv[a:a + step], axis=2)
        err[a:a + step] = np.where(np.isfinite(dist) & (cam[..., 2] > 0), dist, np.inf)
    return err


#: ``recover(t, source, source_pose, guess, uv, depth, replace)`` → (pose or None, note): frame t's pose (4, 4)
#: found without tracks, from the known pose (4, 4) of frame ``source``, a guess (4, 4), and the fitted points
#: seen in frame ``source``: their pixels (n, 2) and camera depths (n,) there; ``replace``: the guess is a weak
#: measured pose, to be replaced only by a clearly better one (see :mod:`.recover`).
Recover = Callable[[int, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool], tuple["np.ndarray | None", str]]


#: How the note of a frame in ``RigidFit.retried_frames`` (and the metadata's ``recovered_frames``) begins.
RETRIED_NOTE = "posed by PnP after the refinement"

#: Median reprojection error (pixels) of the first refinement below which brief pieces of strict tracks are left
#: out of the second (see ``RigidOptions.min_piece_frames``): clean footage gives 0.01-0.1 px, noisy tracks ~1 px.
_PRECISE_PX = 0.25
#: ... at frames that this many other tracks in the refinement see.
_COVERED_FRAME = 30


def fit_rigid(tracks: Tracks, shape: ShapePrior, *, options: RigidOptions = RigidOptions(),
              progress: Callable[[int, int], None] | None = None, recover: Recover | None = None) -> RigidFit:
    """Estimate the per-frame pose of one rigid body from its tracks (see the module docstring).

    Parameters
    ----------
    tracks : Tracks
        T frames, M tracks, all on the body.
    shape : ShapePrior
        The body's frame-0 volume (its scale fixes the poses' translation scale).
    options : RigidOptions
    progress : callable(done, total), optional
        Called after each frame with ``total = T`` (the last step is the refinement).
    recover : callable, optional
        Finds the pose of a frame the tracks lost, or whose PnP pose is weak
        (see ``Recover`` and ``RigidOptions.weak_fraction``), from the last
        strong frame: tried forward in time as the frame comes (so that the
        tracks born there are lifted with the right pose), then backward from
        the next strong frame for the frames it left failed. A recovered pose
        is held in the refinement; the frames still failed are interpolated.

    Returns
    -------
    RigidFit
    """
    k = shape.K
    num_frames, num_tracks = tracks.visible.shape
    uv = tracks.uv  # (T, M, 2) float32, cast where used: a long clip's tracks in float64 are half a gigabyte
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    points = np.full((num_tracks, 3), np.nan)
    directions = np.full((num_tracks, 3), np.nan)  # unit lifting ray of each point, body coordinates
    inliers = np.zeros((num_frames, num_tracks), bool)
    failed: dict[int, str] = {}
    recovered: dict[int, str] = {}
    retried: dict[int, str] = {}
    t_start = time.perf_counter()
    chains = tracks.chains()  # (M,)
    # (M,) pieces of strict tracks that start at a cut and end within min_piece_frames
    brief = (tracks.continues >= 0) & (tracks.visible.sum(axis=0) < options.min_piece_frames)
    birth = np.full((num_tracks, 3), np.nan)  # (M, 3) where each track's chain was lifted, body coordinates
    dropped = np.zeros(num_tracks, bool)  # (M,) tracks whose fitted point went far from the body
    t_recover = 0.0

    def recover_pose(t: int, source: int, guess: np.ndarray, replace: bool = False) -> tuple[np.ndarray | None, str]:
        """Frame t's pose (4, 4) aligned from frame ``source`` (a strong one) or None, and a note; ``replace``:
        the guess is a (weak) measured pose."""
        nonlocal t_recover
        t0 = time.perf_counter()
        # The fitted points seen in the source frame, where they reproject well: its model's relief.
        seen = np.nonzero(tracks.visible[source] & np.isfinite(points[:, 0]))[0]
        err = _reprojection_errors(k, poses[source][None], points[seen], uv[source, seen][None])[0]
        seen = seen[err <= 2 * options.ransac_threshold]
        aligned, note = recover(t, source, poses[source], guess, uv[source, seen].astype(np.float64),
                                transform_points(poses[source], points[seen])[:, 2], replace)
        t_recover += time.perf_counter() - t0
        return (None if aligned is None else snap_pose(aligned, _RECOVERED_STEP)), note

    def lift(t: int, pose: np.ndarray) -> None:
        new = np.nonzero(tracks.visible[t] & np.isnan(points[:, 0]) & ~dropped)[0]
        # A piece of a strict track starts where the one it carries on from was: the same surface point up to
        # the cuts' small step errors, so it starts from the point its chain was lifted to (a piece on a part
        # that moves otherwise stays an outlier to the pose, as a long track would) instead of a fresh lift under
        # this frame's pose. The lift, not a fitted point: a short piece places its point poorly along the ray.
        before = tracks.continues[new]
        inherit = before >= 0
        inherit[inherit] = np.isfinite(birth[before[inherit], 0])
        pieces, before = new[inherit], before[inherit]
        birth[pieces] = birth[before]
        points[pieces], directions[pieces] = birth[pieces], directions[before]
        new = new[~inherit]
        if not len(new):
            return
        lifted = shape.raycast(uv[t, new], pose)
        miss = np.isnan(lifted[:, 0])
        known = np.nonzero(inliers[t])[0]
        if miss.any() and len(known):
            # Mask pixels outside the moved prior volume: take nearby tracks' depth.
            depth = transform_points(pose, points[known])[:, 2]
            lifted[miss] = _lift_by_neighbours(uv[t, new[miss]].astype(np.float64), uv[t, known].astype(np.float64),
                                               depth, pose, k)
        points[new] = lifted
        birth[new] = lifted
        centre = invert_transform(pose)[:3, 3]
        ray = lifted - centre
        directions[new] = ray / np.linalg.norm(ray, axis=1, keepdims=True)

    def refine(upto: int, final: bool) -> None:
        """Bundle-adjust frames 0..upto, then fit the other lifted points to the new poses."""
        nonlocal refined_upto
        refined_upto = upto
        known = np.arange(num_frames) <= upto
        known[list(failed)] = False
        # A recovered pose is held: few tracks see its frame, but those born there tie the frames after a
        # gap in the tracks to the frames before it.
        held = np.array([t for t in recovered if t <= upto], np.int64)
        # During the sequential pass a long clip's older frames are held too (a local bundle adjustment): what
        # steers the next poses is the last frames' shape, and the cost stays bounded instead of growing with
        # the frames squared (cubed, solved dense).
        first = 0 if final or not options.refine_window else max(0, upto + 1 - options.refine_window)
        held = np.union1d(held, np.nonzero(known[:first])[0])
        free = np.setdiff1d(np.nonzero(known)[0][1:], held)
        seen = tracks.visible & known[:, None]
        lifted = np.isfinite(points[:, 0]) & (seen.sum(axis=0) >= 2)
        lifted = np.nonzero(lifted & seen[first:].any(axis=0) if first else lifted)[0]
        if not len(free) or len(lifted) < options.min_points:
            return
        chosen = _choose_tracks(seen[first:, lifted], options.refine_tracks, options.seed, lifted, chains[lifted])
        observed = seen[:, chosen]
        iterations = 30 if final else 10
        _, piece_of, pieces = np.unique(chains[chosen], return_inverse=True, return_counts=True)
        share = 1.0 / np.sqrt(pieces[piece_of])  # (N,) a chain's pieces share one track's depth prior
        poses[:], points[chosen] = _bundle_adjust(observed, uv[:, chosen], k, poses, points[chosen],
                                                  directions[chosen], free, shape.radius, options, iterations, held,
                                                  share)
        # Pieces of strict tracks are checked at every refinement: a short piece on a part that moves otherwise
        # fits any motion over its few frames, and only its chain shows it (long tracks are checked at the end).
        if options.prune_threshold > 0 and (final or (pieces > 1).any()):
            # Tracks drift rather than jump: drop each one from its first frame past the gate on.
            err = _chain_errors(observed, uv[:, chosen], k, poses, points[chosen], chains[chosen],
                                options.refine_loss_scale)
            # 3.4 median residuals is 4 σ for Gaussian pixel noise (Rayleigh norms).
            spread = float(np.median(err[observed]))
            gate = max(options.prune_threshold, 3.4 * spread)
            observed &= np.cumsum(observed & (err > gate), axis=0) == 0
            if spread < _PRECISE_PX:
                # Tracks this close: a brief piece's lag (its window fails to match where it sits) outweighs what
                # its few observations add, at the frames enough other tracks see.
                short = brief[chosen]  # (N,)
                covered = (observed & ~short).sum(axis=1) >= _COVERED_FRAME  # (T,)
                observed &= ~(short[None] & covered[:, None])
            poses[:], points[chosen] = _bundle_adjust(observed, uv[:, chosen], k, poses, points[chosen],
                                                      directions[chosen], free, shape.radius, options,
                                                      iterations, held, share)
        rest = np.setdiff1d(lifted, chosen)
        for at in range(0, len(rest), _POINT_CHUNK):  # each point is fitted alone: chunks change nothing
            few = rest[at:at + _POINT_CHUNK]
            points[few] = _refine_points(seen[:, few], uv[:, few], k, poses, points[few], options.refine_loss_scale)
        # A point sent far from the body is not on it: its track's rays were nearly parallel, or it follows
        # another body, and its place is noise. Its track is left out from here on: lifted again, a lid's
        # track fitted with its box pulls the box's poses (docs/benchmarks/reproducibility_real.md).
        far = np.linalg.norm(points[lifted] - shape.centroid, axis=1) > _MAX_REACH * shape.radius
        points[lifted[far]], dropped[lifted[far]] = np.nan, True
        # What the next frames start from, rounded as PnP's inputs are (_PNP_STEP).
        poses[:upto + 1], points[lifted] = snap_pose(poses[:upto + 1], _PNP_STEP), snap(points[lifted], _PNP_STEP)

    def retry_failed() -> bool:
        """PnP once more at the failed frames, in order, from the refined points and poses; True if any
        frame got a pose. The sequential pass can fail at a frame because the frames before it were posed
        poorly (few inliers each, and the constant-velocity guess from them hundreds of pixels off: the
        backpack clip's end); the refinement corrects those, and the tracks that reach the failed frame from
        them place it. Not the tracks first seen at a failed frame: lifted with its guessed pose, they would
        only give that guess back; once the frame is placed they are lifted again with its pose."""
        posed = np.array([t not in failed for t in range(num_frames)])
        found = False
        for t in sorted(failed):
            usable = np.nonzero(tracks.visible[t] & np.isfinite(points[:, 0]) & posed[tracks.start])[0]
            if len(usable) < options.min_points:
                continue
            before = [u for u in range(t) if posed[u]]
            pose, inl, _ = _pnp(points[usable], uv[t, usable], k, _extrapolate(poses, before, t), options)
            if pose is None:
                continue
            guessed = tracks.visible[t] & ~posed[tracks.start]  # (M,) lifted at failed frames, this one too
            points[guessed], birth[guessed], directions[guessed] = np.nan, np.nan, np.nan
            poses[t], posed[t], found = pose, True, True
            inliers[t, usable[inl]] = True
            if inl.sum() >= options.weak_fraction * np.median(counts):
                strong.append(t)  # a source for aligning the frames still failed
            retried[t] = f"{RETRIED_NOTE} from {int(inl.sum())} PnP inliers (first: {failed.pop(t)})"
            lift(t, pose)
        strong.sort()
        return found

    lift(0, poses[0])
    inliers[0] = tracks.visible[0] & np.isfinite(points[:, 0])
    anchors = np.nonzero(inliers[0])[0]  # tracks lifted on the shape prior's frame-0 surface
    anchor_depths = points[anchors, 2].copy()
    good = [0]  # frames with a pose: tracked or recovered
    strong = [0]  # frames tracked with a usual number of PnP inliers
    counts = [int(inliers[0].sum())]  # PnP inlier counts of the tracked frames
    t_refine, refined_upto = 0.0, 0

    def settle(upto: int) -> bool:
        """Refine frames 0..upto during the sequential pass, unless that is done; True if it ran. Every
        ``refine_every`` frames, and before a recovery starts from frame ``upto``: a recovered pose is the source
        frame's times the alignment's step, and held from then on, so the source's error stays in it (between
        refinements PnP poses rest on points not yet corrected, and strict tracks' fresh pieces on their chains'
        first lifts; docs/benchmarks/recover.md)."""
        nonlocal t_refine
        if not options.refine or refined_upto >= upto:
            return False
        t0 = time.perf_counter()
        refine(upto, final=False)
        t_refine += time.perf_counter() - t0
        return True

    for t in range(1, num_frames):
        usable = np.nonzero(tracks.visible[t] & np.isfinite(points[:, 0]))[0]
        guess = pose = _extrapolate(poses, good, t)
        if len(usable) < options.min_points:
            failed[t] = f"{len(usable)} lifted tracks visible, need {options.min_points}"
        else:
            pose, inl, reason = _pnp(points[usable], uv[t, usable], k, guess, options)
            if pose is None:
                failed[t] = reason
            else:
                inliers[t, usable[inl]] = True
                good.append(t)
                count = int(inl.sum())
                weak = count < options.weak_fraction * np.median(counts[-8:])
                counts.append(count)  # weak ones too: a clip whose tracks thin out slowly is not all weak
                if not weak:
                    strong.append(t)
                elif recover is not None:
                    # A few surviving tracks (a blurred frame) give a poor pose: align the model from it.
                    settle(strong[-1])
                    aligned, note = recover_pose(t, strong[-1], pose, replace=True)
                    if aligned is not None:
                        pose, recovered[t] = aligned, f"PnP kept only {count} inliers; {note}"
        if t in failed and recover is not None:
            # From the last strong frame, not the last with a pose: a frame the tracks lost or kept few of is
            # often blurred, a poor model that the next blurred frame agrees with all the same.
            if settle(strong[-1]):
                guess = _extrapolate(poses, good, t)
            aligned, note = recover_pose(t, strong[-1], guess)
            if aligned is None:
                failed[t] += f"; {note}"
            else:
                pose, recovered[t] = aligned, f"{failed.pop(t)}; {note}"
                good.append(t)
        poses[t] = guess if t in failed else pose
        # Also at a failed frame (with the predicted pose): tracks born there
        # are what lets the next frames recover.
        lift(t, poses[t])
        if options.refine and options.refine_every and t % options.refine_every == 0 and t < num_frames - 1:
            # Incremental: the guessed shape is corrected before errors in it steer the next poses.
            settle(t)
        if progress is not None:
            progress(t, num_frames)
    t_pose, recover_forward = time.perf_counter(), t_recover
    if options.refine:
        refine(num_frames - 1, final=True)
        if failed and retry_failed():
            refine(num_frames - 1, final=True)
    if recover is not None:
        # Backward: each frame still failed from the next strong one, guessed from the two known after it.
        for t in sorted(failed, reverse=True):
            after = [u for u in range(t + 1, num_frames) if u not in failed][:2]
            source = next((u for u in range(t + 1, num_frames) if u in strong), None)
            if source is None:
                continue
            aligned, note = recover_pose(t, source, _extrapolate(poses, after[::-1], t))
            if aligned is None:
                failed[t] += f"; {note}"
            else:
                poses[t], recovered[t] = aligned, f"{failed.pop(t)}; {note}"
    _rescale(poses, points, anchors, anchor_depths)  # a no-op without refinement: PnP keeps the lifted scale
    if failed:
        poses = _fill_failed(poses, failed)
    poses[0] = np.eye(4)
    if progress is not None:
        progress(num_frames, num_frames)

    # Final inliers of every lifted track under the final poses.
    err = _reprojection_errors(k, poses, points, uv)
    inliers = tracks.visible & (err <= options.ransac_threshold)
    rms = float(np.sqrt(np.mean(err[inliers] ** 2))) if inliers.any() else float("nan")
    timings = {"pose": t_pose - t_start - t_refine - recover_forward,
               "refine": time.perf_counter() - t_pose + t_refine - (t_recover - recover_forward),
               "recover": t_recover}
    return RigidFit(poses=poses, points=points, inliers=inliers, triangulated=_triangulated(poses, points, inliers),
                    failed_frames=dict(sorted(failed.items())), recovered_frames=dict(sorted(recovered.items())),
                    retried_frames=retried, reprojection_rms=rms, timings=timings)
