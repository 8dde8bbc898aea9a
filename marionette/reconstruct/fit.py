"""Reconstruct the source object as 3D Gaussians from its video, masks and SpaT prior.

The object is modelled at frame 0 in the prior's world frame; part ``k``'s
Gaussians seen at frame ``t`` are moved by ``poses[k, t]`` and rendered with
the prior's camera. Starting from silhouette lifts carved by the masks
(:mod:`._init`), colours, opacities, positions, orientations and log-scales
are fitted with Adam (Kingma & Ba 2015) against every fitting frame, the
object composited on white, with the loss of 3D Gaussian Splatting (Kerbl et
al. 2023, Eq. 7; its D-SSIM term, :mod:`.ssim`, is off by default) plus an
alpha-vs-mask term::

    L = (1 - λ) mean |I - Î| + λ (1 - SSIM(I, Î)) + λ_mask mean (A - M)²

and 3DGS's adaptive density control (Sec. 5.2): Gaussians with a large mean
screen-space positional gradient are cloned (small ones) or split in two
(large ones), and nearly transparent ones are pruned. Each frame is cropped
to its object and downscaled (:mod:`._views`); gradients come from
:func:`marionette.render.render_with_grad`. Frames where something in front
covers the object (:mod:`.occlusion`) count only where it shows; once fitted,
Gaussians off the mask in many frames are dropped (:mod:`.strays`).

Colours are SH of degree 1 in the object's frame, turned with their part at
every frame: an object turning under a fixed light and camera changes its
shading with the direction it is seen from, which a constant colour can only
average (docs/benchmarks/reconstruct.md). The degree-1 terms step at a
twentieth of the base colour's rate, as 3DGS's do. Those colours are an
albedo, shaded by one light fixed relative to the source camera (the world,
when the camera stands still) through a normal per Gaussian
(:mod:`.shading`): turning about the viewing direction changes an object's
shading but not the direction it is seen from, which SH alone cannot follow.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ..camera import Camera
from ..errors import InputError
from ..gaussians import Gaussians
from ..geometry import matrix_to_quaternion, quaternion_to_matrix
from ..optim import Adam
from ..prior import SpatPrior
from ..progress import ProgressCallback
from ..render import RenderOutput, render
from ..render.backward import render_with_grad
from ..render.sh import rotate_sh
from ..trajectory import Trajectory
from ._init import initial_gaussians, pose_gaussians
from ._views import FitView, box_size, make_view
from .occlusion import covered_frames
from .posing import per_part
from .quality import FitQuality, fit_quality
from .shading import (
    Lighting,
    ShadedTrajectory,
    Shading,
    factor_backward,
    shade_backward,
    shade_factors,
    shade_sh,
    tangent,
    unit_rows,
)
from .ssim import dssim_and_grad
from .strays import stray_gaussians

if TYPE_CHECKING:
    from .joint import PoseFit

__all__ = ["ReconstructOptions", "Reconstruction", "reconstruct_object"]

#: Frames the reported initial and final losses are averaged over: enough to follow the fit, at a fraction of a
#: long clip's cost (each is a render of its own).
LOSS_FRAMES = 20


@dataclass(frozen=True)
class ReconstructOptions:
    """Settings of :func:`reconstruct_object` (defaults tuned on the synthetic scenes and Table 1's real clips).

    Attributes
    ----------
    iterations : int
        Adam steps, one fitting frame each (frames are visited in a shuffled cycle).
    coarse_fraction : float
        Share of the iterations fitted to the frames at half the working resolution first (a quarter
        of the pixels per step), before the rest at full resolution. The default, 600 such steps
        (densification ends within them) and 300 at full resolution, takes about the time of 600 steps
        all at full resolution and fits Table 1's real clips as well as 800 of them, within the 40 s
        budget of a 50-frame clip (docs/benchmarks/reconstruct.md).
    max_side : int
        Long side of the frames the fit works on, before cropping (intrinsics follow). The
        default is the size frames are read at, so a 480p clip is fitted at its own resolution:
        a fit at 480 px cannot hold the texture of an 854 px frame.
    object_side : int or None
        Instead of ``max_side``: each frame scaled so that its object's box spans about this many pixels
        (never above the frame's own resolution), so a car far off and the same car close by weigh alike
        and cost alike.
    init_frames : int
        Frames whose silhouette lifts start the fit (spread over the fitting frames).
    init_cells : int
        About this many cells per lift (the lift's pixel stride follows).
    max_gaussians : int
        Cap on the number of Gaussians (initial and after densification).
    gaussians_per_pixel : float
        A second cap, this many Gaussians per object pixel (median object area of the
        fitting views at the working resolution): more Gaussians than the views have
        pixels are not constrained by them, only slower.
    lr_means : float
        Adam step of the centres, in units of the object radius; decays to a tenth.
    lr_log_scales, lr_opacity, lr_colour, lr_quats : float
        Adam steps of the log-scales, opacity logits, SH DC coefficients, quaternions. The steps of
        the centres, log-scales, opacities and colours are two to four times what the synthetic scenes
        alone ask for: the real clips of Table 1 come out sharper (docs/benchmarks/reconstruct.md).
    ssim_weight : float
        ``λ`` of the D-SSIM term (3DGS uses 0.2). Off by default: on car-turn (Table 1) it gains
        a few thousandths of SSIM and LPIPS for 10-30 % more fit time, less than a few more steps
        without it give, and it lowers the synthetic scenes' held-out masked PSNR
        (docs/benchmarks/ssim_loss.md).
    mask_weight : float
        ``λ_mask`` of the alpha-vs-mask term.
    densify_every : int
        Iterations between densification and pruning steps (from ``densify_every``
        until ``densify_until`` x iterations).
    densify_until : float
        Fraction of the iterations after which the number of Gaussians stays fixed.
    densify_fraction : float
        Share of the Gaussians with the largest mean screen-space gradient cloned or split per step.
    split_scale : float
        Gaussians larger than this (largest std, in object radii) are split, smaller ones cloned.
    prune_opacity : float
        Gaussians below this opacity are removed.
    shading : bool
        Fit a normal per Gaussian and one light fixed relative to the camera (:mod:`.shading`), so
        the shading changes as the object's faces turn towards or away from the light.
    lr_normals, lr_light, lr_diffuse : float
        Adam steps of the normals, the light direction and the diffuse share's logit.
    outside_weight : float
        Weight of the silhouette term carried past the crop: a Gaussian whose centre projects inside the
        frame but outside the view's crop (off the object) has its opacity pulled down as if its footprint
        were drawn on the mask's zeros (at ``mask_weight`` times this). Without it a Gaussian outside every
        crop costs nothing and shows as a floater in the full frame.
    max_scale : float
        Largest standard deviation a Gaussian may keep, in object radii (``inf``: any): larger ones are pulled
        back by a quadratic penalty on the log-scale's excess, so a few wide blurs cannot cover a pose's error.
    seed : int
        Seeds the frame order and the samples of splits and subsampling.
    """

    iterations: int = 900
    coarse_fraction: float = 2 / 3
    max_side: int = 960
    object_side: int | None = None
    init_frames: int = 4
    init_cells: int = 2500
    max_gaussians: int = 12000
    gaussians_per_pixel: float = 2.0
    lr_means: float = 0.004
    lr_log_scales: float = 0.02
    lr_opacity: float = 0.2
    lr_colour: float = 0.08
    lr_quats: float = 0.003
    ssim_weight: float = 0.0
    mask_weight: float = 0.5
    densify_every: int = 100
    densify_until: float = 0.6
    densify_fraction: float = 0.05
    split_scale: float = 0.05
    prune_opacity: float = 0.02
    shading: bool = True
    lr_normals: float = 0.01
    lr_light: float = 0.01
    lr_diffuse: float = 0.05
    outside_weight: float = 1.0
    max_scale: float = np.inf
    seed: int = 0

    @property
    def coarse_steps(self) -> int:
        """How many of the iterations are fitted at half resolution (the first ones)."""
        return int(round(self.coarse_fraction * self.iterations))

    def check(self) -> None:
        """Raise :class:`InputError` naming the first setting out of range."""
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, (int, np.integer)) \
                or not 1 <= self.iterations <= 1_000_000:
            raise InputError(f"iterations must be an integer in 1..1000000, got {self.iterations!r}")
        if not 16 <= self.max_side <= 8192:
            raise InputError(f"max_side must be within 16..8192, got {self.max_side}")
        if self.object_side is not None and not 16 <= self.object_side <= 8192:
            raise InputError(f"object_side must be within 16..8192, got {self.object_side}")
        if self.init_frames < 1 or self.init_cells < 16 or self.max_gaussians < 16:
            raise InputError("init_frames must be >= 1, init_cells and max_gaussians >= 16")
        if not 0 <= self.coarse_fraction < 1:
            raise InputError(f"coarse_fraction must be within [0, 1), got {self.coarse_fraction}")
        if not 0 <= self.ssim_weight <= 1:
            raise InputError(f"ssim_weight must be within 0..1, got {self.ssim_weight}")
        if not self.gaussians_per_pixel > 0:
            raise InputError(f"gaussians_per_pixel must be > 0, got {self.gaussians_per_pixel}")
        if not self.outside_weight >= 0 or not self.max_scale > 0:
            raise InputError("outside_weight must be >= 0 and max_scale > 0")


@dataclass(frozen=True)
class Reconstruction:
    """The source object as Gaussians at frame 0 (prior world frame).

    Attributes
    ----------
    gaussians : Gaussians, N of them (SH degree 1, in the frame-0 object frame).
    parts : (N,) int32, each Gaussian's rigid part (index into the prior's parts).
        Their colours are as the object looks unturned (shaded at rest, when
        ``shading`` is set): what a ``.ply`` of it holds.
    losses : dict
        ``initial`` and ``final`` mean loss over the fitting frames (at most
        :data:`LOSS_FRAMES` of them, evenly spread), ``fit``
        (mean loss of each ``densify_every`` block of iterations), and the
        Gaussian counts ``gaussians_initial`` and ``gaussians_final``.
    frames_used : list of int, the fitting frames.
    shading : Shading or None
        Albedo, normals and light, when the fit modelled the shading.
    quality : FitQuality or None
        How well the fit explains the frames it was fitted to (silhouettes and colours, :mod:`.quality`).
    """

    gaussians: Gaussians
    parts: np.ndarray
    losses: dict = field(default_factory=dict)
    frames_used: list = field(default_factory=list)
    shading: Shading | None = None
    quality: FitQuality | None = None

    def at(self, prior: SpatPrior, t: int) -> Gaussians:
        """The Gaussians at frame ``t``: part k moved by ``prior.poses[k, t]``, shaded as it then faces the light."""
        poses = prior.poses[:, t]
        if self.shading is None:
            return pose_gaussians(self.gaussians, self.parts, poses)
        posed = pose_gaussians(self.gaussians.with_sh(self.shading.albedo), self.parts, poses)
        return posed.with_sh(self.shading.sh_at(poses[:, :3, :3], self.parts, posed.sh))

    def trajectory(self, prior: SpatPrior) -> Trajectory:
        """The Gaussians over the prior's frames (shaded at each when ``shading`` is set), for rendering."""
        means = np.stack([pose_gaussians(self.gaussians, self.parts, prior.poses[:, t]).means
                          for t in range(prior.num_frames)])
        rotations = prior.poses[:, :, :3, :3].transpose(1, 0, 2, 3)
        if self.shading is None:
            return Trajectory(means, rotations, self.parts)
        return ShadedTrajectory(means, rotations, self.parts, self.shading)

    def render_filmed(self, prior: SpatPrior, t: int) -> RenderOutput:
        """Frame ``t`` on white as the source camera filmed it (the prior's intrinsics, and its own motion when
        extraction removed it): what was fitted to frame ``t``. Image (H, W, 3), alpha and depth (H, W)."""
        w, h = (int(v) for v in prior.image_size)
        return render(self.at(prior.motion_in("filmed"), t), Camera(prior.intrinsics, np.eye(4), w, h),
                      (1.0, 1.0, 1.0))

    def render_frame(self, prior: SpatPrior, t: int, camera: Camera | None = None) -> np.ndarray:
        """(H, W, 3) float32 render of frame ``t`` on white, by default as filmed (:meth:`render_filmed`)."""
        if camera is None:
            return self.render_filmed(prior, t).image
        return render(self.at(prior, t), camera, (1.0, 1.0, 1.0)).image


def _check_inputs(frames, masks, prior: SpatPrior, frames_used: Sequence[int] | None) -> list[int]:
    """Validate the shapes against the prior; the checked fitting frames."""
    if not isinstance(prior, SpatPrior):
        raise InputError(f"prior must be a SpatPrior, got {type(prior).__name__}")
    shape = tuple(frames.shape)
    if len(shape) != 4 or shape[3] != 3:
        raise InputError(f"frames must have shape (T, H, W, 3), got {shape}")
    t, h, w = shape[:3]
    if prior.num_frames != t:
        raise InputError(f"the prior has {prior.num_frames} frames but the source has {t}")
    if tuple(int(v) for v in prior.image_size) != (w, h):
        raise InputError(f"the prior is for {prior.image_size[0]}x{prior.image_size[1]} frames but the source's are "
                         f"{w}x{h}")
    if tuple(masks.shape) != (t, h, w):
        raise InputError(f"masks must have shape ({t}, {h}, {w}) to match the frames, got {tuple(masks.shape)}")
    used = list(range(t)) if frames_used is None else [int(i) for i in frames_used]
    if not used or any(not 0 <= i < t for i in used) or len(set(used)) != len(used):
        raise InputError(f"frames_used must be distinct frame indices in 0..{t - 1}")
    return sorted(used)


def gaussian_budget(views: Sequence[FitView], options: ReconstructOptions) -> int:
    """How many Gaussians the fit may hold: ``max_gaussians``, or fewer for an object of few pixels."""
    area = float(np.median([view.mask.sum() for view in views]))
    return int(min(options.max_gaussians, max(16.0, options.gaussians_per_pixel * area)))


def _left_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions ``w, x, y, z`` → (N, 4, 4) matrices ``L`` with ``q ⊗ p = L p``."""
    w, x, y, z = q.T
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, -z, y], -1),
                     np.stack([y, z, w, -x], -1), np.stack([z, -y, x, w], -1)], axis=1)


def _lighting(light: dict) -> Lighting:
    """The light of the global parameters ``direction`` (1, 3) (any length) and ``diffuse`` (1,) (a logit)."""
    return Lighting(unit_rows(light["direction"][0]), float(1 / (1 + np.exp(-light["diffuse"][0]))))


def _initial_normals(gaussians: Gaussians, parts: np.ndarray) -> np.ndarray:
    """(N, 3) float64: each Gaussian's shortest axis (a surfel's normal), turned away from its part's centre."""
    q = gaussians.quats.astype(np.float64)
    rot = quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    axis = rot[np.arange(len(q)), :, np.argmin(gaussians.log_scales, axis=1)]
    means = gaussians.means.astype(np.float64)
    centres = np.stack([means[parts == k].mean(axis=0) if (parts == k).any() else np.zeros(3)
                        for k in range(int(parts.max()) + 1)])
    outward = np.sum(axis * (means - centres[parts]), axis=1)
    return axis * np.where(outward < 0, -1.0, 1.0)[:, None]


def _posed(params: dict, parts: np.ndarray, poses: np.ndarray, q_pose: np.ndarray, light: dict | None) -> tuple:
    """The Gaussians of ``params`` at a frame: part k moved by ``poses[k]`` (K, 4, 4) (its rotation as the
    quaternion ``q_pose[k]``), colours turned with it and shaded under ``light``.

    Returns the posed :class:`Gaussians` and what the backward pass reuses: the parts' rotations (K, 3, 3) and
    quaternion matrices (K, 4, 4), the posed means (N, 3) float64, SH before shading and, with ``light``, the
    lighting, world normals (N, 3) and shading factors.
    """
    g0 = Gaussians(params["means"], params["quats"], params["log_scales"], params["logits"],
                   np.concatenate([params["dc"][:, None], params["rest"]], axis=1))
    rot = poses[:, :3, :3]  # (K, 3, 3)
    left = _left_matrix(q_pose)  # (K, 4, 4)
    posed_means = per_part(g0.means, parts, rot, poses[:, :3, 3])
    posed_quats = per_part(g0.quats, parts, left)
    turned_sh = rotate_sh(g0.sh, rot, parts)
    lighting = normals = factors = None
    if light is not None:
        lighting = _lighting(light)
        normals = per_part(unit_rows(params["normals"].astype(np.float64)), parts, rot)
        factors = shade_factors(normals, lighting)
    posed = Gaussians(posed_means.astype(np.float32), posed_quats.astype(np.float32), g0.log_scales,
                      g0.opacity_logits, turned_sh if light is None else shade_sh(turned_sh, factors))
    return posed, (rot, left, posed_means, turned_sh, lighting, normals, factors)


def _image_loss(image: np.ndarray, alpha: np.ndarray, view: FitView, mask_weight: float,
                ssim_weight: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Loss of a render, image (H, W, 3) and alpha (H, W), against the view, and its gradients with respect to
    the image (H, W, 3) and the alpha (H, W). A covered view counts the colours on its mask only, and the alpha
    only where it falls short of the mask (what is drawn off it may be behind what covers it); no SSIM."""
    res = image - view.target  # (H, W, 3)
    a_res = alpha - view.mask  # (H, W)
    shown = view.mask[..., None] if view.covered else 1.0
    if view.covered:
        res, a_res, ssim_weight = res * shown, np.minimum(a_res, 0.0), 0.0
    npx = res.shape[0] * res.shape[1]
    loss = float((1 - ssim_weight) * np.abs(res).mean() + mask_weight * (a_res ** 2).mean())
    d_image = ((1 - ssim_weight) / (3 * npx)) * np.sign(res) * shown
    if ssim_weight > 0:
        dssim, d_dssim = dssim_and_grad(image, view.target)
        loss += ssim_weight * dssim
        d_image = d_image + ssim_weight * d_dssim
    return loss, d_image.astype(np.float32), (2 * mask_weight / npx) * a_res


def _poses_epoch(pose_fit: PoseFit, params: dict, parts: np.ndarray, views: Sequence[FitView], poses: dict,
                 q_pose: dict, light: dict | None, options: ReconstructOptions, it: int) -> None:
    """The joint fit's end of a pass over the frames (:meth:`~.joint.PoseFit.epoch_done`), the fit's poses
    (``poses``, ``q_pose``: frame → (K, 4, 4), (K, 4)) updated from it."""
    by_frame = {view.frame: view for view in views}

    def frame_loss(t: int, pose: np.ndarray) -> float:  # past the crop too: else, moving an object that shows
        # a sliver (a ball behind a trunk) off its small crop would look cheap
        return _view_loss(params, parts, by_frame[t], pose, matrix_to_quaternion(pose[:, :3, :3]),
                          options.mask_weight, light, options.ssim_weight, options.outside_weight)

    pose_fit.epoch_done(frame_loss, it, options.iterations)
    for t in by_frame:
        poses[t] = pose_fit.poses[:, t]
        q_pose[t] = matrix_to_quaternion(poses[t][:, :3, :3])


def _view_loss(params: dict, parts: np.ndarray, view: FitView, poses: np.ndarray, q_pose: np.ndarray,
               mask_weight: float, light: dict | None, ssim_weight: float, outside_weight: float = 0.0) -> float:
    """Loss of one view (a forward render only); with ``outside_weight``, the silhouette term past the crop too."""
    posed, (_, _, posed_means, *_) = _posed(params, parts, poses, q_pose, light)
    out = render(posed, view.camera, (1.0, 1.0, 1.0))
    loss = _image_loss(out.image, out.alpha, view, mask_weight, ssim_weight)[0]
    return loss + _outside(params, posed_means, view, mask_weight * outside_weight)[0]


def _outside(params: dict, posed_means: np.ndarray, view: FitView, weight: float) -> tuple[float, np.ndarray]:
    """The silhouette term past the crop: loss and its gradient (N,) with respect to the opacity logits.

    A Gaussian whose centre (posed_means (N, 3), camera frame) projects inside the frame but outside the crop
    would draw about ``o² π σ²`` of squared alpha onto the mask's zeros there (``σ`` its largest standard
    deviation in pixels), counted as the crop's own pixels are: ``weight · Σ o² π σ² / (H W)``.
    """
    grad = np.zeros(len(posed_means))
    if view.frame_box is None or weight == 0 or not len(posed_means) or view.covered:
        return 0.0, grad
    cam = view.camera
    z = posed_means[:, 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = cam.K[0, 0] * posed_means[:, 0] / zs + cam.K[0, 2]
    v = cam.K[1, 1] * posed_means[:, 1] / zs + cam.K[1, 2]
    x0, y0, x1, y1 = view.frame_box
    off = front & (u >= x0) & (u < x1) & (v >= y0) & (v < y1) & ~((u >= 0) & (u < cam.width) & (v >= 0)
                                                                  & (v < cam.height))
    if not off.any():
        return 0.0, grad
    o = 1 / (1 + np.exp(-params["logits"][off].astype(np.float64)))
    sigma = np.maximum(cam.K[0, 0] * np.exp(params["log_scales"][off].max(axis=1).astype(np.float64)) / zs[off], 0.5)
    area = np.pi * sigma ** 2 * (weight / (cam.width * cam.height))
    grad[off] = 2 * o * o * (1 - o) * area
    return float(np.sum(o * o * area)), grad


def _scale_excess(log_scales: np.ndarray, cap: float, weight: float) -> np.ndarray:
    """(N, 3) gradient of ``weight · mean_n max(0, log s_n - log cap)²`` over the Gaussians' largest log-scale."""
    grad = np.zeros(log_scales.shape)
    if not np.isfinite(cap) or not len(log_scales):
        return grad
    largest = np.argmax(log_scales, axis=1)
    excess = np.maximum(log_scales[np.arange(len(log_scales)), largest] - np.log(cap), 0.0)
    grad[np.arange(len(log_scales)), largest] = 2 * weight * excess / len(log_scales)
    return grad


def _loss_and_grads(params: dict, parts: np.ndarray, view: FitView, poses: np.ndarray, q_pose: np.ndarray,
                    mask_weight: float, light: dict | None = None, ssim_weight: float = 0.0, *,
                    outside_weight: float = 0.0, pivots: np.ndarray | None = None) -> tuple[float, dict, np.ndarray]:
    """Loss of one view, gradients per parameter, and each Gaussian's screen-space gradient norm (N,).

    With ``light`` (see :func:`_lighting`) the colours are shaded and the gradients include
    ``normals`` and, under ``light``, ``direction`` and ``diffuse``. ``outside_weight``: the silhouette term
    past the crop (:func:`_outside`), at ``mask_weight`` times it. With ``pivots`` (K, 3), also ``pose``
    (K, 6): the gradient with respect to a left-multiplied twist ``[ω, v]`` of each part about its pivot.
    """
    posed, (rot, left, posed_means, turned_sh, lighting, normals, factors) = _posed(params, parts, poses, q_pose,
                                                                                    light)
    out = render_with_grad(posed, view.camera, (1.0, 1.0, 1.0))
    loss, d_image, d_alpha = _image_loss(out.output.image, out.output.alpha, view, mask_weight, ssim_weight)
    groups = None if pivots is None else [parts == k for k in range(len(poses))]
    grads = out.backward(d_image, d_alpha, groups=groups, pivot=pivots)
    outside_loss, g_outside = _outside(params, posed_means, view, mask_weight * outside_weight)
    loss += outside_loss
    g_means = per_part(grads.means, parts, rot, transpose=True)  # Rᵀ ∂L/∂μ'
    g_quats = per_part(grads.quats, parts, left, transpose=True)  # Lᵀ ∂L/∂q'
    depth = np.maximum(posed_means[:, 2], 1e-6)
    screen = np.linalg.norm(grads.means, axis=1) * depth / view.camera.fx  # ∂L per pixel of motion
    g_sh = grads.sh
    if light is not None:
        g_sh, g_factors = shade_backward(turned_sh, factors, g_sh)
        g_normals, g_direction, g_diffuse = factor_backward(normals, lighting, g_factors)
    result = {"means": g_means, "quats": g_quats, "log_scales": grads.log_scales.astype(np.float64),
              "logits": grads.opacity_logits.astype(np.float64) + g_outside,
              "dc": g_sh[:, 0].astype(np.float64),
              # The SH turn is orthogonal: its transpose, the gradient's, is the inverse turn's.
              "rest": rotate_sh(g_sh, np.swapaxes(poses[:, :3, :3], 1, 2), parts)[:, 1:].astype(np.float64)}
    if light is not None:
        result["normals"] = tangent(per_part(g_normals, parts, rot, transpose=True), params["normals"])
        result["direction"] = tangent(g_direction, light["direction"][0])[None]
        result["diffuse"] = np.array([g_diffuse * lighting.diffuse * (1 - lighting.diffuse)])
    if pivots is not None:
        result["pose"] = grads.pose
    return loss, result, screen


def _densify(params: dict, parts: np.ndarray, adam: Adam, score: np.ndarray, options: ReconstructOptions,
             budget: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    """Prune, then clone or split the highest-scoring Gaussians (3DGS Sec. 5.2) up to ``budget`` of them, in
    place; the new parts (N',)."""
    n = len(parts)
    opacity = 1 / (1 + np.exp(-params["logits"]))
    alive = opacity >= options.prune_opacity
    room = max(budget - int(alive.sum()), 0)
    count = min(int(options.densify_fraction * n), room)
    chosen = np.zeros(n, bool)
    if count > 0:
        ranked = np.argsort(-np.where(alive, score, -np.inf), kind="stable")[:count]
        chosen[ranked[(score[ranked] > 0) & alive[ranked]]] = True
    big = chosen & (np.exp(params["log_scales"]).max(axis=1) > options.split_scale * radius)
    clone = chosen & ~big
    # Split: the original is replaced by two samples from it, each 1/1.6 the size (3DGS).
    split_idx = np.flatnonzero(big)
    keep = np.flatnonzero(alive & ~big)
    new_rows = {k: [] for k in params}
    if len(split_idx):
        q = params["quats"][split_idx].astype(np.float64)
        rot = quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
        std = np.exp(params["log_scales"][split_idx]).astype(np.float64)
        for _ in range(2):
            offset = np.einsum("nij,nj->ni", rot, rng.normal(size=std.shape) * std)
            new_rows["means"].append((params["means"][split_idx] + offset).astype(np.float32))
            new_rows["log_scales"].append(params["log_scales"][split_idx] - np.float32(np.log(1.6)))
            for k in params.keys() - {"means", "log_scales"}:
                new_rows[k].append(params[k][split_idx])
    clone_idx = np.flatnonzero(clone & alive)
    if len(clone_idx):
        for k in params:
            new_rows[k].append(params[k][clone_idx])
    fresh_parts = np.concatenate([parts[split_idx], parts[split_idx], parts[clone_idx]]).astype(np.int32)
    fresh = len(fresh_parts)
    for k in params:
        params[k] = np.concatenate([params[k][keep]] + new_rows[k]) if new_rows[k] else params[k][keep]
    adam.reindex(keep, fresh)
    return np.concatenate([parts[keep], fresh_parts])


def reconstruct_object(frames, masks, prior: SpatPrior, *, frames_used: Sequence[int] | None = None,
                       options: ReconstructOptions = ReconstructOptions(),
                       progress: ProgressCallback | None = None, pose_fit: PoseFit | None = None) -> Reconstruction:
    """Fit the source object as 3D Gaussians at frame 0 to the frames it is seen in.

    Parameters
    ----------
    frames : (T, H, W, 3) uint8 array or VideoFrames
        Source frames at the prior's resolution (``prior.image_size``).
    masks : (T, H, W) bool array or PackedMasks
        Object masks of those frames.
    prior : SpatPrior
        K parts over T frames; ``extras['labels']`` (frame-0 part layout) assigns
        parts when K > 1.
    frames_used : sequence of int, optional
        Fitting frames (default all); frames where the object is not visible are skipped.
    options : ReconstructOptions
    progress : callable ``(done, total)``, optional
        Called after every iteration.
    pose_fit : PoseFit, optional
        Fit the poses too (:mod:`.joint`): after every step, the frame's poses take a step of their own from
        the same backward pass. Its poses (as filmed) replace the prior's throughout.

    Returns
    -------
    Reconstruction
        Gaussians (N) at frame 0 in the prior's world frame, each Gaussian's
        part (N,), and the losses.

    Each frame is fitted under the poses as the source camera filmed them: where extraction removed the
    camera's own motion (``extras['camera_world_to_camera']``), it is put back (frame 0's camera is the
    world, so the Gaussians are at frame 0 all the same). The light is fixed relative to the camera.
    """
    options.check()
    used = _check_inputs(frames, masks, prior, frames_used)
    prior = prior.motion_in("filmed")
    visible = [t for t in used if np.asarray(masks[t]).any()]
    if not visible:
        raise InputError("the object is not visible (empty mask) in any of the frames to fit")
    rng = np.random.default_rng(options.seed)
    w, h = (int(v) for v in prior.image_size)
    scale = min(1.0, options.max_side / max(w, h))
    coarse_steps = options.coarse_steps
    covered = covered_frames(masks)
    views, coarse = [], []
    for t in visible:  # each frame read once (a video decodes it again on every read)
        image, mask = np.asarray(frames[t]), np.asarray(masks[t], bool)
        if options.object_side is not None:
            scale = min(1.0, options.object_side / box_size(mask).max())
        views.append(make_view(t, image, mask, prior.intrinsics, scale, covered=t in covered))
        if coarse_steps:
            coarse.append(make_view(t, image, mask, prior.intrinsics, scale / 2, covered=t in covered))
    coarse = coarse or views
    budget = gaussian_budget(views, options)
    whole = [t for t in visible if t not in covered] or visible  # a covered mask would carve the object
    picks = np.unique(np.rint(np.linspace(0, len(whole) - 1, min(options.init_frames, len(whole)))).astype(int))
    gaussians, parts = initial_gaussians(frames, masks, prior, [whole[i] for i in picks], whole,
                                         cells=options.init_cells, max_gaussians=budget,
                                         seed=options.seed)
    radius = float(np.max(prior.radii))
    params = {"means": gaussians.means.copy(), "quats": gaussians.quats.copy(),
              "log_scales": gaussians.log_scales.copy(), "logits": gaussians.opacity_logits.copy(),
              "dc": gaussians.sh[:, 0].copy(), "rest": np.zeros((len(gaussians), 3, 3), np.float32)}
    light = None
    if options.shading:
        params["normals"] = _initial_normals(gaussians, parts)
        # Start from a faint light from the camera: colours as observed, gradients for every term.
        light = {"direction": np.array([[0.0, 0.0, -1.0]]), "diffuse": np.array([np.log(0.1 / 0.9)])}
        light_adam = Adam(light)
    start_poses = prior.poses if pose_fit is None else pose_fit.poses
    poses = {t: start_poses[:, t] for t in visible}
    q_pose = {t: matrix_to_quaternion(start_poses[:, t, :3, :3]) for t in visible}
    adam = Adam(params)

    scored = [views[i] for i in np.unique(np.linspace(0, len(views) - 1, min(LOSS_FRAMES, len(views))).astype(int))]

    def mean_loss() -> float:
        return float(np.mean([_view_loss(params, parts, v, poses[v.frame], q_pose[v.frame], options.mask_weight,
                                         light, options.ssim_weight) for v in scored]))

    losses: dict = {"initial": mean_loss(), "gaussians_initial": len(parts), "fit": []}
    accum = np.zeros(len(parts))
    seen = np.zeros(len(parts))
    order: list[int] = []
    block: list[float] = []
    total = options.iterations
    last_densify = int(options.densify_until * total)
    for it in range(total):
        if not order:
            order = list(rng.permutation(len(views)))
            if pose_fit is not None and it:
                _poses_epoch(pose_fit, params, parts, coarse if it < coarse_steps else views, poses, q_pose, light,
                             options, it)
        view = (coarse if it < coarse_steps else views)[order.pop()]
        loss, grads, screen = _loss_and_grads(params, parts, view, poses[view.frame], q_pose[view.frame],
                                              options.mask_weight, light, options.ssim_weight,
                                              outside_weight=options.outside_weight,
                                              pivots=None if pose_fit is None else pose_fit.pivots(view.frame))
        grads["log_scales"] += _scale_excess(params["log_scales"], options.max_scale * radius, options.mask_weight)
        block.append(loss)
        decay = 0.1 ** (it / max(total - 1, 1))
        lrs = {"means": options.lr_means * radius * decay, "quats": options.lr_quats,
               "log_scales": options.lr_log_scales, "logits": options.lr_opacity, "dc": options.lr_colour,
               "rest": options.lr_colour / 20, "normals": options.lr_normals}
        weight = 1.0 if pose_fit is None else pose_fit.frame_weight(view.frame, loss)
        if view.covered:  # it tells where the object is, not its shape: the rest of it is behind something
            weight = 0.0
        adam.update(params, {k: grads[k] * weight for k in params}, lrs)
        if light is not None and not view.covered:
            light_adam.update(light, {k: grads[k] for k in light},
                              {"direction": options.lr_light, "diffuse": options.lr_diffuse})
        if pose_fit is not None:
            poses[view.frame] = pose_fit.step(view.frame, grads["pose"], it, total)
            q_pose[view.frame] = matrix_to_quaternion(poses[view.frame][:, :3, :3])
        if not view.covered:
            accum += screen
            seen += screen > 0
        if (it + 1) % options.densify_every == 0:
            losses["fit"].append(float(np.mean(block)))
            block = []
            if it + 1 <= last_densify and it + 1 < total:
                parts = _densify(params, parts, adam, accum / np.maximum(seen, 1), options, budget, radius, rng)
                accum, seen = np.zeros(len(parts)), np.zeros(len(parts))
        if progress:
            progress(it + 1, total)
    if block:
        losses["fit"].append(float(np.mean(block)))
    # Final prune of what the fit made transparent, and of what draws off the object in many frames.
    keep = 1 / (1 + np.exp(-params["logits"])) >= options.prune_opacity
    keep &= ~stray_gaussians(params["means"], parts, {t: poses[t] for t in visible if t not in covered}, masks,
                             prior.intrinsics)
    if keep.sum() >= 1:
        params = {k: v[keep] for k, v in params.items()}
        parts = parts[keep]
    losses["final"] = mean_loss()
    losses["gaussians_final"] = len(parts)
    albedo = np.concatenate([params["dc"][:, None], params["rest"]], axis=1)
    shading = None
    if light is not None:
        shading = Shading(albedo, unit_rows(params["normals"]), _lighting(light))
        losses["light"] = {"direction": shading.lighting.direction.tolist(), "diffuse": shading.lighting.diffuse}
    result = Gaussians(params["means"], params["quats"], params["log_scales"], params["logits"],
                       albedo if shading is None else shading.sh_at(np.eye(3)[None], np.zeros(len(parts), int),
                                                                     albedo))
    result.check_finite()
    reconstruction = Reconstruction(result, parts.astype(np.int32), losses, visible, shading)
    if pose_fit is not None:
        reconstruction = pose_fit.rebase(reconstruction)
        prior = pose_fit.fitted_prior(prior)
    reconstruction = replace(reconstruction, quality=fit_quality(reconstruction, frames, masks, prior, visible))
    if reconstruction.quality.poor:
        q = reconstruction.quality.summary()
        warnings.warn(f"the object fitted explains its frames poorly (silhouette IoU {q['silhouette_iou']:.2f} "
                      f"median, {q['silhouette_iou_worst']:.2f} at frame {q['worst_frame']}): no rigid object moves "
                      "as the poses say; check the masks (extract --save-masks writes them) or choose the object "
                      "with --source-point and --source-exclude")
    return reconstruction
