"""Self-transfer evaluation: the protocol of Motion Marionette's Table 1 (Sec. 5.2).

The first source frame is the target; its transferred video should reproduce
the source. We lift frame 0 so that its reference camera *is* the source
camera and the object sits where the prior put the source object (its
frame-0 centroid depth), apply the prior literally in the source world frame
(``anchor="world"``, paper Eq. 5: the target's points are the source's), and
render with the source camera at the source resolution on white. Each frame
is compared with the source frame masked onto white.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import cv2
import numpy as np

from .. import pipeline
from ..camera import Camera
from ..errors import InputError
from ..io import read_video, write_video
from ..io.atomic import atomic_path, check_output_dir, write_text
from ..io.video import write_masks
from ..prior import SpatPrior
from ..progress import Reporter
from ..reconstruct import ReconstructOptions, reconstruct_object
from ..segment import Prompt
from ..source import ExtractOptions, extract_prior
from ..target.lift import LiftedTarget, LiftOptions, lift_image
from .fidelity import motion_fidelity
from .lpips import LPIPS, find_weights
from .metrics import LPIPS_SKIPPED, frame_metrics, on_white
from .silhouette import SilhouetteReport, silhouette_frame

__all__ = ["eval_self", "self_target", "EVAL_EXTRACT", "EVAL_SELF_OUTPUTS", "EVAL_TARGETS"]

#: What ``eval_self`` moves: the object reconstructed from the whole video
#: (:func:`~marionette.reconstruct.reconstruct_object`), or source frame 0 lifted alone.
EVAL_TARGETS = ("reconstruction", "frame0")

#: Extraction settings of the evaluation: the motion as the source camera saw
#: it (camera motion kept in the prior), since the render uses that camera,
#: fixed, as the paper does.
EVAL_EXTRACT = ExtractOptions(camera_motion=False)

#: The files :func:`eval_self` writes into its output folder, by kind.
EVAL_SELF_OUTPUTS = {"video": "video.mp4", "metrics": "metrics.json", "frames": "frames.csv",
                     "side_by_side": "side_by_side.mp4", "metrics_plot": "metrics.png"}


def self_target(image: np.ndarray, mask: np.ndarray, prior: SpatPrior, *, inset: int = 1) -> LiftedTarget:
    """Lift source frame 0 (H, W, 3) with its mask (H, W) into the source's world frame.

    The reference camera is the source camera (the prior's intrinsics and
    image size, at the world origin) and the object's mid-surface sits at
    the depth of the prior's frame-0 centroid (weighted by part size), so
    the target's points are the source object's points at frame 0.

    ``inset``: pixels taken off the mask's outline before lifting. A splat
    covers about a pixel around its centre, and the volume's walls stack
    several at the outline, so a lift of the full mask renders a silhouette
    ~1.5 px wider than the mask; one pixel in, it matches
    (``docs/benchmarks/table1.md``).
    """
    w, h = (int(v) for v in prior.image_size)
    camera = Camera(prior.intrinsics, np.eye(4), w, h)
    depth = float(np.average(prior.centroids[:, 0, 2], weights=prior.radii ** 2))
    mask = np.asarray(mask, dtype=bool)
    if inset > 0:
        inner = cv2.erode(mask.astype(np.uint8), np.ones((2 * inset + 1,) * 2, np.uint8)).astype(bool)
        mask = inner if inner.any() else mask  # a sliver of an object keeps its pixels
    return lift_image(image, mask=mask, camera=camera, options=LiftOptions(depth=depth))


def eval_self(source: str | Path, masks: str | Path | None = None, output_dir: str | Path = "eval-self", *,
              max_side: int = pipeline.DEFAULT_MAX_SIDE, focal: float | str | None = "auto",
              options: ExtractOptions = EVAL_EXTRACT,
              fidelity: bool = True, target: str = "reconstruction",
              reconstruct_options: ReconstructOptions = ReconstructOptions(),
              prompt: Prompt | None = None, masks_out: str | Path | None = None,
              reporter: Reporter | None = None) -> dict:
    """Self-transfer of a source video, scored against the source (paper Table 1).

    Parameters
    ----------
    source : video file or folder of frames.
    masks : folder of per-frame mask PNGs (non-zero = object), or None for
        the object ``prompt`` picks on frame 0 (original pixels), or else
        automatic masks (:func:`~marionette.pipeline.source_masks`).
    output_dir : folder, created if needed. Written (each file atomically;
        names in :data:`EVAL_SELF_OUTPUTS`): ``video.mp4`` (the render),
        ``metrics.json``, ``frames.csv`` (per-frame PSNR and SSIM),
        ``side_by_side.mp4`` (masked source | render) and ``metrics.png``
        (metrics over time).
    max_side : frames are downscaled to this long side (intrinsics follow).
    focal : the source camera's focal length in pixels of the original video;
        ``"auto"`` (default) estimates it from the object's motion, as the
        paper's reconstruction recovers its camera from the video
        (:mod:`~marionette.source.focal`); None: a 60° horizontal field of view.
    options : extraction settings; by default the prior keeps the camera's
        own motion (:data:`EVAL_EXTRACT`).
    fidelity : also report :func:`~marionette.eval.fidelity.motion_fidelity`
        of the render to the masked source.
    target : ``"reconstruction"`` (default): the source object reconstructed
        from every frame with the extracted prior, each part moved by its
        poses; ``"frame0"``: source frame 0 lifted alone (:func:`self_target`),
        moved by the prior in the source world frame (the paper's protocol).
    reconstruct_options : settings of the reconstruction.
    masks_out : folder to write the masks used to (one PNG per frame), or None.

    Returns
    -------
    dict, the content of ``metrics.json``: means ``psnr`` (dB), ``ssim``,
    ``lpips`` (when weights are found, see :mod:`~marionette.eval.lpips`;
    else None, with ``lpips_skipped`` saying why), ``motion_fidelity``,
    ``silhouette`` (the render's alpha against the masks, every frame in
    full: :class:`~marionette.eval.silhouette.SilhouetteReport`),
    ``failed_frames`` (the part-frames whose poses were interpolated)
    and the clip's size. The image metrics are computed from ``video.mp4`` as
    written (decoded back), so they include the codec's loss and agree with
    any recomputation from the files.
    """
    reporter = reporter or Reporter(quiet=True)
    if target not in EVAL_TARGETS:
        raise InputError(f"target must be one of {', '.join(EVAL_TARGETS)}, got {target!r}")
    out = check_output_dir(output_dir)
    video = read_video(source, max_side=max_side)
    frames = video.frames
    t, h, w = frames.shape[:3]
    mask_stack = pipeline.source_masks(video, masks, prompt, reporter=reporter)
    if masks_out is not None:
        write_masks(masks_out, mask_stack)
    focal_px, options = pipeline.focal_setting(focal, options, video.scale)
    prior = extract_prior(frames, mask_stack, pipeline.source_intrinsics(w, h, focal_px), video.fps, options=options,
                          reporter=reporter)
    out.mkdir(exist_ok=True)
    files = {kind: out / name for kind, name in EVAL_SELF_OUTPUTS.items()}
    fit = None  # how well the reconstruction explains the frames it was fitted to
    if target == "frame0":
        lifted = self_target(frames[0], mask_stack[0], prior)
        gaussians, camera = lifted.gaussians, lifted.camera
        trajectory = pipeline.transfer(prior, lifted, anchor="world")
    else:
        with reporter.stage("reconstruction", reconstruct_options.iterations) as progress:
            rec = reconstruct_object(frames, mask_stack, prior, options=reconstruct_options, progress=progress)
        gaussians, camera = rec.gaussians, Camera(prior.intrinsics, np.eye(4), w, h)
        trajectory = rec.trajectory(prior)
        fit = rec.quality.summary()
    silhouette = np.empty((t, 2))  # per frame: IoU against the mask, share of the frame drawn stray

    def score(i: int, alpha: np.ndarray) -> None:
        silhouette[i] = silhouette_frame(alpha, mask_stack[i])

    pipeline.render_video(files["video"], gaussians, trajectory, camera, fps=video.fps, reporter=reporter,
                          on_alpha=score)
    rendered = read_video(files["video"]).frames[:, :h, :w]  # as written: codec loss included
    reference = on_white(frames, mask_stack)
    with reporter.stage("PSNR and SSIM", 1) as progress:
        psnr, ssim = frame_metrics(reference, rendered)
        progress(1, 1)
    lpips = None
    if find_weights() is not None:
        model = LPIPS()
        lpips = np.empty(t)
        with reporter.stage("LPIPS", t) as progress:
            for i, (a, b) in enumerate(zip(reference, rendered)):
                lpips[i] = model(a, b)
                progress(i + 1, t)
    metrics = {
        "psnr": float(psnr.mean()), "ssim": float(ssim.mean()),
        "lpips": None if lpips is None else float(lpips.mean()),
        **({"lpips_skipped": LPIPS_SKIPPED} if lpips is None else {"lpips_weights": str(model.path)}),
        "motion_fidelity": None,
        "psnr_min": float(psnr.min()), "ssim_min": float(ssim.min()),
        "frames": t, "width": w, "height": h, "fps": video.fps,
        "source": str(source), "masks": None if masks is None else str(masks),
        "target": target,
        "protocol": ("target = source frame 0 with its mask, lifted in the source camera; prior applied in the "
                     "source world frame" if target == "frame0" else
                     "target = the source object reconstructed from every frame with the extracted prior; each part "
                     "moved by its poses") + "; rendered with the source camera on white; compared with source "
                    "frames masked onto white, whole frames",
        "silhouette": SilhouetteReport(silhouette[:, 0], silhouette[:, 1]).summary(),
        "failed_frames": list(prior.metadata.get("failed_frames") or {}),  # "part:frame", poses interpolated
        "recovered_frames": len(prior.metadata.get("recovered_frames") or {}),
        "camera_motion": prior.metadata.get("camera_motion"),
        "focal_px": float(prior.intrinsics[0, 0]), "focal": prior.metadata.get("focal"),
        "joint_fit": prior.metadata.get("joint_fit"), "extract_seconds": prior.metadata.get("timings"),
        **({} if fit is None else {"reconstruction_fit": fit}),
    }
    if fidelity:
        with reporter.stage("motion fidelity", 1):
            try:
                metrics["motion_fidelity"] = motion_fidelity(reference, mask_stack, rendered, None)
            except InputError as e:  # e.g. an object without texture to track: the image metrics still stand
                metrics["motion_fidelity_skipped"] = str(e)
    write_video(files["side_by_side"], pipeline.side_by_side(reference, rendered), video.fps)
    write_text(files["frames"], _frames_csv(psnr, ssim, lpips))
    _plot_metrics(files["metrics_plot"], psnr, ssim, lpips, video.fps, metrics)
    write_text(files["metrics"], json.dumps(metrics, indent=2) + "\n")
    return metrics


def _frames_csv(psnr: np.ndarray, ssim: np.ndarray, lpips: np.ndarray | None) -> str:
    """One row per frame: PSNR, SSIM and, when computed, LPIPS."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["frame", "psnr", "ssim"] + ([] if lpips is None else ["lpips"]))
    for t, (p, s) in enumerate(zip(psnr, ssim)):
        writer.writerow([t, f"{p:.4f}", f"{s:.6f}"] + ([] if lpips is None else [f"{lpips[t]:.6f}"]))
    return buf.getvalue()


def _plot_metrics(path: Path, psnr: np.ndarray, ssim: np.ndarray, lpips: np.ndarray | None, fps: float,
                  metrics: dict) -> None:
    """PSNR, SSIM (and LPIPS when computed) over time, their means dashed (matplotlib object API, Agg)."""
    series = [("PSNR", psnr, " (dB)"), ("SSIM", ssim, "")] + ([] if lpips is None else [("LPIPS", lpips, "")])
    from matplotlib.figure import Figure  # imported here: matplotlib costs every command 0.9 s to load

    fig = Figure(figsize=(8.0, 2.5 * len(series)), dpi=100)
    seconds = np.arange(len(psnr)) / fps
    for row, (name, values, unit) in enumerate(series):
        ax = fig.add_subplot(len(series), 1, row + 1)
        ax.plot(seconds, values, color="C0")
        ax.axhline(values.mean(), color="C1", linestyle="--", label=f"mean {values.mean():.3g}")
        ax.set_ylabel(name + unit)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower left")
    ax.set_xlabel("time (s)")
    name = "/".join(Path(metrics["source"]).parts[-2:])
    fig.suptitle(f"Self-transfer of {name}: {metrics['frames']} frames, "
                 f"{metrics['width']}x{metrics['height']}")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
