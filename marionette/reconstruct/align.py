"""Photometric pose refinement: each part's pose in each frame fitted to the frame through the reconstruction.

Analysis by synthesis: the reconstructed Gaussians are moved
by the current per-part poses of frame ``t``, rendered on white in that
frame's (cropped, downscaled) camera and compared with the frame composited
on white by its mask::

    L(ξ) = mean_M ρ(Î - I) + λ_mask mean σ(A - M),   ρ(r) = √(r² + ε²) - ε,   σ(r) = c² log(1 + r²/c²)

The colour term ρ (Charbonnier, a smooth L1) is taken inside the mask only,
off its one-pixel edge band: edge pixels blend the object with a background
the model does not hold, and outside the mask a render's colour says nothing
the silhouette term does not (and a hand cut out of the mask would pull the
pose through it). The silhouette term compares the alpha A with the mask
coverage M; it widens the basin (the hinge lid comes back from 50° off). It
is squared on every level, then the finest level is fitted again with the
Cauchy loss σ: an occluder cut out of the mask costs little there, and the
soft edges of a render against a binary mask bias it less. Each part ``k``
gets a twist ``ξ_k = [ω_k, v_k / r]`` (``r`` the object radius, so both
halves are of order one) that turns it about its centre ``c_k`` and moves
it: ``μ' = exp(ω) (P μ - c) + c + v``. The gradient comes from
:meth:`~marionette.render.backward.RenderWithGrad.backward` with one group
per part and pivot ``c + v`` (the left-perturbation gradient), mapped to ξ
by the left Jacobian of SO(3), so it is exact and L-BFGS (scipy) minimises
L. The fit runs coarse to fine over an image pyramid (halving the working
resolution per level), each level starting from the last one's answer.

A part hinged on another (:mod:`.joints`, the extraction's hinges) moves
with its body and turns about the axis by one angle ``θ``: the pose
``exp(θ a) (μ - p) + p`` after the body's twist, with ``a`` and ``p`` the
axis and its point where the moved body puts them. Its left gradient about
``p`` gives ``∂L/∂θ = g_ω · a``, and, moved to the body's pivot, joins the
body's own (:func:`joint_gradient`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import minimize

from ..errors import InputError
from ..gaussians import Gaussians
from ..geometry import axis_angle_to_matrix, so3_left_jacobian, transform_points
from ..progress import ProgressCallback
from ..render import render
from ..render.backward import render_with_grad
from ._init import pose_gaussians
from ._views import FitView, make_view
from .joints import Hinge, check_hinges, snap_to_hinges
from .shading import Shading

__all__ = ["AlignOptions", "Alignment", "align_poses", "align_frame", "frame_pyramid", "frame_loss", "move_parts",
           "move_joints", "joint_gradient", "rms_radius", "twist_loss", "twist_gradient"]


@dataclass(frozen=True)
class AlignOptions:
    """Settings of :func:`align_poses`.

    Attributes
    ----------
    max_side : int
        Long side of the frames at the finest level, before cropping to the object.
    levels : int
        Pyramid levels; each coarser one halves the resolution. More than two
        bias the answer: at a quarter of the resolution the Gaussians are
        below a pixel and the rasterizer's 0.3 px low-pass fattens thin parts.
    iterations : int
        L-BFGS iterations per level, and at most three times as many loss evaluations.
    mask_weight : float
        ``λ_mask`` of the silhouette term.
    charbonnier : float
        ``ε`` of the Charbonnier loss, in [0, 1] colour units:
        residuals well above it count linearly.
    max_step : float
        Bound on each twist component per level: radians of rotation, and
        object radii of translation.
    silhouette_scale : float
        ``c`` of the finest level's robust silhouette pass (alpha units);
        ``inf`` skips that pass.
    """

    max_side: int = 240
    levels: int = 2
    iterations: int = 30
    mask_weight: float = 0.3
    charbonnier: float = 0.03
    max_step: float = 0.5
    silhouette_scale: float = 0.25

    def check(self) -> None:
        """Raise :class:`InputError` naming the first setting out of range."""
        if not 16 <= self.max_side <= 8192:
            raise InputError(f"align max_side must be within 16..8192, got {self.max_side}")
        if not 1 <= self.levels <= 6 or not 1 <= self.iterations <= 10_000:
            raise InputError("align levels must be within 1..6 and iterations within 1..10000")
        if self.mask_weight < 0 or not self.charbonnier > 0 or not self.max_step > 0 \
                or not self.silhouette_scale > 0:
            raise InputError("align mask_weight must be >= 0, charbonnier, max_step and silhouette_scale > 0")


@dataclass(frozen=True)
class Alignment:
    """Poses after photometric refinement.

    Attributes
    ----------
    poses : (K, T, 4, 4) float64, the refined poses (frames not aligned are unchanged).
    loss_before, loss_after : (T,) float64
        Loss of each frame at the finest level before and after (NaN where not aligned).
    frames : list of int, the aligned frames.
    """

    poses: np.ndarray
    loss_before: np.ndarray
    loss_after: np.ndarray
    frames: list = field(default_factory=list)


def rms_radius(gaussians: Gaussians) -> float:
    """RMS distance (float) of the Gaussians' means (N, 3) from their mean: the scale of a twist's translation."""
    means = gaussians.means
    return float(np.sqrt(np.mean(np.sum((means - means.mean(axis=0)) ** 2, axis=1))))


def move_parts(poses: np.ndarray, x: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """Poses (K, 4, 4) moved by twists x (K, 6) ``[ω, v / radius]`` about centres (K, 3):
    ``μ' = exp(ω) (P μ - c) + c + v``."""
    rot = axis_angle_to_matrix(x[:, :3])  # (K, 3, 3)
    out = poses.copy()
    out[:, :3, :3] = rot @ poses[:, :3, :3]
    out[:, :3, 3] = np.einsum("kij,kj->ki", rot, poses[:, :3, 3] - centres) + centres + x[:, 3:] * radius
    return out


def _interior(cover: np.ndarray) -> np.ndarray:
    """(H, W) float32 weights of the colour term: 1 inside the mask, off its one-pixel edge band, else 0.

    Edge pixels mix the object with a background the model does not hold, and
    a binary mask cuts them at an arbitrary level; left in, their colour pulled
    a test box's pose by a tenth of a degree.
    """
    inside = (cover > 0.5).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    return cv2.erode(inside, kernel).astype(np.float32)


def _silhouette(a_res: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Cauchy cost ``c² log(1 + r²/c²)`` of alpha residuals r (H, W) and its derivative; squared for c = inf."""
    if not np.isfinite(scale):
        return a_res * a_res, 2 * a_res
    c2 = scale * scale
    return c2 * np.log1p(a_res * a_res / c2), 2 * a_res / (1 + a_res * a_res / c2)


def frame_loss(gaussians: Gaussians, parts: np.ndarray, poses: np.ndarray, view: FitView, options: AlignOptions,
               pivots: np.ndarray | None = None, scale: float = np.inf) -> tuple[float, np.ndarray | None]:
    """Loss of one view with the Gaussians (N, parts (N,)) moved by poses (K, 4, 4).

    With ``pivots`` (K, 3), also the gradient (K, 6) with respect to a
    left-multiplied twist ``[ω, v]`` of each part about its pivot. ``scale``:
    ``c`` of the Cauchy silhouette term (``inf``: squared).
    """
    posed = pose_gaussians(gaussians, parts, poses)
    # The plain forward when no gradient is asked for: the same image, without keeping the backward's state.
    with_grad = render_with_grad(posed, view.camera, (1.0, 1.0, 1.0)) if pivots is not None else None
    out = with_grad.output if with_grad is not None else render(posed, view.camera, (1.0, 1.0, 1.0))
    res = (out.image - view.target) * _interior(view.mask)[..., None]  # (H, W, 3)
    a_res = out.alpha - view.mask  # (H, W)
    eps = options.charbonnier
    root = np.sqrt(res * res + eps * eps)
    cost, slope = _silhouette(a_res, scale)
    loss = float((root - eps).mean() + options.mask_weight * cost.mean())
    if pivots is None:
        return loss, None
    grads = with_grad.backward(res / root / res.size, (options.mask_weight / a_res.size) * slope,
                         groups=[parts == k for k in range(len(poses))], pivot=pivots)
    return loss, grads.pose


def move_joints(poses: np.ndarray, x: np.ndarray, centres: np.ndarray, radius: float,
                hinges: Sequence[Hinge] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Poses (K, 4, 4) moved by twists x (K, 6) as :func:`move_parts`, except that a hinged part moves with
    its body and then turns by ``x[part, 0]`` radians about its axis (its other entries are unused).

    Returns the moved poses (K, 4, 4) and the pivots (K, 3) of the gradients :func:`joint_gradient` takes:
    the moved centres, and a hinged part's axis point.
    """
    x_body, c_body = x.copy(), np.array(centres, dtype=np.float64)
    for h in hinges:
        x_body[h.part], c_body[h.part] = x[h.body], centres[h.body]
    moved = move_parts(poses, x_body, c_body, radius)
    pivots = c_body + x_body[:, 3:] * radius
    for h in hinges:
        axis, point = moved[h.body, :3, :3] @ h.axis, transform_points(moved[h.body], h.point)
        rot = axis_angle_to_matrix(x[h.part, 0] * axis)
        moved[h.part, :3, :3] = rot @ moved[h.part, :3, :3]
        moved[h.part, :3, 3] = rot @ (moved[h.part, :3, 3] - point) + point
        pivots[h.part] = point
    return moved, pivots


def joint_gradient(g: np.ndarray, x: np.ndarray, radius: float, moved: np.ndarray, pivots: np.ndarray,
                   hinges: Sequence[Hinge] = ()) -> np.ndarray:
    """Gradient (K, 6) with respect to x (K, 6) of :func:`move_joints`, from the gradient g (K, 6) with respect
    to a left-multiplied twist ``[ω, v]`` of each part about its pivot (K, 3); ``moved`` (K, 4, 4) are the
    moved poses. A hinged part's row is ``[d/dθ, 0, 0, 0, 0, 0]``."""
    g = np.array(g, dtype=np.float64)
    angle = {}
    for h in hinges:
        angle[h.part] = g[h.part, :3] @ (moved[h.body, :3, :3] @ h.axis)  # its pivot is on the moved axis
        # The part moves with its body: its gradient joins the body's, moved to the body's pivot.
        g[h.body, :3] += g[h.part, :3] + np.cross(pivots[h.part] - pivots[h.body], g[h.part, 3:])
        g[h.body, 3:] += g[h.part, 3:]
    grad = twist_gradient(g, x, radius)
    for part, value in angle.items():
        grad[part] = [value, 0, 0, 0, 0, 0]
    return grad


def twist_loss(gaussians: Gaussians, parts: np.ndarray, poses: np.ndarray, x: np.ndarray, centres: np.ndarray,
               radius: float, view: FitView, options: AlignOptions, scale: float = np.inf,
               hinges: Sequence[Hinge] = ()) -> tuple[float, np.ndarray]:
    """Loss of one view with poses (K, 4, 4) moved by twists x (K, 6) (:func:`move_joints`), and its gradient
    (K, 6) (:func:`joint_gradient`); ``scale``: the silhouette term's (see :func:`frame_loss`)."""
    moved, pivots = move_joints(poses, x, centres, radius, hinges)
    loss, g = frame_loss(gaussians, parts, moved, view, options, pivots=pivots, scale=scale)
    return loss, joint_gradient(g, x, radius, moved, pivots, hinges)


def twist_gradient(g: np.ndarray, x: np.ndarray, radius: float) -> np.ndarray:
    """Gradient (K, 6) with respect to the twists x (K, 6) of :func:`move_parts`, from the gradient g (K, 6)
    with respect to a left-multiplied twist ``[ω, v]`` about the moved centres ``c + v``."""
    grad = np.empty_like(g)
    # exp(ω + δ) ≈ exp(J_l(ω) δ) exp(ω): the left-perturbation gradient times J_l.
    grad[:, :3] = np.einsum("kji,kj->ki", so3_left_jacobian(x[:, :3]), g[:, :3])
    grad[:, 3:] = g[:, 3:] * radius
    return grad


class _OutOfEvaluations(Exception):
    """An alignment stage used its budget of loss evaluations (3 per L-BFGS iteration)."""


def align_frame(gaussians: Gaussians, parts: np.ndarray, poses: np.ndarray, pyramid: Sequence[FitView],
                movable: np.ndarray, radius: float, options: AlignOptions,
                hinges: Sequence[Hinge] = ()) -> tuple[np.ndarray, float, float]:
    """Refine one frame's poses (K, 4, 4) of the parts marked ``movable`` (K,) bool, coarse to fine.

    ``pyramid`` lists the frame's views from coarsest to finest. A hinged part
    (``hinges``, its pose on the hinge) moves with its body and, if movable,
    turns about its axis: one angle. Returns the refined poses (K, 4, 4) and
    the finest level's loss before and after; the poses are returned
    unchanged when they did not lower that loss.
    """
    poses = start = np.asarray(poses, dtype=np.float64)
    k_count = len(poses)
    means = gaussians.means.astype(np.float64)
    # Each part's centre at this frame: the mean of its moved Gaussians (the origin if it has none).
    centres = np.zeros((k_count, 3))
    for k in range(k_count):
        mine = means[parts == k]
        if len(mine):
            centres[k] = poses[k, :3, :3] @ mine.mean(axis=0) + poses[k, :3, 3]
    # The entries of the twists x (K, 6) that are fitted: all six of a free part, a hinged part's angle.
    fitted = np.zeros((k_count, 6), bool)
    fitted[np.asarray(movable, bool)] = True
    for h in hinges:
        fitted[h.part, 1:] = False
    fine = options.silhouette_scale
    before = frame_loss(gaussians, parts, poses, pyramid[-1], options, scale=fine)[0]
    if not fitted.any():
        return poses, before, before
    # Every level with the squared silhouette (a wide basin), then the finest again with the robust one
    # (occluders, accuracy).
    stages = [(view, np.inf) for view in pyramid] + ([(pyramid[-1], fine)] if np.isfinite(fine) else [])
    for view, scale in stages:
        best = {"loss": np.inf, "x": np.zeros(fitted.sum()), "evaluations": 0}

        def objective(flat: np.ndarray, view: FitView = view, best: dict = best,
                      scale: float = scale) -> tuple[float, np.ndarray]:
            # Where the loss is rough (a model that barely overlaps the frame) its gradient misleads the
            # line searches, which then take up to 20 evaluations, each a render and its backward pass.
            if best["evaluations"] == 3 * options.iterations:
                raise _OutOfEvaluations
            best["evaluations"] += 1
            x = np.zeros((k_count, 6))
            x[fitted] = flat
            loss, grad = twist_loss(gaussians, parts, poses, x, centres, radius, view, options, scale, hinges)
            if loss < best["loss"]:
                best.update(loss=loss, x=flat.copy())
            return loss, grad[fitted]

        # A box on the twist keeps a line search from leaping to a far pose that happens to score lower
        # (an occluder can make one): a refinement starts within tens of degrees of the answer.
        bounds = [(-options.max_step, options.max_step)] * int(fitted.sum())
        try:
            minimize(objective, np.zeros(fitted.sum()), jac=True, method="L-BFGS-B", bounds=bounds,
                     options={"maxiter": options.iterations, "ftol": 1e-10, "gtol": 1e-9})
        except _OutOfEvaluations:
            pass  # the best twist seen is kept, as after a normal stop
        x = np.zeros((k_count, 6))
        x[fitted] = best["x"]
        poses = move_joints(poses, x, centres, radius, hinges)[0]
        centres = centres + x[:, 3:] * radius  # a hinged part's centre is not used: it turns about its axis
    after = frame_loss(gaussians, parts, poses, pyramid[-1], options, scale=fine)[0]
    if after > before:  # the coarse levels led astray and the finest did not come back: keep the start
        return start, before, before
    return poses, before, after


def frame_pyramid(image: np.ndarray, mask: np.ndarray, K: np.ndarray, scale: float, levels: int,
                  t: int) -> list[FitView]:
    """Views of frame ``t`` (image (H, W, 3) uint8, mask (H, W) bool, intrinsics K (3, 3)) from coarsest to
    finest, the finest at ``scale`` of the frame's resolution."""
    return [make_view(t, image, mask, K, scale / 2 ** level) for level in reversed(range(levels))]


def align_poses(gaussians: Gaussians, parts: np.ndarray, frames, masks, K: np.ndarray, poses: np.ndarray, *,
                frames_to_align: Sequence[int] | None = None, movable: np.ndarray | None = None,
                shading: Shading | None = None, hinges: Sequence[Hinge] = (),
                options: AlignOptions = AlignOptions(), progress: ProgressCallback | None = None) -> Alignment:
    """Refine per-part poses photometrically against the frames.

    Parameters
    ----------
    gaussians : Gaussians, N of them, at frame 0 (camera frame of frame 0).
    parts : (N,) int, each Gaussian's part (0..K-1).
    frames : (T, H, W, 3) uint8 array or VideoFrames.
    masks : (T, H, W) bool array or PackedMasks.
    K : (3, 3) intrinsics of the frames.
    poses : (K, T, 4, 4) float, frame 0 → frame t per part, in the camera frame of frame t
        (what the Gaussians are moved by to be rendered in frame t).
    frames_to_align : sequence of int, optional
        Default: every frame but 0 (whose poses define the model's frame) where the object is seen.
    movable : (K,) bool, optional
        Parts whose poses may change (default all).
    shading : Shading, optional
        A shaded reconstruction's (``Reconstruction.shading``): each frame is
        compared with the Gaussians shaded as they face the light at that
        frame's starting poses, then, from the refined poses, shaded as those
        face it on the finest level again (the shading's own pose gradient is
        left out). Without it the Gaussians keep their own colours.
    hinges : sequence of Hinge, optional
        Parts hinged on others (:func:`~marionette.reconstruct.joints.hinges_from_metadata` reads them from
        a prior's ``metadata["joints"]``): in each aligned frame, each is put on its hinge
        (:func:`~marionette.reconstruct.joints.snap_to_hinges`), moves with its body and turns about its
        axis by one fitted angle, so it stays on its hinge.
    options : AlignOptions
    progress : callable ``(done, total)``, optional, after each frame.

    Returns
    -------
    Alignment
    """
    options.check()
    poses = np.array(poses, dtype=np.float64)
    parts = np.asarray(parts)
    if poses.ndim != 4 or poses.shape[2:] != (4, 4) or len(parts) != len(gaussians.means) or \
            (len(parts) and not 0 <= parts.min() <= parts.max() < len(poses)):
        raise InputError("align_poses: poses must be (K, T, 4, 4) and parts (N,) indices into the K parts")
    k_count, t_count = poses.shape[:2]
    hinges = check_hinges(hinges, k_count)
    movable = np.ones(k_count, bool) if movable is None else np.asarray(movable, bool)
    h, w = np.asarray(masks[0]).shape
    scale = min(1.0, options.max_side / max(w, h))
    radius = rms_radius(gaussians)
    todo = list(range(1, t_count)) if frames_to_align is None else [int(t) for t in frames_to_align]
    before, after = np.full(t_count, np.nan), np.full(t_count, np.nan)
    done = []
    for i, t in enumerate(todo):
        mask = np.asarray(masks[t], bool)
        if mask.any():
            poses[:, t] = snap_to_hinges(poses[:, t:t + 1], hinges)[:, 0]
            pyramid = frame_pyramid(np.asarray(frames[t]), mask, K, scale, options.levels, t)
            model = gaussians if shading is None else shading.lit(gaussians, parts, poses[:, t, :3, :3])
            poses[:, t], before[t], after[t] = align_frame(model, parts, poses[:, t], pyramid, movable,
                                                           max(radius, 1e-9), options, hinges)
            if shading is not None:  # lit as the refined pose faces the light, the finest level once more
                model = shading.lit(gaussians, parts, poses[:, t, :3, :3])
                poses[:, t], _, after[t] = align_frame(model, parts, poses[:, t], pyramid[-1:], movable,
                                                       max(radius, 1e-9), options, hinges)
            done.append(t)
        if progress:
            progress(i + 1, len(todo))
    return Alignment(poses, before, after, done)
