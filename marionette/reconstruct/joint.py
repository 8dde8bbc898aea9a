"""The joint fit: every part's pose in every frame and the object's Gaussians optimised together.

Poses from tracks alone go wrong where the tracks die or slip (blur, smoke,
a fast turn, a hand over the object), and a model fitted under wrong poses
cannot explain the silhouettes. Here the fit of :func:`.fit.reconstruct_object`
moves the poses as well: at each step, the frame's render gives, through the
rasterizer's backward pass, the gradient of its loss with respect to a
left-multiplied twist ``[ω, v]`` of each part about its centre, and, after a
warm-up that fits the Gaussians alone, the frame's poses take an Adam step
(Kingma & Ba 2015) on

    L_t = L_image + L_silhouette                     (the fit's own, on a crop; past it, :func:`.fit._outside`)
        + λ_track mean_j ρ(π(K P_t X_j) - u_tj; s)   (the tracks' 3D points belong to the object)
        + λ_acc (‖a_t‖² + ‖b_t‖²/r²) + λ_vel (…)     (each pose's acceleration and velocity)
        + λ_start ρ(ξ(P_t, P_t⁰); c)                 (the tracked pose, where the images barely tell)

with ``ρ(x; s) = s² log(1 + |x|²/s²)`` (Cauchy), ``X_j`` each track's point
solved under the current poses (linear triangulation, once per pass over the
frames), ``a`` the second difference of the frame-to-frame rotations, ``b``
that of the part's centre (``r`` its radius) and ``ξ`` the twist from the
starting pose. Frame 0 defines the model's frame: it keeps its turn (freed, that drifts with every other
frame's error) and only its place is fitted (a far car's depth).

Tracks that slip by tens of degrees leave a frame beyond what its gradient can climb back. After each pass, a
frame whose loss is several times the median tries its neighbours' poses and keeps the one that renders it
best; frame 0 too, which is then fitted like the rest. The result is re-expressed so that frame 0's pose is
the identity again (the motion is relative to it).

A single rigid model must explain every frame: a frame whose loss stands out
bends the Gaussians less (its step on them is weighted down), the Gaussians'
sizes are capped (``max_scale``) so that wide blurs cannot cover a pose's
error, and what draws outside the object's crop is pushed transparent. The
shading's own dependence on the pose is left out of the pose gradient (as in
:mod:`.align`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..errors import InputError
from ..geometry import (axis_angle_to_matrix, invert_transform, matrix_to_axis_angle, rotation_angle_deg,
                        so3_left_jacobian)
from ..prior import CAMERA_EXTRA, SpatPrior
from ..progress import ProgressCallback
from ..render.sh import rotate_sh
from ._init import pose_gaussians
from ._views import box_size
from .fit import Reconstruction, ReconstructOptions, reconstruct_object
from .posing import per_part

#: A frame whose loss is over this many times the median is an outlier: it tries its neighbours' poses.
OUTLIER_LOSS = 3.0

__all__ = ["JointOptions", "JointFit", "PoseFit", "TrackObservations", "joint_fit", "triangulate_tracks"]


@dataclass(frozen=True)
class JointOptions:
    """Settings of :func:`joint_fit` (defaults from the perturbation study, docs/benchmarks/joint_fit.md).

    Attributes
    ----------
    visits : int
        Times each frame is fitted (``visits x T`` steps, one frame each, at most ``max_iterations``).
    max_iterations : int
    warmup : float
        Share of the steps that fit the Gaussians alone, before the poses move: a model that does not yet
        explain the frames gives their poses no direction.
    object_side : int
        Each frame is scaled so that its object's box spans about this many pixels (at most its own
        resolution): a far, small object keeps the pixels that tell its pose.
    lr_rotation : float
        Adam step of the poses' rotations in radians, decaying to a tenth.
    lr_translation : float
        Adam step of the poses' translations in object radii, decaying to a tenth.
    acceleration : float
        ``λ_acc``: weight of each pose's acceleration (rotation in radians, centre in radii, per frame²).
    velocity : float
        ``λ_vel``: weight of each pose's velocity, alike.
    anchor : float
        ``λ_start``: weight of the pull towards the starting (tracked) pose, a Cauchy loss of the twist from
        it. Frames and model can drift together along what the images barely see (a slightly slower turn
        of a slightly deeper model); this holds the tracks' answer there, while a pose that is degrees off
        leaves it: the pull fades beyond ``anchor_scale``.
    anchor_scale : float
        Scale of that Cauchy loss, in radians and object radii.
    robust_frames : bool
        Weight each frame's step on the Gaussians by ``min(1, (median loss / its loss)²)``, so that frames
        whose poses disagree with the rest do not bend the model to them.
    track_weight : float
        ``λ_track``: weight of the tracks' reprojection term (pixels²; 0: tracks unused).
    track_scale : float
        Scale of its Cauchy loss, in pixels: a track off by several times this pulls little.
    max_scale : float
        Largest standard deviation of a Gaussian, in object radii.
    shading : bool
        Fit the shading as the reconstruction does.
    seed : int
    """

    visits: int = 50
    max_iterations: int = 4000
    warmup: float = 0.3
    object_side: int = 200
    lr_rotation: float = 0.015
    lr_translation: float = 0.015
    acceleration: float = 0.02
    velocity: float = 0.0
    anchor: float = 10.0
    anchor_scale: float = 0.005
    robust_frames: bool = True
    track_weight: float = 0.002
    track_scale: float = 2.0
    max_scale: float = 0.3
    shading: bool = True
    seed: int = 0

    def check(self) -> None:
        """Raise :class:`InputError` naming the first setting out of range."""
        for name in ("visits", "max_iterations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 1_000_000:
                raise InputError(f"joint fit {name} must be an integer in 1..1000000, got {value!r}")
        if not 16 <= self.object_side <= 8192:
            raise InputError(f"joint fit object_side must be within 16..8192, got {self.object_side}")
        if not 0 <= self.warmup < 1:
            raise InputError(f"joint fit warmup must be within [0, 1), got {self.warmup}")
        if min(self.lr_rotation, self.lr_translation, self.acceleration, self.velocity, self.anchor,
               self.track_weight) < 0 or not min(self.track_scale, self.max_scale, self.anchor_scale) > 0:
            raise InputError("joint fit steps and weights must be >= 0; track_scale, anchor_scale and max_scale > 0")

    def reconstruction(self, num_frames: int) -> ReconstructOptions:
        """The Gaussians' side of the fit, for a clip of ``num_frames`` frames to fit."""
        return ReconstructOptions(iterations=min(self.visits * num_frames, self.max_iterations),
                                  object_side=self.object_side, max_scale=self.max_scale, shading=self.shading,
                                  seed=self.seed)


@dataclass(frozen=True)
class TrackObservations:
    """Point tracks of the object, each on one part.

    Attributes
    ----------
    uv : (T, M, 2) float, pixel positions at the prior's resolution.
    visible : (T, M) bool
    parts : (M,) int, each track's part (-1: none).
    """

    uv: np.ndarray
    visible: np.ndarray
    parts: np.ndarray

    @staticmethod
    def of_prior(prior: SpatPrior) -> "TrackObservations | None":
        """The tracks an extraction stored in the prior's extras, or None."""
        e = prior.extras
        if not {"tracks_uv", "tracks_visible", "track_labels"} <= set(e):
            return None
        return TrackObservations(np.asarray(e["tracks_uv"], np.float64), np.asarray(e["tracks_visible"], bool),
                                 np.asarray(e["track_labels"], np.int64))


def triangulate_tracks(poses: np.ndarray, uv: np.ndarray, visible: np.ndarray, K: np.ndarray,
                       min_views: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Each track's point in the model's frame under one part's poses, by linear triangulation.

    Parameters
    ----------
    poses : (T, 4, 4) model → camera of frame t.
    uv : (T, M, 2) pixels; visible : (T, M) bool; K : (3, 3).
    min_views : tracks seen in fewer frames get no point.

    Returns
    -------
    points : (M, 3) float64; ok : (M,) bool, solved and in front of the camera where seen.
    """
    uv = np.where(visible[..., None], uv, 0.0)  # an unseen frame's position may be NaN
    rays = np.concatenate([uv, np.ones(uv.shape[:2] + (1,))], axis=2) @ np.linalg.inv(K).T  # (T, M, 3)
    proj = poses[:, :3, :]  # (T, 3, 4)
    # Rows x·P3 - P1 and y·P3 - P2 of the homogeneous system, for every (frame, track).
    rows = np.stack([rays[..., 0:1] * proj[:, None, 2] - proj[:, None, 0],
                     rays[..., 1:2] * proj[:, None, 2] - proj[:, None, 1]], axis=2)  # (T, M, 2, 4)
    rows = rows * visible[..., None, None]
    normal = np.einsum("tmri,tmrj->mij", rows, rows)  # (M, 4, 4)
    _, vectors = np.linalg.eigh(normal)
    h = vectors[:, :, 0]  # the smallest eigenvalue's
    ok = (visible.sum(axis=0) >= min_views) & (np.abs(h[:, 3]) > 1e-12)
    points = h[:, :3] / np.where(ok, h[:, 3], 1.0)[:, None]
    depth = np.einsum("tij,mj->tmi", poses[:, :3, :3], points)[..., 2] + poses[:, None, 2, 3]  # (T, M)
    ok &= np.all((depth > 0) | ~visible, axis=0)
    return points, ok


class PoseFit:
    """The poses' side of the joint fit: per-frame Adam steps on left twists, with the priors' gradients.

    Parameters
    ----------
    poses : (K, T, 4, 4) model (frame 0) → camera of frame t, as filmed.
    centres : (K, 3) each part's centre in the model's frame.
    radius : object radius (translation unit).
    K : (3, 3) intrinsics of the frames.
    options : JointOptions
    tracks : TrackObservations, optional
    """

    def __init__(self, poses: np.ndarray, centres: np.ndarray, radius: float, K: np.ndarray,
                 options: JointOptions, tracks: TrackObservations | None = None):
        self.poses = np.array(poses, dtype=np.float64)
        self.start = self.poses.copy()
        self.centres = np.asarray(centres, dtype=np.float64)
        self.radius, self.K, self.options, self.tracks = float(radius), np.asarray(K, np.float64), options, tracks
        k_count, t_count = self.poses.shape[:2]
        self.m = np.zeros((t_count, k_count, 6))
        self.v = np.zeros((t_count, k_count, 6))
        self.steps = np.zeros(t_count, int)
        self.free = np.arange(t_count) > 0  # frames whose turn is fitted: frame 0's once it took a neighbour's
        self.losses = np.full(t_count, np.nan)
        self.points: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # per part: track ids, points, ok
        if tracks is not None and options.track_weight > 0:
            self.solve_points()

    def solve_points(self) -> None:
        """Re-solve every track's point under the current poses."""
        self.points = []
        for k in range(len(self.poses)):
            ids = np.flatnonzero(self.tracks.parts == k)
            points, ok = triangulate_tracks(self.poses[k], self.tracks.uv[:, ids], self.tracks.visible[:, ids],
                                            self.K)
            self.points.append((ids[ok], points[ok]))

    def frame_weight(self, t: int, loss: float) -> float:
        """Weight of frame t's step on the Gaussians given its loss: ``min(1, (median / loss)²)`` over the frames'
        latest losses, so that frames whose poses disagree with the rest do not bend the model to them."""
        self.losses[t] = loss
        known = self.losses[~np.isnan(self.losses)]
        if not self.options.robust_frames or len(known) < 3:
            return 1.0
        return float(min(1.0, (np.median(known) / max(loss, 1e-12)) ** 2))

    def pivots(self, t: int) -> np.ndarray:
        """(K, 3) the parts' centres at frame ``t``: what each part's twist turns it about."""
        return np.einsum("kij,kj->ki", self.poses[:, t, :3, :3], self.centres) + self.poses[:, t, :3, 3]

    def prior_gradient(self, t: int) -> np.ndarray:
        """(K, 6) gradient of the smoothness and anchor terms with respect to frame t's twists ``[ω, v]`` about
        the pivots.

        With ``w_s = log(R_{s+1} R_sᵀ)``, turning frame t by ``exp(δ)`` changes ``w_{t-1}`` by
        ``J_l⁻¹(w_{t-1}) δ`` and ``w_t`` by ``-J_r⁻¹(w_t) δ`` (to first order in δ, exactly in the steps).
        """
        o = self.options
        k_count, t_count = self.poses.shape[:2]
        lo, hi = max(t - 2, 0), min(t + 3, t_count)
        window = self.poses[:, lo:hi]  # (K, S, 4, 4): frames lo..hi-1
        i = t - lo
        rot = window[..., :3, :3]
        steps = matrix_to_axis_angle(rot[:, 1:] @ np.swapaxes(rot[:, :-1], -1, -2))  # (K, S-1, 3): w_s, s = lo..
        # ∂E/∂w_s for the steps next to frame t: E = λ_acc Σ |w_s - w_{s-1}|² + λ_vel Σ |w_s|².
        d_step = {}
        for s in (i - 1, i):
            if 0 <= s < len(steps[0]):
                g = 2 * o.velocity * steps[:, s]
                if s >= 1:
                    g = g + 2 * o.acceleration * (steps[:, s] - steps[:, s - 1])
                if s + 1 < len(steps[0]):
                    g = g - 2 * o.acceleration * (steps[:, s + 1] - steps[:, s])
                d_step[s] = g
        g_rot = np.zeros((k_count, 3))
        if i - 1 in d_step:
            g_rot += np.einsum("kji,kj->ki", np.linalg.inv(so3_left_jacobian(steps[:, i - 1])), d_step[i - 1])
        if i in d_step:
            g_rot -= np.einsum("kji,kj->ki", np.linalg.inv(so3_left_jacobian(-steps[:, i])), d_step[i])
        # The centre's: E = λ_acc Σ |c_{s+1} - 2 c_s + c_{s-1}|² / r² + λ_vel Σ |c_{s+1} - c_s|² / r².
        c = (np.einsum("ksij,kj->ksi", rot, self.centres) + window[..., :3, 3]) / self.radius  # (K, S, 3)
        g_pos = np.zeros((k_count, 3))
        for s, sign in ((i - 1, 1.0), (i, -2.0), (i + 1, 1.0)):
            if 1 <= s < c.shape[1] - 1:
                g_pos += 2 * o.acceleration * sign * (c[:, s - 1] - 2 * c[:, s] + c[:, s + 1])
        if i >= 1:
            g_pos += 2 * o.velocity * (c[:, i] - c[:, i - 1])
        if i + 1 < c.shape[1]:
            g_pos -= 2 * o.velocity * (c[:, i + 1] - c[:, i])
        grad = np.concatenate([g_rot, g_pos / self.radius], axis=1)
        if o.anchor > 0:
            # Cauchy pull towards the starting pose: ξ = [ω, Δc / r] of the pose from it, about the centre.
            omega = matrix_to_axis_angle(self.poses[:, t, :3, :3] @ self.start[:, t, :3, :3].swapaxes(-1, -2))
            start_c = np.einsum("kij,kj->ki", self.start[:, t, :3, :3], self.centres) + self.start[:, t, :3, 3]
            xi = np.concatenate([omega, (self.pivots(t) - start_c) / self.radius], axis=1)
            pull = 2 * o.anchor * xi / (1 + np.sum(xi * xi, axis=1, keepdims=True) / o.anchor_scale ** 2)
            grad[:, :3] += np.einsum("kji,kj->ki", np.linalg.inv(so3_left_jacobian(omega)), pull[:, :3])
            grad[:, 3:] += pull[:, 3:] / self.radius
        return grad

    def track_gradient(self, t: int) -> np.ndarray:
        """(K, 6) gradient of the track term at frame t with respect to its twists about the pivots."""
        grad = np.zeros((len(self.poses), 6))
        if not self.points:
            return grad
        o, fx, fy = self.options, self.K[0, 0], self.K[1, 1]
        pivots = self.pivots(t)
        for k, (ids, points) in enumerate(self.points):
            seen = self.tracks.visible[t, ids]
            if not seen.any():
                continue
            p = points[seen] @ self.poses[k, t, :3, :3].T + self.poses[k, t, :3, 3]  # (J, 3) camera frame
            z = np.maximum(p[:, 2], 1e-9)
            r = np.stack([fx * p[:, 0] / z + self.K[0, 2], fy * p[:, 1] / z + self.K[1, 2]], 1) \
                - self.tracks.uv[t, ids[seen]]
            s2 = o.track_scale ** 2
            d_r = 2 * r / (1 + np.sum(r * r, axis=1, keepdims=True) / s2) * (o.track_weight / len(r))  # (J, 2)
            g_p = np.stack([d_r[:, 0] * fx / z, d_r[:, 1] * fy / z,
                            -(d_r[:, 0] * fx * p[:, 0] + d_r[:, 1] * fy * p[:, 1]) / z ** 2], 1)
            grad[k, :3] = np.cross(p - pivots[k], g_p).sum(axis=0)
            grad[k, 3:] = g_p.sum(axis=0)
        return grad

    def step(self, t: int, image_gradient: np.ndarray, it: int, total: int) -> np.ndarray:
        """One Adam step of frame ``t``'s poses given its image loss's twist gradient (K, 6); its poses (K, 4, 4)."""
        first = int(self.options.warmup * total)
        if it < first:
            return self.poses[:, t]
        it, total = it - first, total - first
        o = self.options
        g = np.asarray(image_gradient, np.float64) + self.prior_gradient(t) + self.track_gradient(t)
        g[:, 3:] *= self.radius  # per object radius, as the step is
        if not self.free[t]:
            g[:, :3] = 0.0
        self.steps[t] += 1
        n = self.steps[t]
        self.m[t] = 0.9 * self.m[t] + 0.1 * g
        self.v[t] = 0.999 * self.v[t] + 0.001 * g * g
        step = (self.m[t] / (1 - 0.9 ** n)) / (np.sqrt(self.v[t] / (1 - 0.999 ** n)) + 1e-12)
        decay = 0.1 ** (it / max(total - 1, 1))
        omega = -o.lr_rotation * decay * step[:, :3]
        shift = -o.lr_translation * decay * self.radius * step[:, 3:]
        pivots = self.pivots(t)
        rot = axis_angle_to_matrix(omega)  # (K, 3, 3)
        self.poses[:, t, :3, :3] = rot @ self.poses[:, t, :3, :3]
        self.poses[:, t, :3, 3] = np.einsum("kij,kj->ki", rot, self.poses[:, t, :3, 3] - pivots) + pivots + shift
        return self.poses[:, t]

    def rebase(self, reconstruction: Reconstruction) -> Reconstruction:
        """Frame 0's poses made the identity again (every frame's pose is fitted, frame 0's too): the poses become
        ``P_t P_0⁻¹`` and the centres move by ``P_0``, as do the returned Gaussians; every frame renders as before."""
        first = self.poses[:, 0].copy()
        self.poses = self.poses @ invert_transform(first)[:, None]
        self.centres = np.einsum("kij,kj->ki", first[:, :3, :3], self.centres) + first[:, :3, 3]
        parts, shading = reconstruction.parts, reconstruction.shading
        if shading is not None:
            shading = replace(shading, albedo=rotate_sh(shading.albedo, first[:, :3, :3], parts),
                              normals=per_part(shading.normals, parts, first[:, :3, :3]))
        return replace(reconstruction, gaussians=pose_gaussians(reconstruction.gaussians, parts, first),
                       shading=shading)

    def fitted_prior(self, prior: SpatPrior) -> SpatPrior:
        """``prior`` (as filmed) with the fitted poses."""
        return prior.with_poses(self.poses, self.centres)

    def epoch_done(self, frame_loss: Callable[[int, np.ndarray], float], it: int, total: int) -> None:
        """After a pass over the frames: after the warm-up, frames that stand out try their neighbours' poses
        (:meth:`try_neighbours`); the tracks' points follow the poses."""
        if it >= int(self.options.warmup * total):
            self.try_neighbours(frame_loss)
        if self.points:
            self.solve_points()

    def try_neighbours(self, frame_loss: Callable[[int, np.ndarray], float]) -> None:
        """A frame whose loss is over :data:`OUTLIER_LOSS` times the median (tracks that slipped by tens of
        degrees, beyond what its gradient can climb back) takes the pose of a neighbour with a lower loss, whole or
        turned about its own centre, when that renders it better: ``frame_loss(t, poses (K, 4, 4))``, its loss
        so posed. A run of such frames mends from its ends, a frame per pass."""
        known = ~np.isnan(self.losses)
        if known.sum() < 3:
            return
        median = float(np.median(self.losses[known]))
        t_count = self.poses.shape[1]
        for t in np.flatnonzero(known & (self.losses > OUTLIER_LOSS * median)):
            best, best_loss = None, frame_loss(t, self.poses[:, t])
            pivots = self.pivots(t)
            for n in (t - 1, t + 1):
                if not 0 <= n < t_count or not known[n] or self.losses[n] >= self.losses[t]:
                    continue
                turned = self.poses[:, n].copy()  # the neighbour's rotation about this frame's centres
                turned[:, :3, 3] = pivots - np.einsum("kij,kj->ki", turned[:, :3, :3], self.centres)
                for candidate in (self.poses[:, n], turned):
                    loss = frame_loss(t, candidate)
                    if loss < best_loss:
                        best, best_loss = candidate.copy(), loss
            if best is not None:
                self.poses[:, t] = best
                self.losses[t] = best_loss
                self.m[t], self.v[t], self.steps[t] = 0.0, 0.0, 0
                self.free[t] = True


@dataclass(frozen=True)
class JointFit:
    """The outcome of :func:`joint_fit`.

    Attributes
    ----------
    prior : SpatPrior, the input's with the fitted poses (in the input's frame, world or filmed).
    reconstruction : Reconstruction, the Gaussians fitted with them.
    change_deg : (K, T) float, how far each pose turned from the input's, in degrees.
    seconds : float
    """

    prior: SpatPrior
    reconstruction: Reconstruction
    change_deg: np.ndarray
    seconds: float


def placed_on_masks(poses: np.ndarray, centre: np.ndarray, masks, K: np.ndarray, lost) -> np.ndarray:
    """Poses (K, T, 4, 4) with the frames ``lost`` moved so the object's centre sits on their masks.

    A frame the tracks lost has interpolated poses that can put the object far from where the frame shows it
    (a rolling ball), where no silhouette reaches it. Its parts are shifted together so that the centre
    (3,) in the model's frame projects onto the mask's centroid, at the depth its box gives relative to the
    nearest tracked frame's (``z ∝ 1/size``, of the width and height the one that shrank least: something in
    front, a trunk or a post, hides the object across one of them, and its area halves as a ball goes behind
    it). ``masks`` (T, H, W) bool, ``K`` (3, 3).
    """
    poses = np.array(poses, dtype=np.float64)
    lost = sorted(set(int(t) for t in lost))
    tracked = [t for t in range(poses.shape[1]) if t not in lost and np.asarray(masks[t]).any()]
    if not tracked:
        return poses
    inverse_k = np.linalg.inv(K)
    for t in lost:
        mask = np.asarray(masks[t], bool)
        if not mask.any():
            continue
        ref = min(tracked, key=lambda r: abs(r - t))
        depth = (poses[0, ref, :3, :3] @ centre + poses[0, ref, :3, 3])[2] \
            * np.min(box_size(np.asarray(masks[ref], bool)) / box_size(mask))
        ys, xs = np.nonzero(mask)
        target = inverse_k @ np.array([xs.mean(), ys.mean(), 1.0]) * depth
        poses[:, t, :3, 3] += target - (poses[0, t, :3, :3] @ centre + poses[0, t, :3, 3])
    return poses


def joint_fit(frames, masks, prior: SpatPrior, *, options: JointOptions = JointOptions(),
              tracks: TrackObservations | None = None, progress: ProgressCallback | None = None) -> JointFit:
    """Fit every part's pose in every frame together with the object's Gaussians.

    Parameters
    ----------
    frames : (T, H, W, 3) uint8 array or VideoFrames, at the prior's resolution.
    masks : (T, H, W) bool array or PackedMasks.
    prior : SpatPrior, the starting poses (from the tracks).
    options : JointOptions
    tracks : TrackObservations, optional; default the prior's own (extraction stores them).
    progress : callable ``(done, total)``, optional.

    Returns
    -------
    JointFit
    """
    options.check()
    start = time.perf_counter()
    filmed = prior.motion_in("filmed")
    tracks = TrackObservations.of_prior(prior) if tracks is None else tracks
    centres = filmed.centroids[:, 0]  # frame 0's poses are the identity: the model's frame
    lost = [int(key.split(":")[1]) for key in (prior.metadata.get("failed_frames") or {})]
    start_poses = placed_on_masks(filmed.poses, centres[0], masks, prior.intrinsics, lost)
    pose_fit = PoseFit(start_poses, centres, float(np.max(prior.radii)), prior.intrinsics, options, tracks)
    fitting = sum(bool(np.asarray(masks[t]).any()) for t in range(prior.num_frames))
    reconstruction = reconstruct_object(frames, masks, pose_fit.fitted_prior(filmed),
                                        options=options.reconstruction(fitting),
                                        progress=progress, pose_fit=pose_fit)
    fitted, centres = pose_fit.poses, pose_fit.centres
    cameras = prior.extras.get(CAMERA_EXTRA)
    world = fitted if cameras is None else invert_transform(np.asarray(cameras, np.float64))[None] @ fitted
    refined = prior.with_poses(world, centres)
    change = rotation_angle_deg(fitted[..., :3, :3] @ np.swapaxes(filmed.poses[..., :3, :3], -1, -2))
    return JointFit(refined, reconstruction, change, time.perf_counter() - start)

