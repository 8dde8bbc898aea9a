"""Frames the tracks lose, recovered by aligning a model of the object to them.

Fast or blurred frames cut the LK tracks: too few lifted points remain for
PnP (or a handful survive and give a poor pose), the frame would be
interpolated, and the tracks born there lifted with a guessed pose that
carries its error into every later frame. Instead, the object is lifted
from the last frame the tracks held well (its mask and colours,
:func:`~marionette.target.lift.lift_image`, with the relief of the fitted
points seen there and the depth of the body's centroid), taken to frame 0
by the inverse of that pose, and aligned photometrically to the lost frame
(:func:`~marionette.reconstruct.align.align_frame`: colour and silhouette,
coarse to fine) from a pose extrapolated from its neighbours (or the weak
PnP pose), and if that fails from the model frame's own pose. The result
is kept when the aligned model covers the frame's mask well (silhouette
IoU); otherwise the frame stays failed, with the reason.

Not the nearest frame with a pose as the model: a lost frame is usually
blurred, and the next blurred frame agrees with its blurred model all the
same, so a chain of them drifts (``docs/benchmarks/recover.md``).

The rigid fit (:func:`~marionette.source.rigid.fit_rigid`) lifts the tracks
born in a recovered frame with its pose and holds that pose in the bundle
adjustment, where those tracks tie the frames after a gap in the tracks to
the frames before it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.interpolate import griddata
from scipy.spatial import QhullError

from ..camera import Camera
from ..gaussians import Gaussians
from ..geometry import invert_transform, transform_points
from ..reconstruct._init import pose_gaussians
from ..reconstruct._views import FitView
from ..reconstruct.align import AlignOptions, align_frame, frame_pyramid, rms_radius
from ..render import render
from ..target.lift import LiftOptions, lift_image

__all__ = ["RecoverOptions", "FrameRecovery"]


@dataclass(frozen=True)
class RecoverOptions:
    """Settings of :class:`FrameRecovery`.

    Attributes
    ----------
    cells : int
        About this many lift cells on the model (its stride follows the mask's area).
    max_area : float
        A relief from the fitted points is kept while the lifted surface holds at most this many times the
        mask's area (a smooth body's front, back and walls hold 4-5 times it).
    min_iou : float
        Silhouette IoU between the aligned model and the frame's mask below which the frame stays failed.
        Synthetic recoveries reach 0.94-0.99; on the hand-held backpack clip with automatic masks, weak
        frames aligned at 0.81-0.89 moved its turn by tens of degrees.
    min_gain : float
        A measured pose (``replace``) gives way to the alignment only when this raises the IoU by this much:
        a weak PnP pose is still a measurement, and the one-view model's own error is of its size.
    align : AlignOptions
        The photometric alignment.
    """

    cells: int = 2500
    max_area: float = 8.0
    min_iou: float = 0.9
    min_gain: float = 0.02
    align: AlignOptions = AlignOptions(iterations=8)


class FrameRecovery:
    """Aligns frames of one rigid body the tracks lost to a model lifted from a frame they kept.

    Parameters
    ----------
    frames : (T, H, W, 3) uint8, indexable per frame.
    masks : (T, H, W) bool, indexable per frame: the body's pixels.
    K : (3, 3) intrinsics.
    centroid : (3,) the body's centroid at frame 0 (camera frame 0).
    options : RecoverOptions
    """

    def __init__(self, frames, masks, K: np.ndarray, centroid: np.ndarray,
                 options: RecoverOptions = RecoverOptions()) -> None:
        self.frames, self.masks, self.K = frames, masks, np.asarray(K, np.float64)
        self.centroid = np.asarray(centroid, np.float64)
        self.options = options
        self._models: dict[tuple[int, bytes], tuple[Gaussians, float]] = {}  # (frame, its pose) → model

    def _model(self, source: int, pose: np.ndarray, uv: np.ndarray,
               depth: np.ndarray) -> tuple[Gaussians, float] | None:
        """The body lifted from frame ``source`` and moved to frame 0 by the inverse of its pose (4, 4),
        with its RMS radius; None when the body is not seen there. Its relief follows the depths (n,) of the
        fitted points at pixels uv (n, 2) where there are enough of them, else the silhouette's."""
        key = (source, pose.tobytes())  # a refinement may have moved the frame since
        if key not in self._models:
            mask = np.asarray(self.masks[source], bool)
            inner = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            mask = inner if inner.sum() >= 16 else mask
            if mask.sum() < 16:
                return None
            h, w = mask.shape
            centre_depth = float(transform_points(pose, self.centroid[None])[0, 2])
            stride = max(1, int(round(np.sqrt(mask.sum() / self.options.cells))))
            camera = Camera(self.K, np.eye(4), w, h)
            lift = LiftOptions(depth=centre_depth, stride=stride, solids=False)
            image = np.asarray(self.frames[source])
            lifted = lift_image(image, mask=mask, camera=camera, depth_map=_depth_map(mask, uv, depth), options=lift)
            if len(lifted.gaussians) > self.options.max_area * mask.sum() / stride ** 2:
                # Points fitted badly (after a gap) make a rough relief whose walls hold many times the
                # body's area, in Gaussians to render at every step: take the silhouette's relief instead.
                lifted = lift_image(image, mask=mask, camera=camera, options=lift)
            g = pose_gaussians(lifted.gaussians, np.zeros(len(lifted.gaussians), np.int64),
                               invert_transform(pose)[None])
            self._models[key] = (g, rms_radius(g))
        return self._models[key]

    def __call__(self, t: int, source: int, source_pose: np.ndarray, guess: np.ndarray, uv: np.ndarray,
                 depth: np.ndarray, replace: bool = False) -> tuple[np.ndarray | None, str]:
        """Align frame ``t`` to the model of frame ``source`` (pose (4, 4)) from the pose ``guess`` (4, 4);
        ``uv`` (n, 2) and ``depth`` (n,): the fitted points seen in frame ``source``, their pixels and depths.
        ``replace``: the guess is a measured pose, kept unless the alignment covers the mask clearly better.

        Returns the aligned pose (4, 4) or None, and a note (what was done, or why it failed).
        """
        mask = np.asarray(self.masks[t], bool)
        if mask.sum() < 16:
            return None, "the object is not in view"
        model = self._model(source, source_pose, uv, depth)
        if model is None:
            return None, f"the object is not in view at frame {source}, the model's source"
        gaussians, radius = model
        labels = np.zeros(len(gaussians), np.int64)
        h, w = mask.shape
        options = self.options.align
        scale = min(1.0, options.max_side / max(w, h))
        pyramid = frame_pyramid(np.asarray(self.frames[t]), mask, self.K, scale, options.levels, t)
        need = self.options.min_iou
        if replace:
            need = max(need, _iou(gaussians, guess[None], pyramid[-1]) + self.options.min_gain)
        # From the guess, then, if that fails, from the source frame's own pose: a constant-velocity guess
        # overshoots when the last steps were a wrong pose's (seen at the end of a real clip: 40° and more).
        # A measured guess (``replace``) is not second-guessed.
        starts = [("the guess", guess)] + ([] if replace else [("its pose", source_pose)])
        best, best_iou, start = None, -1.0, "the guess"
        for label, pose in starts:
            poses, _, _ = align_frame(gaussians, labels, pose[None], pyramid, np.ones(1, bool), max(radius, 1e-9),
                                      options)
            iou = _iou(gaussians, poses, pyramid[-1])
            if iou > best_iou:
                best, best_iou, start = poses[0], iou, label
            if best_iou >= need:
                break
        if best_iou < need:
            return None, (f"aligning the model of frame {source} left a silhouette IoU of {best_iou:.2f}, "
                          f"need {need:.2f}")
        return best, f"aligned to the model of frame {source} from {start} (silhouette IoU {best_iou:.2f})"


def _iou(gaussians: Gaussians, poses: np.ndarray, view: FitView) -> float:
    """Silhouette IoU between the Gaussians (one part) moved by poses (1, 4, 4) and the view's mask."""
    covered = render(pose_gaussians(gaussians, np.zeros(len(gaussians), np.int64), poses), view.camera,
                     (1.0, 1.0, 1.0)).alpha > 0.5
    inside = view.mask > 0.5
    return float((covered & inside).sum() / max((covered | inside).sum(), 1))


def _depth_map(mask: np.ndarray, uv: np.ndarray, depth: np.ndarray, min_points: int = 12) -> np.ndarray | None:
    """(H, W) depth over the mask (H, W) bool, interpolated from depths (n,) at pixels uv (n, 2) (linear
    inside their hull, nearest outside; NaN off the mask); None with fewer than ``min_points``."""
    h, w = mask.shape
    inside = (np.isfinite(depth) & (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1)
              & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1))
    uv, depth = uv[inside], depth[inside]
    if len(uv) < min_points:
        return None
    ys, xs = np.nonzero(mask)
    pixels = np.column_stack([xs, ys]).astype(np.float64)
    try:
        values = griddata(uv, depth, pixels, method="linear")
    except QhullError:  # all points on a line
        values = np.full(len(pixels), np.nan)
    hole = np.isnan(values)
    values[hole] = griddata(uv, depth, pixels[hole], method="nearest")
    out = np.full((h, w), np.nan)
    out[ys, xs] = values
    return out
