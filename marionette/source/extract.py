"""Source video → SpaT prior (Motion Marionette stages 1 and 3).

The paper (Sec. 3-4.1) lifts dense 2D tracks to 3D and fits per-step rigid
transforms (Eq. 3-5). We do the same per rigid part, in this order:

1. foreground: the given masks, or :func:`~marionette.source.foreground.auto_masks`
   (salient-object model, motion segmentation, propagation);
2. :func:`~marionette.source.tracks.track`: Lucas–Kanade tracks on the object,
   re-seeded as it turns;
3. :func:`~marionette.source.camera_motion.estimate_camera_motion`: the camera's
   motion from background tracks, removed at the end so poses live in the
   world frame (the camera frame of frame 0);
4. :func:`~marionette.source.parts.segment_parts`: tracks grouped into rigid
   parts (``parts=1`` skips it);
5. per part, poses: with depth maps the paper's path
   (:func:`~marionette.source.depth.poses_from_depth`, Umeyama per step);
   otherwise :func:`~marionette.source.rigid.fit_rigid` (RANSAC PnP and bundle
   adjustment) against the object's inflated silhouette, whose RMS radius of
   1 unit fixes the monocular scale for all parts alike;
6. :func:`~marionette.source.smoothing.smooth_poses`: SE(3) temporal smoothing;
7. each part's centre (the prior volume carved by the silhouettes) moved by
   its poses, and :meth:`~marionette.prior.SpatPrior.from_poses`;
8. :func:`~marionette.reconstruct.joint.joint_fit`: every pose fitted again
   together with a model of the object, to the silhouettes, pixels and tracks,
   so a frame the tracks lost is placed by the fit; smoothed again.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..camera import Camera
from ..errors import InputError
from ..geometry import invert_transform, rotation_angle_deg
from ..io.video import PackedMasks, VideoFrames
from ..prior import CAMERA_EXTRA, SpatPrior
from ..progress import ProgressCallback, Reporter
from ..reconstruct.joint import JointOptions, joint_fit
from ..reconstruct.quality import placed_frames
from ..target.cuboid import MIN_BOX_IOU, Cuboid, box_depth, fit_cuboid
from .camera_motion import estimate_camera_motion, to_world
from .depth import DepthMaps, poses_from_depth
from .focal import FOCAL_SCALES, estimate_focal
from .foreground import auto_masks
from .hinge import HingeFit, fit_hinge, hinge_poses, scaled_hinge
from .joint_tracks import Observations, surface_scale
from .part_pixels import find_still_part, label_pixels, part_depth
from .parts import OFF_OBJECT, OUTLIER, STATIC, PartSegmentation, TooFewTracks, segment_parts
from .pixel_joint import fit_pixel_joint, place_unseen_angles
from .recover import FrameRecovery
from .rigid import RigidOptions, ShapePrior, carved_centroid, fit_rigid
from .seed_align import realign_to_seeds
from .slider import SliderFit, fit_slider, scaled_slider
from .smoothing import smooth_poses
from .tracks import Tracks, _check_video, track

__all__ = ["ExtractOptions", "extract_prior", "whole_object_poses"]

#: Camera motion is removed only when, in 90 % of the frames, at least this
#: share of the background tracks agrees with the fitted camera rotation.
_CAMERA_AGREEMENT = 0.3


@dataclass(frozen=True)
class ExtractOptions:
    """Settings of :func:`extract_prior`.

    Attributes
    ----------
    spacing, window, levels, fb_threshold, reseed_every, min_eigen :
        Tracking settings, passed to :func:`~marionette.source.tracks.track`
        (same defaults: 6 px grid, 21 px window, 3 pyramid levels, 1 px
        forward-backward threshold, re-seeding every 4 frames, texture 2e-4).
    parts : int or "auto"
        Number of rigid parts in all, a static one (what stays still: a
        cabinet under its door, a box under its lid) included when its tracks
        show one; ``"auto"`` picks the count by model selection. A count the
        tracks do not show is an :class:`InputError` saying what they show.
    smoothing : float
        Strength of the SE(3) temporal smoothing (0: off); see
        :func:`~marionette.source.smoothing.smooth_poses`.
    camera_motion : bool
        Estimate and remove the camera's motion (a static camera is detected
        as such and left alone).
    recover_frames : bool
        Find the pose of a frame the tracks lose (blur, a fast turn) by
        aligning a model of the object lifted from the last well-tracked frame
        (:mod:`~marionette.source.recover`), rather than interpolating it.
        One-part fits only: a part's own pixels in a lost frame are not known.
    joints : bool
        Fit each part that turns about a fixed axis of the part that turns
        least (a lid on a box, a door on its frame) as a hinge on it
        (:mod:`~marionette.source.hinge`) when that explains its tracks as
        well as its free 6-DoF poses do.
    estimate_focal : bool
        Estimate the focal length from the tracks (:mod:`~marionette.source.focal`),
        starting from ``camera_K``'s; the prior's intrinsics carry the result and
        its metadata says under ``focal`` whether the tracks determined it (an
        object that only translates or turns in the image plane leaves the
        given one). Not with depth maps.
    strict_tracks : bool or "auto"
        End a track where its window stops matching its anchor window, a fresh
        one starting there, instead of anchoring it again (``track(...,
        strict=True)``): each track one surface point, so clean footage gives
        poses several times closer; compressed or blurred clips get tracks a
        frame or two long. ``"auto"`` (the default): strict while 70 % of the
        windows aligned so far keep matching, else tracking starts over
        anchored. With ``parts`` other than 1, anchored unless ``True`` (the
        part segmentation needs long tracks).
    relief : float
        Half-thickness of the inflated shape prior relative to the mask's
        inscribed radius (1: a disc mask becomes a sphere).
    motion_threshold : float
        Pixels. When the 90th percentile of the track displacements from their
        start stays below this at every frame, the video is declared
        motionless and the identity prior returned (with a warning). Not the
        median: a lid or a door is often less than half of the object, and
        the body it hinges on stays still.
    joint_fit : bool
        Fit the poses again together with the object's Gaussians, to the masks, the frames and the tracks
        (:mod:`~marionette.reconstruct.joint`): poses hold where tracks fail, and a frame they lost is placed
        by the fit. One-part motion, without depth maps.
    rigid : RigidOptions
        Pose estimation settings.
    joint : JointOptions
        Joint fit settings.
    """

    spacing: int = 6
    window: int = 21
    levels: int = 3
    fb_threshold: float = 1.0
    reseed_every: int = 4
    min_eigen: float = 2e-4
    parts: int | str = 1
    smoothing: float = 1.0
    camera_motion: bool = True
    recover_frames: bool = True
    joints: bool = True
    estimate_focal: bool = False
    strict_tracks: bool | str = "auto"
    relief: float = 1.0
    motion_threshold: float = 0.5
    joint_fit: bool = True
    rigid: RigidOptions = field(default_factory=RigidOptions)
    joint: JointOptions = field(default_factory=JointOptions)


@dataclass
class _Part:
    """One rigid group while it is being fitted."""

    group: int  # its label in the segmentation (STATIC for the static group)
    pixels: np.ndarray  # (H, W) bool, its frame-0 object pixels
    shape: ShapePrior
    poses: np.ndarray  # (T, 4, 4), camera-frame poses until the camera motion is removed
    centre: np.ndarray  # (3,) at frame 0
    radius: float
    failed: dict[int, str]  # frames whose pose was interpolated, with the reason
    recovered: dict[int, str]  # frames the tracks lost whose pose was found again (alignment, hinge, PnP retried)
    points: np.ndarray | None = None  # (N, 3) its triangulated tracks at frame 0
    surface: np.ndarray | None = None  # (H, W) frame-0 depth its joint was fitted on (or scaled to)
    held: tuple | None = None  # (RigidFit, note): its points held on the outline's box, when that fits as well
    fit_note: str | None = None  # how its poses were fitted, when not the usual way
    hinge: HingeFit | None = None  # the hinge its tracks fit, when kept
    hinge_tracks: np.ndarray | None = None  # (M,) bool, the tracks that hinge follows

    def take_held(self, masks: np.ndarray) -> None:
        """Its poses, failed and recovered frames, points and centre become those of :attr:`held`."""
        fit, self.fit_note = self.held
        self.poses, self.failed, self.points = fit.poses, dict(fit.failed_frames), fit.points[fit.triangulated]
        self.recovered = dict(sorted({**fit.recovered_frames, **fit.retried_frames}.items()))
        trusted = np.array([t for t in range(len(self.poses)) if t not in self.failed])
        self.centre = carved_centroid(self.shape, masks, self.poses, trusted, points=self.points)


def _strictness(options: ExtractOptions) -> bool | str:
    """``track``'s ``strict`` for these options: anchored where parts are segmented (it needs long tracks)."""
    if options.strict_tracks not in (True, False, "auto"):
        raise InputError(f"strict_tracks must be true, false or 'auto', got {options.strict_tracks!r}")
    return options.strict_tracks if options.parts == 1 or options.strict_tracks is True else False


def _motion_px(tracks: Tracks, percentile: float = 90.0) -> float:
    """Largest, over frames, ``percentile`` of the visible tracks' displacements from their start (px); 0 if none."""
    first = tracks.uv[tracks.start, np.arange(tracks.num_tracks)]  # (M, 2)
    disp = np.linalg.norm(tracks.uv - first[None], axis=2)  # (T, M), NaN where not visible
    moved = [np.percentile(d[v], percentile) for d, v in zip(disp, tracks.visible) if v.any()]
    return float(max(moved, default=0.0))


def _propagate_labels(tracks: Tracks, labels: np.ndarray, unlabelled: int, radius: float,
                      neighbours: int = 5) -> np.ndarray:
    """Give unlabelled tracks (M,) the majority label of their labelled neighbours where they start.

    Tracks seeded after frame 0 (re-seeded as a part turns) are often too
    short for the segmentation to judge; at their first frame they sit among
    tracks of one part. Frames are visited in order, so a newly labelled
    track vouches for later ones. Tracks with no labelled neighbour within
    ``radius`` pixels keep ``unlabelled``.
    """
    labels = labels.copy()
    for t in np.unique(tracks.start):
        todo = np.nonzero((tracks.start == t) & (labels == unlabelled))[0]
        known = np.nonzero(tracks.visible[t] & (labels != unlabelled))[0]
        if not len(todo) or not len(known):
            continue
        dist, idx = cKDTree(tracks.uv[t, known]).query(tracks.uv[t, todo], k=min(neighbours, len(known)),
                                                       distance_upper_bound=radius)
        dist, idx = dist.reshape(len(todo), -1), idx.reshape(len(todo), -1)
        for m, d, i in zip(todo, dist, idx):
            votes = labels[known[i[np.isfinite(d)]]]
            if len(votes):
                values, counts = np.unique(votes, return_counts=True)
                labels[m] = values[counts.argmax()]
    return labels


#: A hinge is kept when its median reprojection error exceeds the free poses' by no more than this (pixels):
#: within the tracks' noise, the simpler model.
_HINGE_TOLERANCE_PX = 0.25
#: Joints are fitted to and judged by the tracks seen at frame 0 no nearer than _SEAM_PX pixels to another part
#: (:func:`_off_the_seams`), and those seeded later; unless that leaves a part fewer than _SEAM_MIN_TRACKS.
_SEAM_PX = 4.0
_SEAM_MIN_TRACKS = 12
#: A slider is kept over a hinge unless the hinge's median reprojection error is lower by more than this (pixels).
_SLIDER_PREFERENCE_PX = 0.05
#: A frame whose free pose failed counts as found by the hinge fit when this many of the part's tracks place its
#: one angle (a free pose needs 6 inliers for its 6 degrees of freedom).
_HINGE_MIN_TRACKS = 3
#: A track's median reprojection error counts up to this (pixels) when the parts' motions are compared.
_ERROR_CAP = 2.0
#: How the note of such a frame in the metadata's ``recovered_frames`` begins (a hinge, a slider).
HINGE_NOTE = "turned about the hinge"
SLIDER_NOTE = "slid along the slider"


def _rigid_groups(seg) -> list[int]:
    """The labels of a segmentation's rigid groups: its moving parts, then STATIC when it holds first-frame pixels."""
    return list(range(seg.num_parts)) + ([STATIC] if (seg.pixel_labels == STATIC).any() else [])


def _joint_of(part: _Part, body_poses: np.ndarray, tracks: Tracks, track_labels: np.ndarray,
              k: np.ndarray) -> HingeFit | SliderFit | None:
    """The hinge or slider on a body moving by ``body_poses`` (T, 4, 4) that explains ``part``'s tracks best."""
    if part.group == STATIC:
        return None
    members = track_labels == part.group
    args = (tracks.uv[:, members], tracks.visible[:, members], body_poses, part.poses, k)
    fits = [f for f in (fit_slider(*args), fit_hinge(*args)) if f is not None]
    # A hinge with a far axis mimics a slider: the slider, one direction instead of an axis, unless the hinge
    # explains the tracks clearly better.
    return min(fits, key=lambda f: f.residual_px - (_SLIDER_PREFERENCE_PX if isinstance(f, SliderFit) else 0),
               default=None)


def _realigned_hinge(part: _Part, fit: HingeFit, body_poses: np.ndarray, tracks: Tracks, track_labels: np.ndarray,
                     frames, masks, k: np.ndarray) -> HingeFit:
    """``fit`` fitted again to ``part``'s tracks re-aligned to their seed windows (:func:`realign_to_seeds`), those
    that no longer match kept as tracked: the tracker's drift makes a lid turning away come out a few per cent
    short at every frame, and the tracks across its edge-on turn tell a turn past it from one back. The
    residuals stay ``fit``'s (the model was chosen on the tracks as tracked)."""
    members = track_labels == part.group
    aligned = realign_to_seeds(tracks, frames, masks, subset=members, keep_unmatched=True)
    again = fit_hinge(aligned.uv[:, members], aligned.visible[:, members], body_poses, fit.poses, k,
                      start_scales=(1.0,))
    if again is None:
        return fit
    return dataclasses.replace(again, residual_px=fit.residual_px, free_residual_px=fit.free_residual_px)


def _on_the_surface(part: _Part, fit: HingeFit | SliderFit, body_poses: np.ndarray, tracks: Tracks,
                    track_labels: np.ndarray, k: np.ndarray, surface: np.ndarray,
                    faces: bool) -> tuple[HingeFit | SliderFit, float | None]:
    """``fit``, a joint on a still body, scaled about the camera to put ``part``'s frame-0 tracks on ``surface``
    (H, W), the object's frame-0 front (:func:`surface_scale`); and the factor (None, the fit as it is, when too
    few tracks tell). Where ``surface`` is the faces of a box, it becomes the part's surface, which its pixels
    are labelled on (the inflated outline is no better there than its tracks)."""
    members = track_labels == part.group
    slider = isinstance(fit, SliderFit)
    values = fit.distances if slider else fit.angles
    scaled = scaled_slider if slider else scaled_hinge
    factor = surface_scale(lambda f: scaled(fit, body_poses, f).poses, values,
                           tracks.uv[:, members], tracks.visible[:, members], k, surface)
    if factor is None:
        return fit, None
    if faces:
        part.surface = surface
    return scaled(fit, body_poses, factor), factor


def _kept(fit: HingeFit | SliderFit | None) -> bool:
    """Whether a joint explains its part's tracks about as well as its free poses (within
    :data:`_HINGE_TOLERANCE_PX`): the simpler model, kept."""
    return fit is not None and fit.residual_px <= fit.free_residual_px + _HINGE_TOLERANCE_PX


def _off_the_seams(tracks: Tracks, track_labels: np.ndarray, parts: list[_Part]) -> np.ndarray:
    """(M,) the tracks' ``track_labels``, :data:`OUTLIER` for those seen at frame 0 within :data:`_SEAM_PX` pixels
    of another part's frame-0 pixels. A track on the seam between two parts has its window on both and follows
    neither: a joint fitted to such tracks bends towards what they share, and judged by them it loses to one
    that explains less (a drawer's seam tracks made a hinge fit its turning cabinet better than a slider, and
    the cabinet hinged on the drawer look likelier)."""
    labels = track_labels.copy()
    h, w = parts[0].pixels.shape
    at0 = tracks.visible[0]
    uv = np.round(tracks.uv[0, at0]).astype(int)
    rows, cols = np.clip(uv[:, 1], 0, h - 1), np.clip(uv[:, 0], 0, w - 1)
    for part in parts:
        others = np.any([other.pixels for other in parts if other is not part], axis=0)
        distance = cv2.distanceTransform((~others).astype(np.uint8), cv2.DIST_L2, 3)
        mine = track_labels[at0] == part.group
        seam = np.flatnonzero(at0)[mine & (distance[rows, cols] < _SEAM_PX)]
        if (track_labels == part.group).sum() - len(seam) >= _SEAM_MIN_TRACKS:
            labels[seam] = OUTLIER
    return labels


def _articulated_error(parts: list[_Part], poses: list[np.ndarray], tracks: Tracks, track_labels: np.ndarray,
                       k: np.ndarray) -> float:
    """Mean over the parts' tracks of each one's median reprojection error (pixels, capped at
    :data:`_ERROR_CAP`) under its part's ``poses`` (each (T, 4, 4)), its point re-solved."""
    errors = []
    for part, part_poses in zip(parts, poses):
        seen = (track_labels == part.group) & (tracks.visible.sum(axis=0) >= 2)
        if seen.any():
            obs = Observations(tracks.uv, tracks.visible, seen)
            errors.append(obs.per_track_median(np.linalg.norm(obs.residuals(part_poses, k)[0], axis=1)))
    return float(np.mean(np.minimum(np.concatenate(errors), _ERROR_CAP))) if errors else 0.0


def _based_on_the_stiller(parts: list[_Part], on: int, notes: dict[str, dict]) -> dict[str, dict]:
    """The joint of two parts told with the one that turns less as its base: fitted the other way round (a
    screen's tracks placing it better than its small stand's place the stand), part ``on`` turning on its
    hinge (slider) is the other part turning back about the same line (sliding back along it)."""
    (other, note), = notes.items()
    turns = [rotation_angle_deg(part.poses[:, :3, :3]).max() for part in parts]
    if note["model"] == "free" or turns[int(other)] >= turns[on]:
        return notes
    span = "range_deg" if note["model"] == "hinge" else "range"
    return {str(on): {**note, "on_part": int(other), span: [0.0 - note[span][1], 0.0 - note[span][0]],
                      "fitted": f"as part {other} on part {on}, told from part {other}, which turns less"}}


def _fit_joints(parts: list[_Part], tracks: Tracks, track_labels: np.ndarray, frames, masks: np.ndarray,
                k: np.ndarray, surface: np.ndarray | None, faces: bool, progress: ProgressCallback) -> dict[str, dict]:
    """Refit each part as a hinge on the body (it turns) or a slider (it travels without turning) where that
    fits its tracks as well as its free poses.

    The body is a still part when there is one; otherwise each part is tried as the body (its poses held on the
    outline's box where it has them, :attr:`_Part.held`), and the one on which the other parts' joints are kept
    (:func:`_kept`), and then explain the tracks best, is taken: a drawer and its cabinet turn alike, and the
    part whose free fit turns least need not be the cabinet. A joint on a still body has its scale (a slider's
    travel, a hinge's axis) from ``surface`` (H, W), the frame-0 depth of the object's front (the ``faces`` of
    the box its outline shows, or not; :func:`_on_the_surface`). Updates the parts' poses and centres in place;
    returns, per part index, the model kept (with its axis and range) and why.
    """
    static = [i for i, p in enumerate(parts) if p.group == STATIC]
    bodies = static[:1] or list(range(len(parts)))
    off_seams = _off_the_seams(tracks, track_labels, parts)
    total, done, best = len(bodies) * (len(parts) - 1), 0, None
    for on in bodies:
        body_poses = parts[on].poses if parts[on].held is None else parts[on].held[0].poses
        fits = {}
        for index in (i for i in range(len(parts)) if i != on):
            fits[index] = _joint_of(parts[index], body_poses, tracks, off_seams, k)
            done += 1
            progress(done, total)
        kept = {i: fit.poses for i, fit in fits.items() if _kept(fit)}
        error = 0.0 if len(bodies) == 1 else _articulated_error(
            parts, [body_poses if i == on else kept.get(i, parts[i].poses) for i in range(len(parts))], tracks,
            off_seams, k)
        rank = (len(fits) - len(kept), error)  # a body the other parts are joined to, then the lowest error
        if best is None or rank < best[0]:
            best = (rank, on, fits)
    _, on, fits = best
    body, notes = parts[on], {}
    if body.held is not None:
        body.take_held(masks)
    for index, fit in fits.items():
        part = parts[index]
        kind = "hinge" if isinstance(fit, HingeFit) else "slider"
        if fit is None:
            notes[str(index)] = {"model": "free", "reason": f"it neither turns about an axis nor slides against part "
                                 f"{on}, or has too few tracks"}
        elif not _kept(fit):
            notes[str(index)] = {"model": "free", "reason": f"a {kind} on part {on} fits its tracks worse "
                                 f"({fit.residual_px:.2f} px against {fit.free_residual_px:.2f} px)"}
        else:
            if kind == "hinge":  # chosen on the tracks as tracked, its angles from the tracks re-aligned
                fit = _realigned_hinge(part, fit, body.poses, tracks, off_seams, frames, masks, k)
            factor = None
            if body.group == STATIC and surface is not None:  # the joint's scale is the body's, not its free fit's
                fit, factor = _on_the_surface(part, fit, body.poses, tracks, off_seams, k, surface, faces)
            if kind == "hinge":
                part.hinge, part.hinge_tracks = fit, np.zeros(tracks.num_tracks, bool)
                part.hinge_tracks[np.flatnonzero(off_seams == part.group)[fit.followers]] = True
            part.poses = fit.poses
            for t in sorted(part.failed):  # a frame the free fit lost, placed by its tracks on the joint
                if fit.seen[t] >= _HINGE_MIN_TRACKS:
                    del part.failed[t]
                    note = HINGE_NOTE if kind == "hinge" else SLIDER_NOTE
                    part.recovered[t] = f"{note} to fit {fit.seen[t]} tracks"
            trusted = np.array([t for t in range(len(part.poses)) if t not in part.failed])
            part.centre = carved_centroid(part.shape, masks, part.poses, trusted)
            if kind == "hinge":
                joint = {"point": np.round(fit.point, 4).tolist(),
                         "range_deg": np.round(np.degrees([fit.angles.min(), fit.angles.max()]), 2).tolist()}
            else:
                joint = {"range": np.round([fit.distances.min(), fit.distances.max()], 4).tolist()}
            notes[str(index)] = {"model": kind, "on_part": on, "axis": np.round(fit.axis, 4).tolist(), **joint,
                                 "residual_px": round(fit.residual_px, 3),
                                 "free_residual_px": round(fit.free_residual_px, 3), "dropped_tracks": fit.dropped,
                                 **({} if factor is None else {"scaled_to_the_surface": round(factor, 3)})}
    if not static and len(parts) == 2:
        notes = _based_on_the_stiller(parts, on, notes)
    return notes


#: A part with fewer tracks than _PIXEL_JOINT_TRACKS, whose tracks fit no joint, has its joint looked for in
#: its pixels; at least _PIXEL_JOINT_POINTS of its tracks must be triangulated (they place its surface).
_PIXEL_JOINT_TRACKS = 40
_PIXEL_JOINT_POINTS = 8
#: A face of the box moves when a joint explains the frames below this share of its staying still's cost; a
#: face smaller than _MIN_FACE_SHARE of the object is not tried.
_MOVING_FACE_RATIO = 0.7
_MIN_FACE_SHARE = 0.05
#: A track that never moves more than this (pixels) from where it starts is still.
_STILL_TRACK_PX = 1.5
#: A track whose median reprojection error under its part's final poses exceeds this (pixels) does not place
#: the part's surface.
_SURFACE_TRACK_PX = 1.0


def _fit_pixel_joint(parts: list[_Part], index: int, tracks: Tracks, track_labels: np.ndarray, frames, masks,
                     whole: ShapePrior, k: np.ndarray, box: Cuboid | None, notes: dict[str, dict]) -> None:
    """Part ``index``, too few tracks to trust the joint they fit (or none), refitted as the hinge or slider on
    the body that best explains its pixels and the masks (:func:`fit_pixel_joint`) when that beats its poses so
    far. Its surface: the faces of ``box`` (:func:`_outline_box`), when the frame-0 outline shows one (a plain
    cabinet or chest, whose part's few tracks do not place it), else where at least :data:`_PIXEL_JOINT_POINTS` of its
    tracks put it. ``notes`` (the metadata's joints) say what was done."""
    part, on = parts[index], notes[str(index)].get("on_part", next(i for i in range(len(parts)) if i != index))
    mask0 = np.asarray(masks[0], bool)
    points = _surface_points(part, tracks, track_labels, k)
    if box is not None:  # a box (a cabinet, a chest): its faces are the surface
        depth, surface = box_depth(box, k, mask0), "the faces of the box its outline shows"
    elif points is not None and len(points) >= _PIXEL_JOINT_POINTS:
        depth, surface = part_depth(points, k, part.pixels, whole.front), "its tracks"
    else:
        notes[str(index)]["pixels"] = "neither its outline (a box) nor its tracks give its surface a depth"
        return
    fit = fit_pixel_joint(frames, masks, k, parts[on].poses, mask0, part.pixels, depth, part.poses)
    if fit is None or fit.cost >= fit.start_cost:
        notes[str(index)]["pixels"] = "no hinge or slider explains its pixels better than its poses"
        return
    part.poses, part.surface, part.hinge, part.hinge_tracks = fit.poses, depth, None, None
    part.failed.clear()
    joint = ({"point": np.round(fit.point, 4).tolist(),
              "range_deg": np.round(np.degrees([fit.values.min(), fit.values.max()]), 2).tolist()}
             if fit.kind == "hinge" else {"range": np.round([fit.values.min(), fit.values.max()], 4).tolist()})
    notes[str(index)] = {"model": fit.kind, "on_part": on, "axis": np.round(fit.axis, 4).tolist(), **joint,
                         "fitted_to": "pixels and masks", "surface": surface,
                         "cost_ratio": round(fit.cost / fit.start_cost, 3)}


def _place_unseen(parts: list[_Part], index: int, tracks: Tracks, track_labels: np.ndarray, frames, masks,
                  whole: ShapePrior, k: np.ndarray, notes: dict[str, dict]) -> None:
    """Part ``index``'s hinge angles in the frames its tracks do not see (:func:`_unanchored`), found
    from its pixels and the masks (:func:`place_unseen_angles`) on the surface its tracks place; those frames
    are listed as recovered, and ``notes`` (the metadata's joints) give the new range."""
    part, note = parts[index], notes[str(index)]
    unseen = _unanchored(tracks.visible[:, part.hinge_tracks], part.hinge.seen < _HINGE_MIN_TRACKS)
    depth = part_depth(_surface_points(part, tracks, track_labels, k), k, part.pixels, whole.front)
    body = parts[note["on_part"]].poses
    angles = place_unseen_angles(frames, masks, k, body, np.asarray(masks[0], bool), part.pixels, depth,
                                 part.hinge.axis, part.hinge.point, part.hinge.angles, unseen)
    if angles is None:
        return
    part.poses = hinge_poses(body, part.hinge.axis, part.hinge.point, angles)
    for t in np.flatnonzero(unseen):
        part.failed.pop(int(t), None)
        part.recovered[int(t)] = "placed about its hinge by its pixels and the mask (its tracks do not see it)"
    part.recovered = dict(sorted(part.recovered.items()))
    note["range_deg"] = np.round(np.degrees([angles.min(), angles.max()]), 2).tolist()
    note["placed_by_pixels"] = int(unseen.sum())


def _unanchored(visible: np.ndarray, unseen: np.ndarray) -> np.ndarray:
    """(T,) bool: the frames of ``unseen`` (T,) after frame 0, and every later frame where fewer than
    :data:`_HINGE_MIN_TRACKS` of a hinge's tracks seen (``visible`` (T, M)) were seen before the first of them.
    A door that turns edge-on and on shows its other face, and the tracks seeded there fix their own depths:
    they place its turn from where they start, the angle at which they start only as their relief allows."""
    out = np.asarray(unseen, bool).copy()
    out[0] = False
    if out.any():
        first = int(np.argmax(out))
        anchored = visible[:first].any(axis=0)
        out[first:] |= visible[first:, anchored].sum(axis=1) < _HINGE_MIN_TRACKS
    return out


def _outline_box(mask0: np.ndarray, k: np.ndarray, whole: ShapePrior) -> Cuboid | None:
    """The box the first frame's outline shows (:func:`fit_cuboid`, any outline: feet or a rim still make a
    box), its centre at the object's depth; None when no box covers the mask by :data:`MIN_BOX_IOU`."""
    box = fit_cuboid(mask0, Camera(k, np.eye(4), *mask0.shape[::-1]), float(whole.centroid[2]), any_outline=True)
    return box if box is not None and box.iou >= MIN_BOX_IOU else None


#: A part's points held on the faces of the outline's box cost this many pixels per radius they move off them
#: (:attr:`RigidOptions.depth_prior_weight`, 0.1 when free), and those poses are kept when their reprojection
#: error is at most _HELD_RMS_RATIO times the free fit's.
_HELD_DEPTH_PRIOR = 100.0
_HELD_RMS_RATIO = 1.5


def _box_held_fit(tracks: Tracks, pixels: np.ndarray, box: Cuboid, k: np.ndarray, options: RigidOptions,
                  free) -> tuple | None:
    """A part's fit (a :class:`RigidFit`) with its points held on the faces of ``box`` (:func:`_outline_box`),
    and a note; None when that explains its tracks clearly worse than its free fit ``free``.

    A turn of a few degrees leaves the free fit's depths and turn traded against each other (the bas-relief
    ambiguity: 3.9° off on a cabinet turning 8°, 0.2 px of reprojection error either way); the closed lid,
    door or drawer of a box, and the box itself, lie on the faces of the box the first frame's outline shows.
    """
    front = box_depth(box, k, pixels)
    shape = ShapePrior.from_depths(front, front * 1.05, k)
    held = fit_rigid(tracks, shape, options=dataclasses.replace(options, depth_prior_weight=_HELD_DEPTH_PRIOR))
    if held.reprojection_rms > _HELD_RMS_RATIO * free.reprojection_rms:
        return None
    return held, (f"points held on the outline's box ({held.reprojection_rms:.2f} px of reprojection error against "
                  f"{free.reprojection_rms:.2f} px free)")


def _moving_face(frames, masks, k: np.ndarray, box: Cuboid | None) -> np.ndarray | None:
    """(H, W) bool frame-0 pixels of the face of ``box`` (:func:`_outline_box`)
    that a hinge or slider on the still rest explains best (:func:`fit_pixel_joint`), when that explains the
    frames clearly better than the face staying still; None otherwise."""
    if box is None:
        return None
    mask0 = np.asarray(masks[0], bool)
    depth, still = box_depth(box, k, mask0), np.tile(np.eye(4), (len(masks), 1, 1))
    best, best_ratio = None, _MOVING_FACE_RATIO
    for axis in range(3):
        for side in (-1.0, 1.0):
            normal = side * box.axes[axis]
            centre = box.centre + side * box.half[axis] * box.axes[axis]
            if normal @ centre >= 0:  # faces away from the camera
                continue
            i, j = [m for m in range(3) if m != axis]
            quad = np.array([centre + a * box.half[i] * box.axes[i] + b * box.half[j] * box.axes[j]
                             for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            uv = (quad @ k.T)[:, :2] / (quad @ k.T)[:, 2:]
            face = np.zeros(mask0.shape, np.uint8)
            cv2.fillConvexPoly(face, np.rint(uv).astype(np.int32), 1)
            face = face.astype(bool) & mask0
            if face.sum() < _MIN_FACE_SHARE * mask0.sum():
                continue
            fit = fit_pixel_joint(frames, masks, k, still, mask0, face, depth, still)
            if fit is not None and fit.cost < best_ratio * fit.start_cost:
                best, best_ratio = face, fit.cost / fit.start_cost
    return best


def _still_tracks(tracks: Tracks) -> np.ndarray:
    """(M,) bool: tracks that never move more than :data:`_STILL_TRACK_PX` from where they start."""
    first = tracks.uv[tracks.start, np.arange(tracks.num_tracks)]  # (M, 2)
    moved = np.where(tracks.visible, np.linalg.norm(tracks.uv - first, axis=2), 0.0)
    return moved.max(axis=0) < _STILL_TRACK_PX


def _surface_points(part: _Part, tracks: Tracks, track_labels: np.ndarray, k: np.ndarray) -> np.ndarray | None:
    """(N, 3) frame-0 points of the part's tracks triangulated under its poses (those that fit them), or None."""
    members = track_labels == part.group
    if part.group == STATIC or not members.any():
        return None
    observed = Observations(tracks.uv, tracks.visible, members)
    errors, points = observed.residuals(part.poses, k)
    return points[observed.per_track_median(np.linalg.norm(errors, axis=1)) < _SURFACE_TRACK_PX]


def _label_part_pixels(parts: list[_Part], tracks: Tracks, track_labels: np.ndarray, frames, masks,
                       whole: ShapePrior, k: np.ndarray) -> None:
    """Give each frame-0 object pixel to the part whose motion explains it (:func:`label_pixels`), each part's
    surface the one its joint was fitted on (:attr:`_Part.surface`), else at the depth of its tracks
    triangulated under its final poses; the parts' pixels, shapes and centres follow."""
    vote = np.full(whole.front.shape, -1, np.int64)
    for index, part in enumerate(parts):
        vote[part.pixels] = index
    on = vote >= 0
    depths = [part_depth(_surface_points(part, tracks, track_labels, k), k, on, whole.front) if part.surface is None
              else np.where(on, part.surface, np.nan) for part in parts]
    labels = label_pixels(frames, masks, k, np.stack([p.poses for p in parts]), np.stack(depths), vote)
    for index, part in enumerate(parts):
        pixels = labels == index
        if not pixels.any():
            continue
        part.pixels = pixels
        part.shape = ShapePrior.from_depths(np.where(pixels, whole.front, np.nan), np.where(pixels, whole.back, np.nan),
                                            k)
        trusted = np.array([t for t in range(len(part.poses)) if t not in part.failed])
        part.centre = carved_centroid(part.shape, masks, part.poses, trusted, points=part.points)
        part.radius = part.shape.radius


def whole_object_poses(tracks: Tracks, shape: ShapePrior, options: RigidOptions = RigidOptions()) -> np.ndarray:
    """(T, 4, 4) camera-frame poses of the whole object as one rigid body, by :func:`fit_rigid`.

    Translations are in units of the object's frame-0 depth, as
    :func:`~marionette.source.parts.segment_parts` takes them (``whole``).
    """
    poses = fit_rigid(tracks, shape, options=options).poses
    poses[:, :3, 3] /= shape.centroid[2]
    return poses


def _check_inputs(camera_K, fps, depths, shape: tuple[int, int, int]) -> np.ndarray:
    k = np.asarray(camera_K, dtype=np.float64) if isinstance(camera_K, (np.ndarray, list, tuple)) else None
    if k is None or k.shape != (3, 3) or not np.all(np.isfinite(k)) or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise InputError(f"camera_K must be a finite 3x3 matrix with positive focal lengths, got {camera_K!r}")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) or not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a positive number, got {fps!r}")
    if depths is not None and np.shape(depths) != shape:
        raise InputError(f"depths must have shape {shape} like the frames, got {np.shape(depths)}")
    return k


class _Stages:
    """Progress bars and wall-clock timings of the extraction stages."""

    def __init__(self, reporter: Reporter) -> None:
        self.reporter = reporter
        self.timings: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, key: str, description: str, total: int | None = None) -> Iterator[ProgressCallback]:
        start = time.perf_counter()
        with self.reporter.stage(description, total) as progress:
            yield progress
        self.timings[key] = self.timings.get(key, 0.0) + time.perf_counter() - start


def _depth_shape(mask: np.ndarray, depth: np.ndarray, k: np.ndarray, relief: float) -> ShapePrior:
    """The frame-0 volume behind a measured front depth, as thick as the inflated silhouette."""
    guess = ShapePrior.inflate(mask, k, relief=relief)
    front = np.where(mask & np.isfinite(depth) & (depth > 0), depth, np.nan)
    if not np.isfinite(front).any():
        raise InputError("the depth map of frame 0 has no valid depth on the object")
    scale = np.nanmedian(front) / np.nanmedian(guess.front)
    back = front + scale * (guess.back - guess.front)
    return ShapePrior.from_depths(front, back, k)


def extract_prior(frames: np.ndarray | VideoFrames, masks: np.ndarray | PackedMasks | None, camera_K: np.ndarray,
                  fps: float, *, depths: np.ndarray | DepthMaps | None = None,
                  options: ExtractOptions = ExtractOptions(), reporter: Reporter | None = None) -> SpatPrior:
    """Extract the SpaT prior of a rigidly moving object (one or more parts) from a video.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W, 3), uint8, or VideoFrames
        RGB frames, T >= 2. Frames decoded on demand
        (:func:`~marionette.io.video.open_video`) are read in a few passes in
        order and never held together.
    masks : ndarray, shape (T, H, W), bool or integer, PackedMasks, or None
        Object masks (non-zero = object); frame 0's must not be empty. None:
        found automatically (and kept packed).
    camera_K : ndarray, shape (3, 3)
        Intrinsics of the source camera.
    fps : float
        Source frame rate.
    depths : ndarray, shape (T, H, W), float, or DepthMaps, optional
        Per-frame depth maps (z, any unit; non-positive or NaN = unknown):
        the paper's lifting path. Poses and radii are then in their unit.
    options : ExtractOptions
    reporter : Reporter, optional
        Progress bars per stage.

    Returns
    -------
    SpatPrior
        K parts, part 0 the largest (frame-0 pixels); poses (K, T, 4, 4) in
        the world frame (camera frame of frame 0). Without depth maps the
        units make the whole object's shape prior 1 unit in RMS radius.
        Extras: ``tracks_uv`` (T, M, 2) float32, ``tracks_visible`` (T, M)
        bool, ``track_labels`` (M,) int16 (part, -1 unused), ``labels``
        (H, W) int16 (part of each frame-0 object pixel, -1 elsewhere) and,
        when the camera's motion was removed, ``camera_world_to_camera``
        (T, 4, 4) float64 (:meth:`SpatPrior.motion_in` puts it back).
        Metadata: method, options, camera motion, per-stage timings, failed
        frames with reasons, track count, reprojection RMS.

    Warns
    -----
    UserWarning
        When nothing moves or the object has too few trackable points (the
        identity prior is returned), or when the pose of some frames could not
        be estimated (they are interpolated).
    """
    frames = frames if isinstance(frames, VideoFrames) else np.asarray(frames)
    k = _check_inputs(camera_K, fps, depths, frames.shape[:3])
    stages = _Stages(reporter or Reporter(quiet=True))
    start = time.perf_counter()
    if masks is None:
        with stages("foreground", "finding the object", len(frames)) as progress:
            masks = auto_masks(frames, packed=True, progress=progress)
    frames, masks = _check_video(frames, masks)
    num_frames, h, w = masks.shape
    if num_frames < 2:
        raise InputError(f"the source video needs at least 2 frames, got {num_frames}")

    with stages("tracking", "tracking", num_frames - 1) as progress:
        tracks = track(frames, masks, spacing=options.spacing, window=options.window, levels=options.levels,
                       fb_threshold=options.fb_threshold, reseed_every=options.reseed_every,
                       min_eigen=options.min_eigen, strict=_strictness(options), progress=progress)
    # Strict tracks are pieces of chains, one surface point each: the pose fit takes the pieces; what needs long
    # tracks (the amount of motion, the focal length, parts and joints) takes the chains.
    chain_of = tracks.chains()
    chains = tracks.joined(chain_of)
    focal = None
    if options.estimate_focal and depths is None:
        with stages("focal", "focal length", len(FOCAL_SCALES) + 1) as progress:
            estimate = estimate_focal(chains, masks[0], k, options=options.rigid, progress=progress)
        focal = {"focal_px": round(estimate.focal, 2), "measured": estimate.measured,
                 "given_px": round(float(k[0, 0]), 2), "note": estimate.note}
        k = k.copy()
        k[:2, :2] *= estimate.focal / k[0, 0]  # fx and fy alike, the principal point kept
    whole = (_depth_shape(masks[0], depths[0], k, options.relief) if depths is not None
             else ShapePrior.inflate(masks[0], k, relief=options.relief))
    camera, camera_note, camera_model = None, "not estimated", None
    if options.camera_motion:
        with stages("camera", "camera motion", 1) as progress:
            camera = estimate_camera_motion(frames, masks, k, object_depth=float(whole.centroid[2]))
            progress(1, 1)
        camera_note = "static" if camera.static else "removed"
        camera_model = {"model": camera.model, "background_agreement": round(camera.agreement, 3),
                        "rotation_agreement": round(camera.rotation_agreement, 3),
                        "full_pose_agreement": (None if camera.full_agreement is None
                                                else round(camera.full_agreement, 3)),
                        "residual_px": round(float(np.median(camera.residual_px[1:])) if num_frames > 1 else 0.0, 3)}
        if not camera.static and camera.agreement < _CAMERA_AGREEMENT:
            warnings.warn(f"the camera moves, but only {camera.agreement:.0%} of the background agrees with a "
                          f"camera {camera.model} in some frames: poses are left relative to the camera",
                          stacklevel=2)
            camera, camera_note = None, f"unreliable (background agreement {camera.agreement:.0%}), kept"
    metadata = {"method": "lk-tracks+" + ("depth-umeyama" if depths is not None else "inflated-shape+pnp+ba"),
                "options": dataclasses.asdict(options), "num_tracks": tracks.num_tracks,
                "tracks": {"strict": tracks.strict,
                           "anchor_match": None if np.isnan(tracks.anchor_match) else round(tracks.anchor_match, 3)},
                "camera_motion": camera_note, "camera_model": camera_model,
                **({} if focal is None else {"focal": focal}), "timings": stages.timings}
    common = dict(fps=fps, image_size=(w, h), intrinsics=k)
    extras = {"tracks_uv": tracks.uv, "tracks_visible": tracks.visible}

    motion = _motion_px(chains) if camera is None or camera.static else np.inf
    few = tracks.num_tracks < options.rigid.min_points
    if few or motion < options.motion_threshold:
        reason = (f"only {tracks.num_tracks} trackable points on the object (too little texture, or a tiny mask)"
                  if few else f"no motion detected (90th percentile of the track displacements {motion:.2f} px < "
                  f"{options.motion_threshold} px)")
        if options.parts not in (1, "auto"):
            raise InputError(f"{options.parts} parts were asked for, but no part moves: {reason}")
        warnings.warn(f"{reason}: returning the identity prior", stacklevel=2)
        stages.timings["total"] = time.perf_counter() - start
        metadata.update(failed_frames={}, recovered_frames={}, no_motion=not few, motion_px=motion)
        extras.update(track_labels=np.zeros(tracks.num_tracks, np.int16),
                      labels=np.where(masks[0], 0, -1).astype(np.int16))
        prior = SpatPrior.identity(num_frames, centroid=whole.centroid, radius=whole.radius, metadata=metadata,
                                   **common)
        return dataclasses.replace(prior, extras=extras)

    outline_box = functools.cache(lambda: _outline_box(np.asarray(masks[0], bool), k, whole))  # fitted once
    beside_still = None  # (T, 4, 4) the whole object's poses, when its pixels show a still part beside a moving one
    if options.parts == 1:
        chain_labels = np.zeros(chains.num_tracks, np.int64)
        pixel_labels = np.where(masks[0], 0, OFF_OBJECT)
        groups = [0]
    else:
        with stages("parts", "finding parts", 1) as progress:
            whole_poses = whole_object_poses(chains, whole, options.rigid)
            try:
                seg = segment_parts(chains, masks[0], k, options.parts, whole=whole_poses)
                if options.parts != "auto" and len(_rigid_groups(seg)) > options.parts:  # a static part counts
                    seg = segment_parts(chains, masks[0], k, options.parts - 1, whole=whole_poses)
            except TooFewTracks as error:  # a plain object: one moving part as far as the tracks tell
                seg = PartSegmentation(track_labels=np.zeros(chains.num_tracks, np.int64), num_parts=1,
                                       pixel_labels=np.where(masks[0], 0, OFF_OBJECT).astype(np.int16),
                                       selection=f"1 part: {str(error).removeprefix('segment_parts: ')}")
            progress(1, 1)
        chain_labels = _propagate_labels(chains, seg.track_labels, OUTLIER, radius=3.0 * options.spacing)
        pixel_labels = seg.pixel_labels
        groups = _rigid_groups(seg)
        if groups == [0] and options.parts in ("auto", 2):  # one moving part: is something beside it still?
            with stages("still", "looking for a still part", 1) as progress:
                still = find_still_part(frames, masks, k, whole_poses, whole.front / whole.centroid[2], masks[0])
                progress(1, 1)
            metadata["still_part"] = ("none: every pixel moves with the tracks" if still is None else
                                      f"found from the pixels: {still.sum() / masks[0].sum():.0%} of the object "
                                      "stays still")
            if still is None and options.parts == 2 and rotation_angle_deg(whole_poses[:, :3, :3]).max() < 5.0:
                # Two parts asked for, the tracks nearly all still and the moving part's colours alike (a plain
                # lid on a chest of the same wood): a face of the box the outline shows that turns or slides.
                with stages("still", "looking for a moving face", 1) as progress:
                    face = _moving_face(frames, masks, k, outline_box())
                    progress(1, 1)
                if face is not None:
                    still = np.asarray(masks[0], bool) & ~face
                    metadata["still_part"] = (f"a face of the box moves, the rest ({still.sum() / masks[0].sum():.0%}"
                                              " of the object) stays still")
            if still is not None:
                beside_still = whole_poses.copy()
                beside_still[:, :3, 3] *= whole.centroid[2]
                pixel_labels = np.where(still, STATIC, pixel_labels)
                chain_labels = np.where(_still_tracks(chains), STATIC, chain_labels)
                groups = [0, STATIC]
        groups = [g for g in groups if (pixel_labels == g).any()]  # a part is pixels too
        if options.parts != "auto" and len(groups) != options.parts:
            moving, still = len(groups) - (STATIC in groups), " and a still one" if STATIC in groups else ""
            raise InputError(f"{options.parts} parts were asked for, but the tracks show {moving} moving part(s)"
                             f"{still} (a part needs 5 % of the first frame's tracks moving alike, and pixels), and "
                             f"the pixels no still part beside them; ask for {len(groups)}, or 'auto'")
        # Rounded: the scores' last digits follow the BLAS thread count, and the metadata should not.
        metadata["part_selection"] = {str(n): round(float(score), 3) for n, score in seg.scores.items()}
        metadata["part_selection_note"] = seg.selection

    track_labels = chain_labels[chain_of]  # (M,) each track's, from its chain
    parts, rms, recover_seconds = [], [], 0.0
    free_fits = {}  # index in parts: its fit_rigid result, for the parts whose poses it gave
    with stages("poses", "fitting poses", len(groups) * num_frames) as progress:
        for i, g in enumerate(groups):
            pixels = pixel_labels == g
            members = track_labels == g
            shape = ShapePrior.from_depths(np.where(pixels, whole.front, np.nan), np.where(pixels, whole.back, np.nan),
                                           k)

            def step(done: int, total: int, i=i) -> None:
                progress(i * num_frames + round(done * num_frames / max(total, 1)), len(groups) * num_frames)

            failed: dict[int, str] = {}
            recovered: dict[int, str] = {}
            points = None  # fitted 3D points whose depth the motion measured (they extend the carved volume)
            if g != STATIC and members.sum() < options.rigid.min_points and beside_still is not None:
                poses = beside_still  # a part the pixels split from a still one: the motion of them all
            elif g == STATIC or members.sum() < options.rigid.min_points:
                poses = np.tile(np.eye(4), (num_frames, 1, 1))  # static, or too few tracks to tell
            elif depths is not None:
                poses = poses_from_depth(tracks.subset(members), depths, k)
            else:
                recover = (FrameRecovery(frames, masks, k, shape.centroid)
                           if options.recover_frames and len(groups) == 1 else None)
                fit = fit_rigid(tracks.subset(members), shape, options=options.rigid, progress=step,
                                recover=recover)
                poses, failed, points = fit.poses, fit.failed_frames, fit.points[fit.triangulated]
                if beside_still is not None and len(failed) > num_frames // 2:  # its few tracks lost it
                    poses, failed, points = beside_still, {}, None
                else:
                    free_fits[len(parts)] = fit
                recovered = dict(sorted({**fit.recovered_frames, **fit.retried_frames}.items()))
                recover_seconds += fit.timings["recover"]
                rms.append(fit.reprojection_rms)
            trusted = np.array([t for t in range(num_frames) if t not in failed])
            centre = carved_centroid(shape, masks, poses, trusted, points=points)
            parts.append(_Part(g, pixels, shape, poses, centre, shape.radius, failed, recovered, points))
    if len(parts) > 1 and free_fits and STATIC not in groups and options.joints and outline_box() is not None:
        # A closed box's parts lie on its faces at frame 0. The body's poses are taken from there when it is
        # found (_fit_joints): its turn of a few degrees is what its free fit gets least right.
        with stages("box_pose", "fitting the parts on the outline's box", len(free_fits)) as progress:
            for done, (index, free) in enumerate(free_fits.items(), start=1):
                part = parts[index]
                part.held = _box_held_fit(tracks.subset(track_labels == part.group), part.pixels, outline_box(), k,
                                          options.rigid, free)
                progress(done, len(free_fits))
    if recover_seconds:  # its own line in the timings, out of the pose fit's
        stages.timings["poses"] -= recover_seconds
        stages.timings["recover"] = recover_seconds

    parts.sort(key=lambda p: -p.pixels.sum())
    if options.joints and len(parts) > 1:
        with stages("joints", "fitting joints", len(parts) - 1) as progress:
            surface, faces = None, False
            if STATIC in groups:  # a joint on a still body: its scale from the object's front
                box = outline_box()
                surface = whole.front if box is None else box_depth(box, k, np.asarray(masks[0], bool))
                faces = box is not None
            metadata["joints"] = _fit_joints(parts, chains, chain_labels, frames, masks, k, surface, faces, progress)
        free = [i for i, note in metadata["joints"].items()  # the pixels found it, or its tracks are few
                if beside_still is not None or (chain_labels == parts[int(i)].group).sum() < _PIXEL_JOINT_TRACKS]
        if free:  # too few tracks to trust a joint fitted to them: look for one in the pixels
            with stages("pixel_joint", "fitting joints to the pixels", len(free)) as progress:
                for done, index in enumerate(free, start=1):
                    _fit_pixel_joint(parts, int(index), chains, chain_labels, frames, masks, whole, k,
                                     outline_box(), metadata["joints"])
                    progress(done, len(free))
        unseen = [i for i, part in enumerate(parts)  # a hinge told the other way round keeps its tracks' angles
                  if part.hinge is not None and metadata["joints"].get(str(i), {}).get("model") == "hinge"
                  and (part.hinge.seen[1:] < _HINGE_MIN_TRACKS).any()]
        if unseen:
            with stages("unseen", "placing hinges where their tracks do not see them", len(unseen)) as progress:
                for done, index in enumerate(unseen, start=1):
                    _place_unseen(parts, index, chains, chain_labels, frames, masks, whole, k, metadata["joints"])
                    progress(done, len(unseen))
    if len(parts) > 1:
        with stages("labels", "labelling the parts' pixels", 1) as progress:
            _label_part_pixels(parts, chains, chain_labels, frames, masks, whole, k)
            progress(1, 1)
    poses = np.stack([p.poses for p in parts])  # (K, T, 4, 4) in camera coordinates
    cameras = None  # (1, T, 4, 4) world_to_camera, when the camera's motion is removed
    if camera is not None and not camera.static:
        poses = to_world(poses, camera)
        cameras = camera.world_to_camera[None]
    centres = np.stack([p.centre for p in parts])  # (K, 3)
    if options.smoothing > 0:
        with stages("smoothing", "smoothing", 1) as progress:
            poses = smooth_poses(poses, options.smoothing, centers=centres)
            if cameras is not None:  # kept jitter-free too: a transfer may put it back (as filmed)
                cameras = smooth_poses(cameras, options.smoothing, centers=centres[:1])
            progress(1, 1)
    if cameras is not None:
        extras[CAMERA_EXTRA] = cameras[0] @ invert_transform(cameras[0, 0])  # frame 0's camera is the world
    centroids = np.einsum("ktij,kj->kti", poses[..., :3, :3], centres) + poses[..., :3, 3]

    labels = np.full((h, w), -1, np.int16)
    track_parts = np.full(tracks.num_tracks, -1, np.int16)  # outliers stay -1
    for index, part in enumerate(parts):
        labels[part.pixels] = index
        track_parts[track_labels == part.group] = index
    extras.update(labels=labels, track_labels=track_parts)

    if any(part.fit_note for part in parts):
        metadata["part_fits"] = {str(index): part.fit_note or "free" for index, part in enumerate(parts)}
    failed = {f"{index}:{t}": reason for index, part in enumerate(parts) for t, reason in part.failed.items()}
    recovered = {f"{index}:{t}": note for index, part in enumerate(parts) for t, note in part.recovered.items()}
    metadata.update(failed_frames=failed, recovered_frames=recovered, no_motion=False,
                    motion_px=float(motion) if np.isfinite(motion) else None, num_parts=len(parts),
                    reprojection_rms_px=float(np.mean(rms)) if rms else None)
    prior = SpatPrior.from_poses(poses, centroids, np.array([p.radius for p in parts]), extras=extras,
                                 metadata=metadata, **common)
    if options.joint_fit and depths is None:
        prior = _fit_jointly(prior, frames, masks, options, stages)
    failed = prior.metadata["failed_frames"]
    if failed:
        listed = ", ".join(list(failed)[:10])
        more = "…" if len(failed) > 10 else ""
        warnings.warn(f"pose estimation failed at {len(failed)} part-frames ({listed}{more}); "
                      "their poses are interpolated (see metadata 'failed_frames')", stacklevel=2)
    stages.timings["total"] = time.perf_counter() - start
    return prior


def _fit_jointly(prior: SpatPrior, frames, masks, options: ExtractOptions, stages: _Stages) -> SpatPrior:
    """The prior with its poses fitted again together with the object (:func:`joint_fit`), smoothed as before.

    A failed (interpolated) part-frame whose fitted silhouette then explains its mask
    (:func:`~marionette.reconstruct.quality.placed_frames`: it matches, or holds what something in front leaves of
    it) is listed as recovered, "placed by the joint fit"; the others stay failed. Metadata ``joint_fit``: the
    time, the Gaussians' count, the fit's silhouette IoU and how far the poses turned.
    """
    metadata = dict(prior.metadata)
    if prior.num_parts > 1:  # a part's pixels in a frame are not known: one mask for all (issue 52)
        metadata["joint_fit"] = {"skipped": "several parts: the joint fit is for one-part motion so far"}
        return dataclasses.replace(prior, metadata=metadata)
    with stages("joint", "fitting poses and object together") as progress:
        fit = joint_fit(frames, masks, prior, options=options.joint, progress=progress)
        poses, centres = fit.prior.poses, fit.prior.centroids[:, 0]  # frame 0 may have moved (its tracks slipped)
        if options.smoothing > 0:
            poses = smooth_poses(poses, options.smoothing, centers=centres)
        refined = prior.with_poses(poses, centres)
        failed, recovered = dict(metadata["failed_frames"]), dict(metadata["recovered_frames"])
        filmed = refined.motion_in("filmed")
        frame_of = {key: int(key.split(":")[1]) for key in failed}
        placed = placed_frames(lambda t: fit.reconstruction.render_filmed(filmed, t).alpha >= 0.5, masks,
                               frame_of.values())
        for key, t in frame_of.items():
            if t in placed:
                recovered[key] = f"placed by the joint fit ({placed[t]}); tracks: {failed.pop(key)}"
    quality = fit.reconstruction.quality.summary()
    metadata.update(failed_frames=failed, recovered_frames=dict(sorted(recovered.items())),
                    joint_fit={"seconds": round(fit.seconds, 2), "gaussians": len(fit.reconstruction.parts),
                               "silhouette_iou": quality["silhouette_iou"],
                               "silhouette_iou_worst": quality["silhouette_iou_worst"],
                               "turn_deg_median": round(float(np.median(fit.change_deg)), 3),
                               "turn_deg_max": round(float(np.max(fit.change_deg)), 3)})
    return dataclasses.replace(refined, metadata=metadata)
