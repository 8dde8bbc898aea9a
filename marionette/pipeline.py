"""The whole method as a few library calls; the command line is a thin layer over these.

``extract`` (source video → SpaT prior), ``load_target`` (image or .ply →
Gaussians and a reference camera), ``transfer`` (prior + target →
trajectory), ``render_video`` (trajectory → video file).
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from .camera import MAX_IMAGE_SIDE, Camera, focal_from_fov
from .errors import InputError
from .gaussians import Gaussians
from .io import (
    read_image,
    read_mask,
    read_masks,
    read_ply,
    read_video,
    write_ply,
    write_video,
)
from .io.atomic import atomic_folder
from .io.ply import PLY_FRAME_NAME
from .io.video import DEFAULT_MAX_PIXELS, DEFAULT_MAX_SIDE, open_video, write_masks
from .prior import SpatPrior
from .progress import Reporter
from .render import render
from .render.camera_path import camera_path, keep_in_view, load_camera_path
from .scene import SceneCompositor, clean_plate
from .segment import Prompt, prompted_mask
from .source import ExtractOptions, extract_prior
from .source.depth import read_depth_map, read_depths
from .source.foreground import auto_masks
from .source.prompted import prompted_masks
from .target.lift import LiftedTarget, LiftOptions, alpha_mask, lift_image, object_mask
from .target.mesh import MESH_SUFFIXES, is_mesh_file, mesh_gaussians
from .trajectory import Trajectory
from .transfer.controls import retime, scale_motion
from .transfer.parts import labels_from_seeds, seeds_from_layout
from .transfer.refine import RefineOptions
from .transfer.velocity import integrate

__all__ = ["extract", "source_masks", "reconstruct",
           "load_target", "relative_depth", "check_target", "is_3d_target", "check_part_seeds", "transfer",
           "output_cameras", "fit_view", "scene_compositor", "frames_outside", "frames_unseen", "render_frames",
           "render_video", "write_ply_frames", "side_by_side", "write_side_by_side", "write_preview",
           "source_intrinsics", "focal_setting", "DEFAULT_MAX_SIDE", "PLY_FRAME_NAME"]


def source_intrinsics(width: int, height: int, focal: float | None = None) -> np.ndarray:
    """(3, 3) K for a source of the given size; focal from a 60° horizontal FOV by default."""
    if focal is not None and not (np.isfinite(focal) and focal > 0):
        raise InputError(f"focal must be a positive number of pixels, got {focal}")
    f = focal_from_fov(width) if focal is None else float(focal)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])


def focal_setting(focal: float | str | None, options: ExtractOptions, scale: float) -> tuple[float | None,
                                                                                            ExtractOptions]:
    """``focal`` of the original video (pixels, "auto" or None) → that of the frames read at ``scale``, and the
    extraction settings: "auto" starts from the default and estimates it (``ExtractOptions.estimate_focal``)."""
    if isinstance(focal, str):
        if focal != "auto":
            raise InputError(f"focal must be a positive number of pixels or 'auto', got {focal!r}")
        return None, replace(options, estimate_focal=True)
    return (None if focal is None else focal * scale), options


def source_masks(video, masks: str | Path | None = None, prompt: Prompt | None = None, *, packed: bool = False,
                 reporter: Reporter | None = None):
    """The object masks of a source video (:class:`~marionette.io.video.Video` or an opened one): read from the
    ``masks`` folder, or following the object ``prompt`` picks on the first frame used (in pixels of the
    original video), or found automatically. (T, H, W) bool, or PackedMasks with ``packed``."""
    reporter = reporter or Reporter(quiet=True)
    t, h, w = video.frames.shape[:3]
    if masks is not None:
        if prompt is not None:
            raise InputError("give the object as a mask folder or as a prompt, not both")
        return read_masks(masks, count=t, size=(w, h), indices=video.indices, packed=packed)
    if prompt is not None:
        prompt.check(round(w / video.scale), round(h / video.scale), "first frame")
        with reporter.stage("following the object", t) as progress:
            return prompted_masks(video.frames, prompt.scaled(video.scale), packed=packed, progress=progress)
    with reporter.stage("finding the object", t) as progress:
        return auto_masks(video.frames, packed=packed, progress=progress)


def extract(source: str | Path, *, masks: str | Path | None = None, depth: str | Path | None = None,
            focal: float | str | None = None, max_side: int = DEFAULT_MAX_SIDE,
            max_pixels: int | None = DEFAULT_MAX_PIXELS,
            start: int = 0, end: int | None = None, stride: int = 1, options: ExtractOptions = ExtractOptions(),
            prompt: Prompt | None = None, masks_out: str | Path | None = None,
            reporter: Reporter | None = None) -> SpatPrior:
    """Source video (file or frame folder) → SpaT prior.

    ``masks`` and ``depth`` are folders with one image per source frame (or
    per selected frame); without masks the object is the one ``prompt``
    (points and a box on the first frame used, original pixels) picks, or
    is found automatically. ``masks_out``: a folder to write the masks used
    to (one PNG per selected frame, at the frames' working size).
    ``start``, ``end``, ``stride`` select frames; frames are downscaled to a
    long side of ``max_side``, and further (with a warning) when all frames
    together hold more than ``max_pixels`` pixels. ``focal`` is in pixels of
    the original video (it is scaled with the frames), or ``"auto"``: estimated
    from the object's motion (:mod:`~marionette.source.focal`). Frames are decoded on
    demand and masks kept packed, so memory stays bounded for long videos.
    """
    reporter = reporter or Reporter(quiet=True)
    video = open_video(source, max_side=max_side, max_pixels=max_pixels, start=start, end=end, stride=stride)
    t, h, w = video.frames.shape[:3]
    mask_stack = None
    if masks is not None or prompt is not None or masks_out is not None:
        mask_stack = source_masks(video, masks, prompt, packed=True, reporter=reporter)
    if masks_out is not None:
        write_masks(masks_out, mask_stack)
    depth_stack = None if depth is None else read_depths(depth, count=t, size=(w, h), indices=video.indices,
                                                         lazy=True)
    focal, options = focal_setting(focal, options, video.scale)
    k = source_intrinsics(w, h, focal)
    with contextlib.closing(video.frames):  # stop the decoder however extraction ends
        return extract_prior(video.frames, mask_stack, k, video.fps, depths=depth_stack, options=options,
                             reporter=reporter)


def reconstruct(source: str | Path, *, masks: str | Path | None = None, prior: SpatPrior | None = None,
                focal: float | str | None = None, start: int = 0, end: int | None = None, stride: int = 1,
                extract_options: ExtractOptions = ExtractOptions(), options=None, prompt: Prompt | None = None,
                reporter: Reporter | None = None):
    """Source video (file or frame folder) → the object as Gaussians at frame 0, and the prior used.

    Returns ``(Reconstruction, SpatPrior)``.

    ``start`` and ``end`` select the frames the prior covers; ``stride`` picks
    every ``stride``-th of them (from the first) for fitting, so the others
    can test it. Frames are decoded at the prior's size: a given ``prior``
    must cover the selected frames, and the source, downscaled to the
    prior's long side, must have the prior's image size. Without a
    ``prior`` it is extracted first as :func:`extract` does (``max_side``
    :data:`DEFAULT_MAX_SIDE`, ``focal``, ``extract_options``). Masks are
    read from ``masks``, or follow the object ``prompt`` picks on the first
    frame used, or are found as extraction finds them (:func:`source_masks`).
    ``options`` (:class:`~marionette.reconstruct.ReconstructOptions`) sets
    the fit; its ``max_side`` is the fit's working resolution.
    """
    from .reconstruct import ReconstructOptions, reconstruct_object

    reporter = reporter or Reporter(quiet=True)
    options = options or ReconstructOptions()
    options.check()
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise InputError(f"stride must be a positive integer, got {stride!r}")
    max_side = DEFAULT_MAX_SIDE if prior is None else int(max(prior.image_size))
    video = read_video(source, max_side=max_side, start=start, end=end)
    t, h, w = video.frames.shape[:3]
    if prior is not None:
        if prior.num_frames != t:
            raise InputError(f"the prior has {prior.num_frames} frames but the source has {t} (selected) frames")
        if tuple(int(v) for v in prior.image_size) != (w, h):
            raise InputError(f"the prior is for {prior.image_size[0]}x{prior.image_size[1]} frames but the source's "
                             f"are {w}x{h} at that long side")
    mask_stack = source_masks(video, masks, prompt, reporter=reporter)
    if not np.asarray(mask_stack).any():
        raise InputError("the object is not visible in any frame (every mask is empty)")
    if prior is None:
        focal, extract_options = focal_setting(focal, extract_options, video.scale)
        prior = extract_prior(video.frames, mask_stack, source_intrinsics(w, h, focal), video.fps,
                              options=extract_options, reporter=reporter)
    with reporter.stage("reconstruction", options.iterations) as progress:
        return reconstruct_object(video.frames, mask_stack, prior, frames_used=range(0, t, stride),
                                  options=options, progress=progress), prior


def _camera_for_splats(gaussians: Gaussians, width: int, height: int) -> Camera:
    """A front view (looking down +z) that frames the splats' bulk at half the image width."""
    m = gaussians.means.astype(np.float64)
    c = np.median(m, axis=0)
    r = float(np.sqrt(np.median(((m - c) ** 2).sum(axis=1))))
    cam = Camera.from_fov(width, height)
    dist = 2.0 * r * cam.fx / (0.5 * width) + r
    return cam.with_pose(np.array([[1, 0, 0, -c[0]], [0, 1, 0, -c[1]], [0, 0, 1, -c[2] + dist], [0, 0, 0, 1.0]]))


def relative_depth(prior: SpatPrior, limits: tuple[float, float] = (2.0, 200.0)) -> float:
    """Source camera distance over object radius at frame 0, clipped to ``limits``.

    Lifting the target at the same relative depth gives it the source's
    perspective, so motion toward the camera grows it on screen as it grew
    the source instead of carrying it past the camera.
    """
    centre = prior.centroids[:, 0].mean(axis=0)
    return float(np.clip(np.linalg.norm(centre) / prior.radii.max(), *limits))


def load_target(target: str | Path, *, size: tuple[int, int] | None = None,
                mask: str | Path | np.ndarray | None = None,
                depth: str | Path | None = None, options: LiftOptions = LiftOptions(),
                prior: SpatPrior | None = None, prompt: Prompt | None = None) -> LiftedTarget:
    """Target image (RGB/RGBA), 3DGS ``.ply`` or textured mesh → Gaussians with a reference camera.

    With a ``prior``, an image is lifted at the source's relative depth
    (:func:`relative_depth`) unless ``options`` sets one. ``mask`` is an
    image file marking the object, or that mask as an (H, W) bool array at
    the image's own size (:func:`check_target` finds it) (default: alpha, plain-background key,
    salient-object model, GrabCut; see
    :func:`~marionette.target.lift.object_mask`). ``depth`` is a depth
    map file of the image (16-bit PNG in millimetres, or ``.npy``; any
    unit) that shapes the front surface instead of the inflated silhouette.
    ``prompt`` (points and a box in the image's own pixels) picks the object
    instead of the automatic mask
    (:func:`~marionette.segment.prompt.prompted_mask`). A 3DGS ``.ply`` is
    taken as it is, a mesh (``.glb``, ``.gltf``, ``.obj``, ``.ply`` with
    faces) sampled into surfels (:mod:`~marionette.target.mesh`); either is
    viewed from the front (along +z) at ``size`` (512x512 by default).
    """
    path = Path(target)
    if is_3d_target(path):
        g = mesh_gaussians(path) if is_mesh_file(path) else read_ply(path)
        width, height = size or (512, 512)
        cam = _camera_for_splats(g, width, height)
        uv, z = cam.project(g.means)
        pix = np.clip(np.rint(uv), 0, [width - 1, height - 1]).astype(np.int32)
        mask = np.zeros((height, width), bool)
        mask[pix[z > 0, 1], pix[z > 0, 0]] = True
        return LiftedTarget(g, cam, mask, pix)
    image, object_pixels, depth_map = _read_target_image(path, mask, depth, prompt)
    if prompt is not None:
        scaled = prompt if size is None else prompt.scaled(size[0] / image.shape[1], size[1] / image.shape[0])
    if size is not None and (image.shape[1], image.shape[0]) != tuple(size):
        image = cv2.resize(image, tuple(size), interpolation=cv2.INTER_AREA)
        if object_pixels is not None:
            object_pixels = cv2.resize(object_pixels.view(np.uint8), tuple(size), interpolation=cv2.INTER_NEAREST) > 0
        if depth_map is not None:  # nearest: depths of different surfaces never mix
            depth_map = cv2.resize(depth_map, tuple(size), interpolation=cv2.INTER_NEAREST)
    if prompt is not None:
        object_pixels = prompted_mask(image[..., :3], scaled)
    if prior is not None and options.relative_depth is None:
        options = replace(options, relative_depth=relative_depth(prior))
    return lift_image(image, mask=object_pixels, depth_map=depth_map, options=options)


def _read_target_image(path: Path, mask: str | Path | np.ndarray | None, depth: str | Path | None = None,
                       prompt: Prompt | None = None) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(H, W, 3|4) uint8 target image, its (H, W) bool mask and (H, W) depth map files' content if given; checked
    (a ``prompt`` against the image's size)."""
    image = read_image(path)
    size = (image.shape[1], image.shape[0])
    depth_map = None if depth is None else read_depth_map(depth, size)
    if prompt is not None:
        if mask is not None:
            raise InputError("give the target object as a mask file or as a prompt, not both")
        prompt.check(*size, "target image")
    if mask is None:
        alpha_mask(image)  # a fully transparent image is refused here
        return image, None, depth_map
    object_pixels = mask if isinstance(mask, np.ndarray) else read_mask(mask)
    if object_pixels.shape != image.shape[:2]:
        h, w = object_pixels.shape
        name = "found" if isinstance(mask, np.ndarray) else Path(mask).name
        raise InputError(f"target mask {name} is {w}x{h} "
                         f"but the target image is {image.shape[1]}x{image.shape[0]}")
    return image, object_pixels, depth_map


def check_target(target: str | Path, mask: str | Path | None = None, depth: str | Path | None = None,
                 prompt: Prompt | None = None) -> np.ndarray | None:
    """Reject a target (and its mask and depth files, its prompt) that cannot be lifted, before any long work:
    unreadable, an image with a side outside 16..MAX_IMAGE_SIDE pixels, or one where no object is found.

    Returns the (H, W) bool object mask found in an image given without a mask or a prompt (for
    :func:`load_target`'s ``mask``, so that it is not searched for twice), else None.
    """
    path = Path(target)
    if is_3d_target(path):
        if mask is not None or depth is not None or prompt is not None:
            raise InputError(f"a target mask, prompt or depth map applies to an image target, not to {path.name}")
        mesh_gaussians(path, count=64) if is_mesh_file(path) else read_ply(path)
        return None
    image = _read_target_image(path, mask, depth, prompt)[0]
    if not 16 <= min(image.shape[:2]) <= max(image.shape[:2]) <= MAX_IMAGE_SIDE:
        raise InputError(f"target image {path.name} is {image.shape[1]}x{image.shape[0]} pixels: its sides must be "
                         f"within 16..{MAX_IMAGE_SIDE}")
    if mask is not None or prompt is not None:
        return None
    try:
        return object_mask(image)
    except InputError as e:
        raise InputError(f"target image {path.name}: {e}") from None


def is_3d_target(path: str | Path) -> bool:
    """Whether a target is 3D already (a 3DGS ``.ply`` or a mesh), not a photo to lift."""
    return Path(path).suffix.lower() in MESH_SUFFIXES


def check_part_seeds(prior: SpatPrior, part_seeds: dict[int, tuple[float, float]]) -> None:
    """Raise :class:`InputError` unless every seeded part is one of the prior's."""
    bad = [k for k in part_seeds if not 0 <= k < prior.num_parts]
    if bad:
        raise InputError(f"part seed for part {bad[0]}, but the prior has parts 0..{prior.num_parts - 1}")


def transfer(prior: SpatPrior, target: LiftedTarget, *, frames: int | None = None, speed: float = 1.0,
             loop: str = "hold", reverse: bool = False, rotation_scale: float = 1.0,
             translation_scale: float = 1.0, anchor: str = "centroid", motion: str = "filmed",
             part_seeds: dict[int, tuple[float, float]] | None = None,
             refine: RefineOptions | None = RefineOptions()) -> Trajectory:
    """Move the target as the prior's parts move; (T, N, 3) trajectory out.

    ``motion``: ``"filmed"`` moves it as the source camera saw the object
    move (a camera motion extraction removed is put back: a car a panning
    camera follows turns in view), ``"world"`` as the object moved in the
    world (:meth:`SpatPrior.motion_in`).

    With ``anchor="centroid"`` the motion is taken as seen by a source camera
    aimed at the object (:meth:`SpatPrior.aimed_at_object`), since the target
    sits on its camera's axis. ``speed``, ``frames``, ``loop`` and
    ``reverse`` retime the prior (:func:`~marionette.transfer.controls.retime`);
    the scales multiply its rotation angles and centre displacements.
    Parts are assigned by geodesic flood fill from ``part_seeds`` (part →
    target pixel x, y), or from seeds matched to the source's part layout.
    With several parts, ``refine`` (None: off) refines the velocity field
    and turns the parts about their joints (:mod:`~marionette.transfer.refine`).
    """
    prior = retime(prior.motion_in(motion), speed=speed, frames=frames, loop=loop, reverse=reverse)
    prior = scale_motion(prior, rotation=rotation_scale, translation=translation_scale)
    if anchor == "centroid":
        prior = prior.aimed_at_object()
    if part_seeds:
        check_part_seeds(prior, part_seeds)
        labels = labels_from_seeds(target.gaussians.means, target.pixel_of, part_seeds)
    elif prior.num_parts > 1 and np.ndim(prior.extras.get("labels")) == 2:
        seeds = seeds_from_layout(np.asarray(prior.extras["labels"]), target.mask)
        labels = labels_from_seeds(target.gaussians.means, target.pixel_of, seeds)
    else:
        labels = np.zeros(len(target.gaussians), np.int32)  # one part, or no layout stored: the largest part
    return integrate(target.gaussians.means, labels, prior, anchor=anchor, refine=refine)


def output_cameras(target: LiftedTarget, trajectory: Trajectory, move: str = "static", amount: float | None = None,
                   path: str | Path | None = None, framed: bool = True) -> list[Camera]:
    """One camera per output frame: from a camera-path JSON file, or the reference view with a ``move``.

    ``move`` is static, orbit or dolly with its ``amount`` (see
    :func:`~marionette.render.camera_path.camera_path`). ``framed``: the
    reference view zoomed out to keep the whole motion in frame
    (:func:`fit_view`; an orbit zooms out further to keep its turned path in
    frame too), with a warning if some frames still show nothing of the
    object; False keeps the photo's own framing (a result in the photo's
    scene).
    """
    if path is not None:
        return load_camera_path(path, trajectory.num_frames)
    centres = trajectory.means.mean(axis=1, dtype=np.float64)  # (T, 3) the object's centre in each frame
    if not framed:
        return camera_path(target.camera, centres, move, amount)
    cameras = camera_path(fit_view(target.camera, trajectory), centres, move, amount)
    if move == "orbit":  # a dolly keeps the start's zoom: it pushes in on the object
        cameras = keep_in_view(cameras, _sampled(trajectory))
    unseen = frames_unseen(trajectory, cameras)
    if unseen:
        warnings.warn(f"nothing of the object is in view in {unseen} of {trajectory.num_frames} frames of the "
                      f"{move} camera", stacklevel=2)
    return cameras


def fit_view(camera: Camera, trajectory: Trajectory, margin: float = 0.06, samples: int = 20000) -> Camera:
    """The reference camera zoomed out and re-centred so the whole trajectory stays in frame.

    A camera that already keeps every frame in view is returned unchanged.
    """
    return camera.framing(_sampled(trajectory, samples).reshape(-1, 3), margin)


def _sampled(trajectory: Trajectory, samples: int = 20000) -> np.ndarray:
    """(T, M, 3) every k-th Gaussian's centre in each frame, about ``samples`` of them: enough to frame the motion."""
    return trajectory.means[:, ::max(1, trajectory.means.shape[1] // samples)]


def scene_compositor(target: LiftedTarget, *, inpaint: str = "fsr", detail: bool = True) -> SceneCompositor:
    """What renders a lifted photo's object inside the photo's own scene (``--background scene``).

    The object's region of the photo is inpainted (``inpaint``, see
    :func:`~marionette.scene.plate.clean_plate`); ``detail`` carries the
    photo's own texture on the object (:mod:`marionette.scene.composite`).
    """
    if target.image is None:
        raise InputError("a scene background needs an image target (a .ply or a mesh has no scene around it)")
    if target.image.shape[2] == 4 and (target.image[..., 3] < 128).any():
        warnings.warn("the photo is transparent around its object: the scene is whatever colour lies under its "
                      "alpha", stacklevel=2)
    plate = clean_plate(target.image, target.mask, inpaint)
    return SceneCompositor.from_lift(target.gaussians, target.camera, target.pixel_of, target.image, plate, detail)


def frames_outside(gaussians: Gaussians, trajectory: Trajectory, cameras: Sequence[Camera]) -> int:
    """How many frames show the Gaussians' centroid outside the image (or behind the camera)."""
    count = 0
    for t, cam in enumerate(cameras):
        uv, z = cam.project(trajectory.means[t].mean(axis=0, dtype=np.float64)[None])
        (u, v), z = uv[0], z[0]
        count += int(not (z > 0 and 0 <= u <= cam.width - 1 and 0 <= v <= cam.height - 1))
    return count


def frames_unseen(trajectory: Trajectory, cameras: Sequence[Camera]) -> int:
    """How many frames show none of the object: every (sampled) Gaussian centre outside the image or behind."""
    count = 0
    for points, cam in zip(_sampled(trajectory), cameras):
        uv, z = cam.project(points)
        inside = (z > 0) & (uv >= 0).all(axis=1) & (uv <= [cam.width - 1, cam.height - 1]).all(axis=1)
        count += not inside.any()
    return count


def render_frames(gaussians: Gaussians, trajectory: Trajectory, camera: Camera | Sequence[Camera],
                  background: tuple[float, float, float] | SceneCompositor = (1.0, 1.0, 1.0),
                  progress=None, on_alpha: Callable[[int, np.ndarray], None] | None = None) -> Iterator[np.ndarray]:
    """Yield (H, W, 3) uint8 frames of the moving Gaussians, from one camera or one per frame, over a colour
    or inside a photo's scene (a :class:`~marionette.scene.SceneCompositor` of these Gaussians).

    ``on_alpha(t, alpha)``, over a colour: each frame's (H, W) alpha, as it is rendered (e.g. to score the
    silhouette without rendering twice)."""
    cameras = [camera] * trajectory.num_frames if isinstance(camera, Camera) else list(camera)
    if len(cameras) != trajectory.num_frames:
        raise InputError(f"{len(cameras)} cameras for {trajectory.num_frames} frames")
    for t, cam in enumerate(cameras):
        if isinstance(background, SceneCompositor):
            frame = background.frame(trajectory.frame(gaussians, t), trajectory.frame(background.features, t), cam)
        else:
            out = render(trajectory.frame(gaussians, t), cam, background)
            if on_alpha is not None:
                on_alpha(t, out.alpha)
            image = out.image  # in [0, 1], ours to change
            image *= 255
            image += 0.5
            frame = image.astype(np.uint8)
        if progress:
            progress(t + 1, trajectory.num_frames)
        yield frame


def render_video(path: str | Path, target: LiftedTarget | Gaussians, trajectory: Trajectory,
                 camera: Camera | Sequence[Camera] | None = None, *, fps: float,
                 background: tuple[float, float, float] | SceneCompositor = (1.0, 1.0, 1.0),
                 reporter: Reporter | None = None, on_alpha: Callable[[int, np.ndarray], None] | None = None) -> None:
    """Render the trajectory and write it (MP4, GIF or a PNG folder, by suffix).

    ``target`` is a lifted target (its reference camera, zoomed out to keep
    the motion in frame, is the default ``camera``; inside a scene, the
    photo's camera as it is) or bare Gaussians, which need a ``camera`` (one,
    or one per frame). ``background``: a colour, or the photo's scene
    (:func:`scene_compositor`). ``on_alpha``: see :func:`render_frames`.
    """
    reporter = reporter or Reporter(quiet=True)
    if isinstance(target, LiftedTarget):
        gaussians = target.gaussians
        if camera is None:
            camera = target.camera if isinstance(background, SceneCompositor) else fit_view(target.camera, trajectory)
    elif camera is None:
        raise InputError("render_video needs a camera for bare Gaussians")
    else:
        gaussians = target
    with reporter.stage("rendering", trajectory.num_frames) as progress:
        write_video(path, render_frames(gaussians, trajectory, camera, background, progress, on_alpha), fps)


def write_ply_frames(folder: str | Path, gaussians: Gaussians, trajectory: Trajectory) -> list[Path]:
    """Write each frame's moved Gaussians as ``folder/00000.ply`` … (3DGS layout); the paths written.

    The folder appears complete or not at all (see :func:`~marionette.io.atomic.atomic_folder`).
    """
    folder = Path(folder)
    with atomic_folder(folder, PLY_FRAME_NAME) as tmp:
        for t in range(trajectory.num_frames):
            write_ply(tmp / f"{t:05d}.ply", trajectory.frame(gaussians, t))
    return [folder / f"{t:05d}.ply" for t in range(trajectory.num_frames)]


def write_side_by_side(path: str | Path, source: str | Path, result: str | Path, source_times: np.ndarray, *,
                       fps: float, max_side: int = DEFAULT_MAX_SIDE, start: int = 0, end: int | None = None,
                       stride: int = 1) -> None:
    """Write the source video beside a result video, frame-aligned.

    ``source`` frames are selected as for :func:`extract`; result frame ``t``
    is shown beside source frame ``source_times[t]`` (rounded), (T_out,).
    """
    left = read_video(source, max_side=max_side, start=start, end=end, stride=stride).frames
    right = read_video(result).frames
    index = np.clip(np.rint(source_times).astype(int), 0, len(left) - 1)
    write_video(path, side_by_side([left[i] for i in index], right), fps)


def write_preview(path: str | Path, video: str | Path, *, fps: float, max_side: int = 320,
                  max_frames: int = 120) -> None:
    """Write a small looping GIF of a video: long side ``max_side``, at most ``max_frames`` frames."""
    frames = read_video(video, max_side=max_side).frames
    step = -(-len(frames) // max_frames)
    write_video(path, frames[::step], fps / step)


def side_by_side(left: np.ndarray, right: list[np.ndarray] | np.ndarray, *,
                 height: int | None = None) -> Iterator[np.ndarray]:
    """Yield frames with ``left[t]`` beside ``right[t]``, both scaled to one height.

    The shorter sequence holds its last frame. (T, H, W, 3) uint8 in, frames out.
    """
    height = height or max(left[0].shape[0], right[0].shape[0])
    height -= height % 2

    def fit(img: np.ndarray) -> np.ndarray:
        w = int(round(img.shape[1] * height / img.shape[0]))
        return cv2.resize(img, (w + w % 2, height), interpolation=cv2.INTER_AREA)

    for t in range(max(len(left), len(right))):
        yield np.concatenate([fit(left[min(t, len(left) - 1)]), fit(right[min(t, len(right) - 1)])], axis=1)
