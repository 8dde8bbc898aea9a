"""Motion fidelity: how alike two videos move, compared through point tracks.

In the spirit of the motion-fidelity score of Yatim et al., "Space-Time
Diffusion Features for Zero-Shot Text-Driven Motion Transfer" (CVPR 2024):
both videos are tracked, every track is matched with its most similar track
in the other video, and the best similarities are averaged both ways::

    fidelity = ½ (mean_{a ∈ A} max_{b ∈ B} sim(a, b) + mean_{b ∈ B} max_{a ∈ A} sim(a, b))

Our own tracker (:func:`~marionette.source.tracks.track`) replaces
CoTracker. Where Yatim et al. average the cosine of the two tracks' per-frame
displacements (blind to speed), we divide each displacement by the object's
size in its own video (RMS radius of the mask, in pixels, per frame) and
compare magnitudes too: per step ``t``::

    s_t = (2 a_t · b_t + ε²) / (|a_t|² + |b_t|² + ε²)

which is 1 when the size-normalised displacements are equal, about the cosine
when their lengths are alike, near 0 when one moves and the other is still,
and −1 for opposite motion; ``ε`` (``FidelityOptions.still``) makes two still
steps agree instead of comparing the tracker's jitter. ``sim(a, b)`` is the
mean of ``s_t`` over the steps both tracks see.

A retimed result (another speed, a loop, reversed) is compared with the
source at the times it shows: given each result frame's source time ``τ_i``,
the source's tracks and object size are read at ``τ_i`` (linear between
frames), so step ``i`` of the result meets the source's step from ``τ_i`` to
``τ_{i+1}``, and the score does not change with the playback controls.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..source.tracks import track

__all__ = ["FidelityOptions", "motion_fidelity", "white_background_masks", "normalised_displacements",
           "track_similarity"]


@dataclass(frozen=True)
class FidelityOptions:
    """Settings of :func:`motion_fidelity`.

    Attributes
    ----------
    spacing : int
        Seed grid spacing of the tracker, pixels.
    max_tracks : int
        At most this many tracks per video are compared (evenly subsampled).
    min_steps : int
        Tracks seen over fewer frame steps are left out; a pair of tracks is
        compared only when they share at least this many steps and at least
        half of the query track's steps.
    still : float
        ``ε``: displacement per frame, in object radii, below which motion
        hardly counts (tracker jitter on a still object is well below it).
    """

    spacing: int = 6
    max_tracks: int = 800
    min_steps: int = 4
    still: float = 0.005


def white_background_masks(frames: np.ndarray, level: int = 245) -> np.ndarray:
    """(T, H, W) bool: pixels of (T, H, W, 3) uint8 frames that are not white (a render's object).

    Pixels with every channel at or above ``level`` are background; the mask
    is closed (3x3) so that white specks on the object do not punch holes.
    """
    mask = (np.asarray(frames) < level).any(axis=3).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    return np.stack([cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel) for m in mask]).astype(bool)


def _object_masks(frames: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
    """The given masks, or the object found in the frames: non-white on a white background, else automatic."""
    if masks is not None:
        masks = np.asarray(masks, dtype=bool)
        if masks.shape != frames.shape[:3]:
            raise InputError(f"masks must be (T, H, W) = {frames.shape[:3]}, got {masks.shape}")
        return masks
    border = np.concatenate([frames[:, 0], frames[:, -1], frames[:, :, 0], frames[:, :, -1]], axis=1)
    if np.median(border.min(axis=2)) >= 245:
        return white_background_masks(frames)
    from ..source.foreground import (
        auto_masks,  # the salient-object model loads only when needed
    )

    return auto_masks(frames)


def _object_radius(masks: np.ndarray) -> np.ndarray:
    """(T,) RMS distance in pixels of each mask's pixels to their centroid; empty masks take the median."""
    radii = np.full(len(masks), np.nan)
    for t, m in enumerate(masks):
        v, u = np.nonzero(m)
        if len(u) > 1:
            radii[t] = max(np.sqrt(u.var() + v.var()), 1.0)
    if np.all(np.isnan(radii)):
        raise InputError("no object found in any frame: cannot measure its motion")
    return np.where(np.isnan(radii), np.nanmedian(radii), radii)


def _at_times(values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(T', ...) ``values`` (T, ...) read at fractional frame ``times`` (T',) in [0, T-1], linear between frames.

    A time on a frame takes that frame's value alone (a NaN next door does not spread).
    """
    lo = np.clip(np.floor(times).astype(int), 0, len(values) - 2)
    w = (times - lo).reshape((-1,) + (1,) * (values.ndim - 1))
    mixed = (1 - w) * values[lo] + w * values[lo + 1]
    return np.where(w == 0, values[lo], np.where(w == 1, values[lo + 1], mixed))


def normalised_displacements(frames: np.ndarray, masks: np.ndarray, options: FidelityOptions = FidelityOptions(),
                             times: np.ndarray | None = None) -> np.ndarray:
    """Track the object and return its per-step displacements in object radii.

    Parameters
    ----------
    frames : (T, H, W, 3) uint8
    masks : (T, H, W) bool, the object.
    times : (T',) float in [0, T-1] or None
        Fractional frames to take the steps between (tracks and object size
        read linearly between frames); None: every frame, ``T' = T``.

    Returns
    -------
    (T'-1, M, 2) float64: ``(uv[t+1] - uv[t]) / radius[t]`` for each kept
    track, NaN where the track is not seen at both ends of the step.
    """
    uv = track(frames, masks, spacing=options.spacing).uv.astype(np.float64)  # (T, M, 2)
    radius = _object_radius(masks)  # (T,)
    if times is not None:
        uv, radius = _at_times(uv, times), _at_times(radius, times)
    d = np.diff(uv, axis=0) / radius[:-1, None, None]
    steps = np.isfinite(d[..., 0]).sum(axis=0)
    d = d[:, steps >= options.min_steps]
    if d.shape[1] > options.max_tracks:
        d = d[:, np.linspace(0, d.shape[1] - 1, options.max_tracks).round().astype(int)]
    return d


def track_similarity(a: np.ndarray, b: np.ndarray, still: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean per-step similarity ``s_t`` (module docstring) of every pair of tracks.

    Parameters
    ----------
    a : (S, M, 2), b : (S, N, 2) float
        Normalised displacements, NaN where a track is not seen.
    still : float
        ``ε`` of ``s_t``.

    Returns
    -------
    sim : (M, N) float64, mean of ``s_t`` over the steps both tracks see (0 where none).
    common : (M, N) int64, the number of those steps.
    """
    seen_a, seen_b = np.isfinite(a[..., 0]), np.isfinite(b[..., 0])
    a, b = np.nan_to_num(a), np.nan_to_num(b)
    total = np.zeros((a.shape[1], b.shape[1]))
    common = np.zeros((a.shape[1], b.shape[1]), np.int64)
    eps2 = still ** 2
    for at, bt, sa, sb in zip(a, b, seen_a, seen_b):
        num = 2 * at @ bt.T + eps2
        den = (at ** 2).sum(1)[:, None] + (bt ** 2).sum(1)[None] + eps2
        s = np.divide(num, den, out=np.ones_like(num), where=den > 0)  # two still steps (ε = 0) agree
        both = sa[:, None] & sb[None]
        total += np.where(both, s, 0.0)
        common += both
    return np.divide(total, common, out=np.zeros_like(total), where=common > 0), common


def _best_matches(sim: np.ndarray, common: np.ndarray, steps: np.ndarray, min_steps: int) -> np.ndarray:
    """(M,) best similarity of each query track (rows) over the tracks it shares enough steps with; 0 if none."""
    ok = (common >= min_steps) & (common >= 0.5 * steps[:, None])
    best = np.where(ok, sim, -np.inf).max(axis=1)
    return np.where(np.isfinite(best), best, 0.0)


def motion_fidelity(source_frames: np.ndarray, source_masks: np.ndarray | None, result_frames: np.ndarray,
                    result_masks: np.ndarray | None, *, source_times: np.ndarray | None = None,
                    options: FidelityOptions = FidelityOptions()) -> float:
    """Motion fidelity of a result video to a source video, in [-1, 1] (1: the same motion).

    Parameters
    ----------
    source_frames : (T, H, W, 3) uint8
    source_masks : (T, H, W) bool or None
        The object. None: the non-white pixels when the video is on a white
        background (our renders), else automatic masks
        (:func:`~marionette.source.foreground.auto_masks`).
    result_frames : (T', H', W', 3) uint8, any size.
    result_masks : (T', H', W') bool or None, as for the source.
    source_times : (T',) float in [0, T-1] or None
        The source time each result frame shows (e.g.
        :func:`~marionette.transfer.controls.source_times` of the controls
        that made it); the source is compared at these times (module
        docstring). None: frame t of one is frame t of the other, and both
        videos are cut to the shorter one's length.
    options : FidelityOptions

    A track with no counterpart sharing enough of its steps scores 0.
    """
    videos = []
    for name, frames, masks in (("source", source_frames, source_masks), ("result", result_frames, result_masks)):
        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.shape[3] != 3 or frames.dtype != np.uint8 or len(frames) < 2:
            raise InputError(f"{name} video must be (T, H, W, 3) uint8 with T >= 2, got {frames.shape} {frames.dtype}")
        videos.append((frames, _object_masks(frames, masks)))
    (src, src_masks), (res, res_masks) = videos
    if source_times is None:
        t = min(len(src), len(res))
        a = normalised_displacements(src[:t], src_masks[:t], options)
        b = normalised_displacements(res[:t], res_masks[:t], options)
    else:
        source_times = np.asarray(source_times, dtype=np.float64)
        if source_times.shape != (len(res),) or not np.all((source_times >= 0) & (source_times <= len(src) - 1)):
            raise InputError(f"source_times must be ({len(res)},) within 0..{len(src) - 1}, one per result frame")
        a = normalised_displacements(src, src_masks, options, times=source_times)
        b = normalised_displacements(res, res_masks, options)
    if a.shape[1] == 0 or b.shape[1] == 0:
        raise InputError(f"no track on the object lasts {options.min_steps} frame steps in the "
                         f"{'source' if a.shape[1] == 0 else 'result'} video (too short, or no texture)")
    sim, common = track_similarity(a, b, options.still)
    steps_a, steps_b = np.isfinite(a[..., 0]).sum(0), np.isfinite(b[..., 0]).sum(0)
    best_a = _best_matches(sim, common, steps_a, options.min_steps)
    best_b = _best_matches(sim.T, common.T, steps_b, options.min_steps)
    return float(0.5 * (best_a.mean() + best_b.mean()))
