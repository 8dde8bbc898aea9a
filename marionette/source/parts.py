"""Rigid parts of an object from its 2D tracks (motion segmentation by rigid-motion consistency).

Motion Marionette (Sec. 3) extracts one rigid transform sequence per part and
takes the parts as given. Here they come from the tracks: the tracks of one
rigid part are projections of fixed 3D points moved by one rigid motion per
frame, so a part is a set of tracks that one *rigid motion model* explains,

    x_mt ≈ π(R_t X_m + T_t)                  (perspective, known K)

with a pose ``(R_t, T_t)`` per frame and a 3D point ``X_m`` per track (camera
frame 0). A track seeded at frame s is triangulated from the frames where it
is visible, so re-seeded tracks need no special case. Per-frame 2D models
(affine, homography) are cheaper but do not tell a lid turning on a hinge
from the parallax of a box turning out of plane (a homography leaves about
the same residual on both). A motion is fitted by Levenberg–Marquardt bundle
adjustment over all its poses and points (Schur complement on the poses;
Triggs et al., "Bundle adjustment — a modern synthesis", 1999), started frame
by frame from a fronto-parallel surface, with a weak prior holding each point
near its first ray at the part's depth (it fixes the scale and the depth of
points seen without parallax). Long clips are subsampled to ``max_frames``
frames.

Segmentation, a sequential RANSAC (Torr & Zisserman, "MLESAC", CVIU 2000)
with spatial smoothing in the spirit of PEARL (Isack & Boykov, IJCV 2012):

1. A static model (identity poses) takes the tracks that do not move (label
   :data:`STATIC`); the camera is assumed static (camera motion is removed
   before).
2. Growing: a new part is the best of a few candidate motions, each
   refined together with the motions found so far (step 3) and judged by
   the cost of the labelling it leads to. The candidates: the motion of the
   tracks no motion explains yet; the best of local patch motions around
   seeds spread over their part of the frame-0 object and of all of them,
   each refitted to the tracks it explains (RMS reprojection error below
   ``threshold``) while that lowers its truncated quadratic cost (MSAC);
   for the first part, the whole
   object's motion when the caller has one (``whole``, from the full pose
   estimator, which a long out-of-plane turn does not defeat); and, once a
   part exists, the motions of halves of the object, since the motions found
   may explain every track within the threshold, a compromise between parts
   that move almost alike (the cars of ``davis_train``), and leave no track
   unexplained to seed another part. One candidate replaces the motions
   found instead of adding to them: from a pool of local motions (patches
   spread over the object, each refitted to the tracks it explains) and
   the motions found, the set of one more part that explains the tracks
   best (greedy, then swaps; PEARL's proposals, Isack & Boykov, IJCV 2012).
   A part that moves little against the rest (a drawer sliding out of a
   turning cabinet) needs it: the compromise found first explains most of
   its tracks, and the motions grown from there split the body instead.
3. Refinement: labels by iterated conditional modes on a k-nearest-neighbour
   graph of the tracks (neighbours in every frame where tracks are seeded),
   cost ``n_m ρ(e_ml) + β #{neighbours labelled otherwise}``, with ``e_ml``
   the mean squared reprojection error of track m under motion l, ``n_m``
   its number of frames and ``ρ(e) = min(e / σ², τ²)``; then each motion is
   refitted to the tracks of its label that it explains (or cannot judge
   yet, so that it extends in time; with ``whole`` given, the first part's
   motion gives way only to a refit that explains its tracks better); a few
   rounds. A part left with fewer than ``5 %`` of the frame-0 tracks (at
   least 8; only those it explains count) is dropped; growing stops when no
   candidate adds a part.
4. ``"auto"`` grows parts up to ``max_parts``, stops after the first count
   that does not lower the score, and keeps the count with the lowest
   score, a GRIC-style criterion (Torr, "Geometric motion segmentation and
   model selection", Phil. Trans. R. Soc. A, 1998)::

       score(P) = Σ_m n_m ρ(e_m) + P · penalty · τ² · 6 (T - 1)

   with ``σ = noise``, ``τ = threshold / noise`` and 6 (T - 1) pose
   parameters per moving part (the static group has none). The truncation
   caps what a track costs when no motion explains it, so a new part pays
   off only when it explains tracks that were unexplained (or explained
   markedly worse); each pose parameter costs ``penalty`` observations at
   the cap. Scores within a noise margin (``_SELECTION_MARGIN`` of one
   part's penalty) count as equal and the simpler model is taken, both for
   the count and for the whole object's motion against the segmentation's
   own first motion; :attr:`PartSegmentation.selection` says when that
   happened. The margin between real and spurious parts is thin
   (docs/benchmarks/parts.md), and a motion is fitted on ``fit_tracks``
   tracks drawn at random, enough for its cost not to vary by much of a
   part's penalty from draw to draw.

The noise σ is estimated from the data unless given: the rigid motions of
small patches of tracks (a dozen, spread over the object at frame 0) are
fitted to their own tracks, which measures the tracker's error without the
motion between parts; σ is 3 times the median RMS reprojection error of the
patch tracks (at least 0.08 px), the threshold 2 σ. Both the truncation and
the ``auto`` criterion use them, so they follow the footage (real tracks are
noisier than synthetic ones).

Tracks visible in fewer than ``min_length`` (subsampled) frames, and tracks
no motion explains within ``threshold``, are labelled :data:`OUTLIER`.
Frame-0 object pixels take the label of a distance-weighted vote of their
nearest labelled frame-0 tracks, then a majority filter.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from ..errors import InputError
from ..geometry import axis_angle_to_matrix
from .part_normals import (
    normal_blocks,
    point_steps,
    reduced_system,
    refine_pose,
    reprojection_cost,
    triangulate_points,
)
from .tracks import Tracks

__all__ = ["PartSegmentation", "segment_parts", "TooFewTracks", "STATIC", "OUTLIER", "OFF_OBJECT"]

#: Track label of the static group (motion consistent with identity).
STATIC = -1
#: Track label of tracks no model explains (or too short to tell).
OUTLIER = -2
#: Pixel label off the object mask.
OFF_OBJECT = -3

# A point moving by a quarter of its depth away from its prior costs as much
# as one pixel of reprojection error in one frame (weak: parallax decides).
_DEPTH_PRIOR = 16.0
# Default σ: this multiple of the median RMS error of tracks under the motion of their local patch
# (:func:`_estimate_noise`, _NOISE_PATCHES patches of _NOISE_PATCH tracks; a fit this local also
# absorbs part of the error, and tracker errors have heavier tails than Gaussian ones). The
# threshold: this multiple of σ.
_NOISE_SCALE = 3.0
# σ is never below this (pixels): a tracker keeps the tracks of a still, sharp surface exactly still, and a
# median over patches mostly on it would ask a moving part to explain its tracks to a few hundredths of a pixel.
_MIN_NOISE = 0.08
_THRESHOLD_SCALE = 2.0
_NOISE_PATCHES = 16
_NOISE_PATCH = 12
# Scores closer than this share of one part's penalty are within noise, and the simpler choice is
# taken: fewer parts, and the segmentation's own first motion over the whole-object one. Under another
# BLAS kernel the motions of a compromise fit (a hinge fitted as one body) can land in other local
# optima, whose scores differ by about a tenth of a part's penalty (docs/benchmarks/parts.md).
_SELECTION_MARGIN = 0.15


class TooFewTracks(InputError):
    """Too few tracks to segment (a plain object): the tracks cannot tell parts apart."""


class _Motion(NamedTuple):
    """One rigid motion over T frames, ``X_t = R_t X_0 + T_t`` (camera frame 0 → frame t).

    rotations : (T, 3, 3); translations : (T, 3); depths : (T,) median camera
    depth of the part's points per frame (where new points are placed);
    known : (T,) bool, frames where the fit saw the part (elsewhere the
    poses are held from the nearest earlier known frame, and not used).
    """

    rotations: np.ndarray
    translations: np.ndarray
    depths: np.ndarray
    known: np.ndarray


@dataclass(frozen=True)
class PartSegmentation:
    """Rigid parts of an object's tracks.

    Attributes
    ----------
    track_labels : (M,) int64
        Part of each track: ``0 .. P-1`` for the moving parts, ordered by
        size (number of tracks; part 0 is the largest), :data:`STATIC` (-1)
        for tracks that do not move, :data:`OUTLIER` (-2) for tracks no part
        explains or too short to tell.
    num_parts : int
        P, the number of moving parts.
    pixel_labels : (H, W) int16
        Label of every frame-0 object pixel (a moving part or :data:`STATIC`);
        :data:`OFF_OBJECT` (-3) elsewhere.
    scores : dict[int, float]
        Model-selection score (lower is better) of each number of parts grown.
    selection : str
        How the number of parts was chosen, and whether a better-scoring
        alternative was set aside as within noise (see ``margin``).
    residuals : (M,) float64
        RMS reprojection error (pixels) of each track under the model of its
        label; NaN for tracks too short to fit.
    noise, threshold : float
        σ and the threshold used (pixels), given or estimated.
    """

    track_labels: np.ndarray
    num_parts: int
    pixel_labels: np.ndarray
    scores: dict[int, float] = field(default_factory=dict)
    selection: str = ""
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    noise: float = np.nan
    threshold: float = np.nan


# ------------------------------------------------------------------ rigid motion model


def _prior_points(motion: _Motion, obs: np.ndarray, vis: np.ndarray) -> np.ndarray:
    """(M, 3) each track's first ray in a known frame, at the motion's depth there, moved back to frame 0."""
    start = np.argmax(vis, axis=0)
    ray = np.concatenate([obs[start, np.arange(len(start))], np.ones((len(start), 1))], axis=1)
    return np.einsum("mji,mj->mi", motion.rotations[start], ray * motion.depths[start, None]
                     - motion.translations[start])


def _triangulate(motion: _Motion, obs: np.ndarray, vis: np.ndarray, prior_weight: float,
                 iterations: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each track's 3D point under ``motion`` and its squared reprojection errors.

    obs (T, M, 2) normalised observations, vis (T, M); only the motion's
    known frames count. Gauss–Newton per track from its prior point
    (:func:`_prior_points`); ``prior_weight`` (normalised image units² per
    unit² of frame-0 space) holds it there where the observations do not
    decide. Returns points (M, 3), errors (T, M) (normalised units², 0
    where not counted) and the counted observations (T, M) bool.
    """
    vis = np.ascontiguousarray(vis & motion.known[:, None])
    points, err = triangulate_points(motion.rotations, motion.translations, _prior_points(motion, obs, vis),
                                     np.ascontiguousarray(obs, dtype=np.float64), vis, prior_weight, iterations)
    return points, err, vis


def _depths(rot: np.ndarray, trans: np.ndarray, points: np.ndarray, vis: np.ndarray,
            fallback: np.ndarray) -> np.ndarray:
    """(T,) median camera depth of the visible ``points`` (N, 3) per frame; ``fallback`` (T,) where none is."""
    z = np.einsum("tj,nj->tn", rot[:, 2], points) + trans[:, 2:3]
    z = np.where(vis, z, np.nan)
    seen = vis.any(axis=1)
    out = fallback.copy()
    out[seen] = np.nanmedian(z[seen], axis=1)
    return np.maximum(out, 1e-3)


def _initial_motion(obs: np.ndarray, vis: np.ndarray, min_points: int) -> _Motion:
    """Frame-by-frame poses of N tracks from a fronto-parallel start at depth 1.

    obs (T, N, 2), vis (T, N). The tracks seen in the first frame with at
    least ``min_points`` of them sit at depth 1 on their rays (its pose is
    identity, like every frame before it); at each later frame with
    ``min_points`` lifted tracks the pose follows from them (a few
    Gauss–Newton steps from the previous pose; other frames hold it), then
    the tracks seen for the first time are lifted onto their rays at the
    median depth of the others.
    """
    num_frames, n = vis.shape
    obs = np.ascontiguousarray(obs, dtype=np.float64)
    rot, trans = np.tile(np.eye(3), (num_frames, 1, 1)), np.zeros((num_frames, 3))
    depths = np.ones(num_frames)
    known = np.zeros(num_frames, bool)
    points = np.full((n, 3), np.nan)
    for t in range(num_frames):
        if t > 0:
            rot[t], trans[t], depths[t] = rot[t - 1], trans[t - 1], depths[t - 1]
        seen = vis[t] & ~np.isnan(points[:, 0])
        if seen.sum() >= min_points:
            refine_pose(rot[t], trans[t], points[seen], obs[t, seen], 3)
            depths[t] = np.median(points[seen] @ rot[t, 2] + trans[t, 2])
            known[t] = True
        new = vis[t] & np.isnan(points[:, 0])
        if not known.any() and new.sum() < min_points:
            continue
        known[t] = True
        ray = np.concatenate([obs[t, new], np.ones((new.sum(), 1))], axis=1) * depths[t]
        points[new] = (ray - trans[t]) @ rot[t]
    return _Motion(rot, trans, depths, known)


def _bundle_adjust(motion: _Motion, points: np.ndarray, prior: np.ndarray, obs: np.ndarray, vis: np.ndarray,
                   prior_weight: float, iterations: int) -> tuple[_Motion, np.ndarray]:
    """Levenberg–Marquardt on all poses and points jointly (Schur complement on the poses).

    points, prior (N, 3); obs (T, N, 2); vis (T, N). The first known frame
    stays fixed (the gauge); the prior term ``prior_weight |X - prior|²`` fixes the
    scale and what the observations leave free. The reduced camera system is
    dense, 6T x 6T, cheap for T of a few hundred (:mod:`.part_normals`).
    Returns the motion and points.
    """
    num_frames = len(vis)
    vis = np.ascontiguousarray(vis)
    obs, prior = np.ascontiguousarray(obs, dtype=np.float64), np.ascontiguousarray(prior, dtype=np.float64)
    rot, trans = motion.rotations, motion.translations
    gauge = int(np.argmax(motion.known))
    current, damping = reprojection_cost(rot, trans, points, prior, obs, vis, prior_weight), 1e-3
    for _ in range(iterations):
        u, v, w, g_cam, g_pt = normal_blocks(rot, trans, points, prior, obs, vis, prior_weight)
        u[gauge] += 1e12 * np.eye(6)  # the gauge: the first known frame does not move
        while True:
            reduced, rhs, vinv = reduced_system(u, v, w, vis, g_cam, g_pt, damping)
            d_cam = np.linalg.solve(reduced, rhs).reshape(num_frames, 6)
            turn = axis_angle_to_matrix(d_cam[:, :3])
            new_rot, new_trans = turn @ rot, np.einsum("tij,tj->ti", turn, trans) + d_cam[:, 3:]
            new_points = points + point_steps(vinv, w, vis, g_pt, d_cam)
            trial = reprojection_cost(new_rot, new_trans, new_points, prior, obs, vis, prior_weight)
            if trial <= current or damping > 1e6:
                break
            damping *= 10.0
        if trial > current:
            break
        converged = trial > (1.0 - 1e-4) * current
        rot, trans, points, current, damping = new_rot, new_trans, new_points, trial, damping * 0.3
        if converged:
            break
    return motion._replace(rotations=rot, translations=trans,
                           depths=_depths(rot, trans, points, vis, motion.depths)), points


def _fit_motion(obs: np.ndarray, vis: np.ndarray, prior_weight: float, iterations: int = 20,
                min_points: int = 4, start: _Motion | None = None) -> _Motion:
    """Rigid motion of N tracks (all on one part): :func:`_initial_motion` (or ``start``), then bundle adjustment.

    obs (T, N, 2), vis (T, N). Frames where fewer than ``min_points`` of
    the tracks are visible are not known to the motion.
    """
    motion = _initial_motion(obs, vis, min_points) if start is None else start
    motion = motion._replace(known=motion.known & (vis.sum(axis=1) >= min_points))
    vis = vis & motion.known[:, None]
    points, _, _ = _triangulate(motion, obs, vis, prior_weight)
    motion, _ = _bundle_adjust(motion, points, _prior_points(motion, obs, vis), obs, vis, prior_weight, iterations)
    return motion


def _static_motion(num_frames: int) -> _Motion:
    return _Motion(np.tile(np.eye(3), (num_frames, 1, 1)), np.zeros((num_frames, 3)), np.ones(num_frames),
                   np.ones(num_frames, bool))


# ------------------------------------------------------------------ segmentation


class _Problem(NamedTuple):
    """The usable tracks (U of them) in normalised coordinates, and the settings shared by the steps."""

    obs: np.ndarray  # (T, U, 2) normalised observations (0 where not visible)
    vis: np.ndarray  # (T, U) bool
    start: np.ndarray  # (U,) first visible frame
    frames: np.ndarray  # (U,) number of visible frames
    focal: float  # pixels per normalised unit
    prior_weight: float
    noise: float  # σ, pixels
    cap: float  # τ² = (threshold / noise)²
    fit_tracks: int
    rng: np.random.Generator
    guarded_refits: bool = False  # the first part's refit replaces its motion only when better (``whole`` given)


def _errors(problem: _Problem, motion: _Motion, idx: np.ndarray | None = None) -> np.ndarray:
    """Mean squared reprojection error (pixels²) of tracks ``idx`` (all when None) under ``motion``.

    Over the frames the motion knows; infinite for tracks seen in fewer
    than 3 of them (too few to judge).
    """
    sl = slice(None) if idx is None else idx
    _, err, counted = _triangulate(motion, problem.obs[:, sl], problem.vis[:, sl], problem.prior_weight)
    n = counted.sum(axis=0)
    return np.where(n >= 3, err.sum(axis=0) / np.maximum(n, 1) * problem.focal**2, np.inf)


def _fit(problem: _Problem, idx: np.ndarray, start: _Motion | None = None) -> _Motion:
    """Rigid motion of tracks ``idx``, fitted on at most ``fit_tracks`` of them (drawn at random), from ``start``."""
    if len(idx) > problem.fit_tracks:
        idx = np.sort(problem.rng.choice(idx, problem.fit_tracks, replace=False))
    return _fit_motion(problem.obs[:, idx], problem.vis[:, idx], problem.prior_weight, start=start)


def _robust(problem: _Problem, errors: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
    """Truncated quadratic ``n_m min(e / σ², τ²)`` of mean squared errors (..., U) pixels² of tracks ``idx``."""
    frames = problem.frames if idx is None else problem.frames[idx]
    return frames * np.minimum(errors / problem.noise**2, problem.cap)


def _neighbour_graph(uv: np.ndarray, vis: np.ndarray, start: np.ndarray, k: int) -> sparse.csr_matrix:
    """(U, U) symmetric 0/1 adjacency: k nearest neighbours at every frame where tracks are seeded.

    Tracks seeded later have no frame-0 position, so neighbours are taken in
    each seeding frame among the tracks visible there.
    """
    rows, cols = [], []
    for t in np.unique(start):
        ids = np.nonzero(vis[t])[0]
        if len(ids) < 2:
            continue
        _, nn = cKDTree(uv[t, ids]).query(uv[t, ids], k=min(k + 1, len(ids)))
        rows.append(np.repeat(ids, nn.shape[1] - 1))
        cols.append(ids[nn[:, 1:]].ravel())
    n = len(start)
    if not rows:
        return sparse.csr_matrix((n, n))
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)).tocsr()
    graph = ((graph + graph.T) > 0).astype(np.float64)
    return graph


def _icm(costs: np.ndarray, graph: sparse.csr_matrix, beta: float, labels: np.ndarray, sweeps: int = 4) -> np.ndarray:
    """Iterated conditional modes: labels (U,) minimising ``costs[l, m] + beta #{neighbours not l}``.

    costs (L, U). Updates all tracks at once per sweep (from ``labels``).
    """
    num_labels = costs.shape[0]
    degree = np.asarray(graph.sum(axis=1)).ravel()
    for _ in range(sweeps):
        agree = graph @ np.eye(num_labels)[labels]  # (U, L) neighbours per label
        new = np.argmin(costs.T + beta * (degree[:, None] - agree), axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


def _patch(xy: np.ndarray, ids: np.ndarray, seed: int, size: int) -> np.ndarray:
    """The ``size`` tracks of ``ids`` nearest to track ``seed`` at positions ``xy`` (U, 2)."""
    d = np.linalg.norm(xy[ids] - xy[seed], axis=1)
    return np.sort(ids[np.argsort(d)[:size]])


def _spread(xy: np.ndarray, ids: np.ndarray, count: int) -> np.ndarray:
    """``count`` of the tracks ``ids`` spread over their positions ``xy[ids]`` (xy (U, 2)).

    Farthest-point sampling from the track nearest their centre.
    """
    if len(ids) == 0:
        return ids
    xy = xy[ids]
    dist = np.linalg.norm(xy - xy.mean(axis=0), axis=1)
    seeds = [int(np.argmin(dist))]
    dist = np.linalg.norm(xy - xy[seeds[0]], axis=1)
    for _ in range(min(count, len(ids)) - 1):
        seeds.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(xy - xy[seeds[-1]], axis=1))
    return ids[seeds]


def _estimate_noise(problem: _Problem, uv: np.ndarray, patches: int, size: int) -> float:
    """Tracking noise (pixels): median RMS reprojection error of tracks under the rigid motion of their patch.

    The rigid motions of ``patches`` small patches of ``size`` tracks
    (spread over the object at frame 0), each fitted to its own tracks: a
    patch this small rarely straddles two parts, so what is left is the
    tracker's error, not the motion between parts (unlike the residuals
    of a one-part fit).
    """
    first = np.nonzero(problem.vis[0])[0]
    rms = []
    for seed in _spread(uv[0], first, patches):
        members = _patch(uv[0], first, seed, size)
        errors = _errors(problem, _fit(problem, members), members)
        rms.append(np.sqrt(errors[np.isfinite(errors)]))
    return float(np.median(np.concatenate(rms)))


def _grown(problem: _Problem, motion: _Motion, probe: np.ndarray, grow: int) -> tuple[_Motion, np.ndarray, float]:
    """``motion`` refitted to the tracks of ``probe`` it explains while that lowers its cost over ``probe`` (MSAC).

    Returns the motion, its errors over ``probe`` and its cost.
    """
    threshold = problem.cap * problem.noise**2
    errors = _errors(problem, motion, probe)
    cost = _robust(problem, errors, probe).sum()
    for _ in range(grow):
        inliers = probe[errors < threshold]
        if len(inliers) < 6:
            break
        refit = _fit(problem, inliers)
        refit_errors = _errors(problem, refit, probe)
        refit_cost = _robust(problem, refit_errors, probe).sum()
        if refit_cost >= cost:
            break
        motion, errors, cost = refit, refit_errors, refit_cost
    return motion, errors, cost


def _new_part(problem: _Problem, uv: np.ndarray, pool: np.ndarray, hypotheses: int, patch: int,
              grow: int = 3) -> _Motion:
    """Best rigid motion for the tracks ``pool`` no model explains yet (a sequential RANSAC step).

    Hypotheses: the motion of all of ``pool`` and of ``hypotheses`` local
    patches spread over the part of the object at frame 0 no motion
    explains yet. Each is refitted to the tracks it explains (RMS below the
    threshold) while that lowers its cost, the truncated quadratic over the
    pool (MSAC, Torr & Zisserman, CVIU 2000), and the cheapest wins: unlike
    a count of inliers, it prefers a motion that explains its tracks exactly
    to a compromise between two parts that explains both roughly.
    """
    probe = pool if len(pool) <= 4 * problem.fit_tracks else np.sort(
        problem.rng.choice(pool, 4 * problem.fit_tracks, replace=False))
    first = pool[problem.vis[0, pool]]
    fits = [_grown(problem, _fit(problem, members), probe, grow)
            for members in [pool] + [_patch(uv[0], first, s, patch) for s in _spread(uv[0], first, hypotheses)]]
    return min(fits, key=lambda fit: fit[2])[0]


def _patch_motions(problem: _Problem, uv: np.ndarray, count: int, patch: int, grow: int = 3) -> list:
    """The motions of ``count`` patches of ``patch`` tracks spread over the object at frame 0, each grown over all
    tracks (:func:`_grown`): a pool of local motions from which sets of parts are drawn (:func:`_best_set`)."""
    first = np.nonzero(problem.vis[0])[0]
    every = np.arange(problem.vis.shape[1])
    return [_grown(problem, _fit(problem, _patch(uv[0], first, seed, patch)), every, grow)[:2]
            for seed in _spread(uv[0], first, count)]


def _best_set(costs: np.ndarray, base: np.ndarray, size: int) -> list[int]:
    """Rows of ``costs`` (N, U) whose track-wise minimum, with ``base`` (U,), sums lowest: ``size`` of them.

    Greedy, then each chosen row swapped for a better one while any is (a local search on the labelling cost
    without the smoothness term, for PEARL-style proposals; Isack & Boykov, IJCV 2012).
    """
    chosen: list[int] = []
    for _ in range(min(size, len(costs))):
        current = np.minimum.reduce([base] + [costs[i] for i in chosen])
        gains = np.minimum(costs, current).sum(axis=1)
        gains[chosen] = np.inf
        chosen.append(int(np.argmin(gains)))

    def total(rows: list[int]) -> float:
        return float(np.minimum.reduce([base] + [costs[i] for i in rows]).sum())

    best, improved = total(chosen), True
    while improved:
        improved = False
        for slot in range(len(chosen)):
            for row in range(len(costs)):
                if row in chosen:
                    continue
                trial = chosen[:slot] + [row] + chosen[slot + 1:]
                cost = total(trial)
                if cost < best - 1e-9:
                    chosen, best, improved = trial, cost, True
    return chosen


class _Level(NamedTuple):
    """The segmentation with P moving parts: its motions (static first if modelled), labels and errors."""

    motions: list
    labels: np.ndarray  # (U,) index into motions
    errors: np.ndarray  # (L, U) mean squared reprojection errors, pixels²
    score: float


def _refine(problem: _Problem, graph: sparse.csr_matrix, beta: float, motions: list, errors: np.ndarray,
            first_moving: int, min_part: int, rounds: int) -> _Level:
    """Labels and motions refined together from each track's best motion; parts left too small dropped.

    ``rounds`` times: labels by :func:`_icm`, then each moving motion refitted
    to the tracks of its label. errors (L, U) of ``motions`` (not modified).
    Returns the level with its labelling cost (the truncated quadratic) as
    its score, before any penalty.
    """
    threshold = problem.cap * problem.noise**2
    motions, errors = list(motions), errors.copy()
    labels = np.argmin(errors, axis=0)
    for _ in range(rounds):
        labels = _icm(_robust(problem, errors), graph, beta, labels)
        for part in range(first_moving, len(motions)):
            # Only the tracks it explains, so that a part does not bend towards what it does not
            # (and those it cannot judge yet, seen in too few of its frames: so it extends in time).
            members = np.nonzero((labels == part) & ((errors[part] < threshold) | np.isinf(errors[part])))[0]
            if len(members) >= min_part:
                refit = _fit(problem, members)
                refit_errors = _errors(problem, refit)
                mine = labels == part
                # A refit starts from a fronto-parallel surface; the first part's motion, grown from the
                # full pose estimator's (``whole``), may be far better, so it only gives way to a better refit.
                if not (problem.guarded_refits and part == first_moving) or (
                        _robust(problem, refit_errors[mine], mine).sum()
                        < _robust(problem, errors[part][mine], mine).sum()):
                    motions[part], errors[part] = refit, refit_errors
    # A part that explains too few tracks on the object at frame 0 was not one. Only the tracks it
    # explains count: the smoothness term also hands it unexplained neighbours (a thin part's drifting
    # tracks), which made a fragment of 12 drifting lid tracks a part of the hinge.
    labels = _icm(_robust(problem, errors), graph, beta, labels)
    explained = errors[labels, np.arange(len(labels))] < threshold
    sizes = np.bincount(labels[problem.vis[0] & explained], minlength=len(motions))
    keep = np.ones(len(motions), bool)
    keep[first_moving:] = sizes[first_moving:] >= min_part
    if not keep.all():
        motions = [m for m, k in zip(motions, keep) if k]
        errors = errors[keep]
        labels = _icm(_robust(problem, errors), graph, beta, np.argmin(errors, axis=0))
    cost = float(_robust(problem, errors[labels, np.arange(len(labels))]).sum())
    return _Level(motions, labels, errors, cost)


def _grow(problem: _Problem, uv: np.ndarray, graph: sparse.csr_matrix, beta: float, static: bool, max_parts: int,
          min_part: int, penalty: float, hypotheses: int, patch: int, rounds: int, auto: bool,
          whole: _Motion | None = None, margin: float = 0.0, pool: int = 16) -> dict[int, _Level]:
    """Add moving parts one at a time, refining all labels and motions after each; every level by P.

    ``auto``: stop after the first level whose score is not below the best before. ``whole``: a motion
    of the whole object, one more candidate for the first part, taken only when its level scores
    better than the others by more than ``margin`` (a compromise fit's motion is the least repeatable).
    ``pool``: local motions drawn once (:func:`_patch_motions`), whose best set is one more candidate.
    """
    num_frames, num_tracks = problem.vis.shape
    motions = [_static_motion(num_frames)] if static else []
    first_moving = len(motions)
    errors = np.stack([_errors(problem, m) for m in motions]) if motions else np.zeros((0, num_tracks))
    threshold = problem.cap * problem.noise**2
    first = np.nonzero(problem.vis[0])[0]
    local = _patch_motions(problem, uv, pool, patch) if pool else []
    levels: dict[int, _Level] = {}
    for _ in range(max_parts):
        # A part must show on the object at frame 0 (its poses map those points): candidates are
        # seeded there. The motion of the tracks no motion explains, when enough frame-0 tracks are
        # left; and once a part exists, the motions of halves of the object, since the motions found
        # may explain every track roughly, a compromise between parts that move almost alike (the
        # cars of a train). Each is added to the motions found so far; one more candidate replaces
        # them: the set of local motions (and those found) that explains the tracks best, which a
        # part that moves little against the rest (a drawer sliding out of a turning cabinet) needs,
        # as the compromise found first explains its tracks too.
        explained = errors.min(axis=0) < threshold if len(errors) else np.zeros(num_tracks, bool)
        added = []  # (motion, handicap on its level's score)
        if (~explained & problem.vis[0]).sum() >= min_part:
            added.append((_new_part(problem, uv, np.nonzero(~explained)[0], hypotheses, patch), 0.0))
        if len(motions) > first_moving:
            added += [(_fit(problem, _patch(uv[0], first, seed, len(first) // 2)), 0.0)
                      for seed in _spread(uv[0], first, hypotheses)]
        elif whole is not None:
            added.append((whole, margin))
        candidates = [(motions + [motion], np.vstack([errors, _errors(problem, motion)]), handicap)
                      for motion, handicap in added]
        if local:
            proposals = local + list(zip(motions[first_moving:], errors[first_moving:]))
            base = _robust(problem, errors[0]) if static else np.full(num_tracks, np.inf)
            rows = _best_set(np.stack([_robust(problem, e) for _, e in proposals]), base,
                             len(motions) - first_moving + 1)
            candidates.append((motions[:first_moving] + [proposals[i][0] for i in rows],
                               np.vstack([errors[:first_moving]] + [proposals[i][1][None] for i in rows]), 0.0))
        best, best_rank = None, np.inf
        for candidate, candidate_errors, handicap in candidates:
            level = _refine(problem, graph, beta, candidate, candidate_errors, first_moving, min_part, rounds)
            if len(level.motions) > len(motions) and level.score + handicap < best_rank:
                best, best_rank = level, level.score + handicap
        if best is None:
            break
        motions, errors = best.motions, best.errors
        num_parts = len(motions) - first_moving
        score = best.score + penalty * num_parts * 6 * (num_frames - 1)
        worse = bool(levels) and score >= min(level.score for level in levels.values())
        levels[num_parts] = best._replace(score=score)
        if auto and worse:
            break
    return levels


def _select_count(scores: dict[int, float], margin: float) -> tuple[int, str]:
    """The fewest parts whose score is within ``margin`` of the best, and a sentence saying how it was chosen."""
    best = min(scores, key=scores.get)
    count = min(p for p, score in scores.items() if score <= scores[best] + margin)
    if count == best:
        return count, f"{count} part(s): lowest score"
    return count, (f"{count} part(s): {best} scored lower by {scores[count] - scores[best]:.1f}, within the noise "
                   f"margin {margin:.1f}, so the simpler model was kept")


def _pixel_labels(positions: np.ndarray, labels: np.ndarray, mask: np.ndarray, k: int = 5,
                  filter_size: int = 5) -> np.ndarray:
    """Label every pixel of ``mask`` (H, W) by a vote of its ``k`` nearest tracks, then a majority filter.

    positions (N, 2) frame-0 pixel positions of labelled tracks, labels (N,)
    (>= STATIC). The vote weighs each track by 1 / (1 + distance); the
    filter takes, per pixel, the most frequent label among the object
    pixels of its ``filter_size`` square. Returns (H, W) int16, OFF_OBJECT
    outside the mask.
    """
    out = np.full(mask.shape, OFF_OBJECT, np.int16)
    vv, uu = np.nonzero(mask)
    values = np.unique(labels)
    dist, nn = cKDTree(positions).query(np.stack([uu, vv], axis=1), k=min(k, len(positions)))
    dist, nn = dist.reshape(len(uu), -1), nn.reshape(len(uu), -1)
    votes = np.zeros((len(uu), len(values)))
    slot = np.searchsorted(values, labels[nn])
    np.add.at(votes, (np.arange(len(uu))[:, None], slot), 1.0 / (1.0 + dist))
    vote = np.argmax(votes, axis=1)
    # Majority filter among object pixels (box-filtered indicator per label).
    counts = np.zeros((len(values),) + mask.shape, np.float32)
    counts[vote, vv, uu] = 1.0
    counts = np.stack([cv2.boxFilter(c, -1, (filter_size, filter_size), normalize=False) for c in counts])
    out[vv, uu] = values[np.argmax(counts[:, vv, uu], axis=0)]
    return out


def segment_parts(tracks: Tracks, object_mask0: np.ndarray, K: np.ndarray, num_parts: int | str = "auto", *,
                  max_parts: int = 4, noise: float | None = None, threshold: float | None = None,
                  penalty: float = 3.0,
                  smoothness: float = 3.0, neighbours: int = 8, min_length: int = 4, static: bool = True,
                  max_frames: int = 24, hypotheses: int = 4, patch: int = 24, fit_tracks: int = 1000,
                  rounds: int = 2, pool: int = 16, seed: int = 0, whole: np.ndarray | None = None) -> PartSegmentation:
    """Segment an object's tracks into rigid parts (see the module docstring for the method).

    Parameters
    ----------
    tracks : Tracks
        T frames, M tracks on the object (static camera, or camera motion removed).
    object_mask0 : ndarray, shape (H, W), bool
        The object at frame 0; its pixels get part labels.
    K : ndarray, shape (3, 3)
        Camera intrinsics.
    num_parts : int or "auto"
        Number of moving parts, or ``"auto"`` to choose 1 .. ``max_parts`` by
        the model-selection score. Fewer are returned when no candidate
        motion keeps a part of its own (at least 5 % of the frame-0 tracks,
        at least 8).
    max_parts : int
        Most moving parts ``"auto"`` considers.
    noise : float or None
        σ, the expected reprojection error (pixels) of a track under its
        part's rigid motion; None: estimated from the tracks (see the
        module docstring), reported in the result.
    threshold : float or None
        A track is explained by a motion when its RMS reprojection error is
        below this (pixels); above it, all motions cost it the same. None:
        2 σ.
    penalty : float
        Cost of one pose parameter (6 per frame step and part) in units of
        an observation at the ``threshold``; larger prefers fewer parts.
    smoothness : float
        Weight of the label smoothness: a track whose ``neighbours`` nearest
        tracks all carry another label pays ``smoothness`` times a track of
        median length at the threshold.
    neighbours : int
        k of the nearest-neighbour graph.
    min_length : int
        Tracks visible in fewer of the frames used are labelled :data:`OUTLIER`.
    static : bool
        Model a static group (identity motion, label :data:`STATIC`). One
        with fewer frame-0 tracks than a part needs is given to the parts.
    max_frames : int
        Longer clips are subsampled to at most this many frames (every k-th).
    hypotheses, patch, fit_tracks, rounds : int
        Local hypotheses per new part (patches, and halves of the object) and
        the patches' number of tracks; most tracks a motion is fitted on
        (drawn at random); label/motion refinement rounds.
    pool : int
        Local motions (of patches spread over the object) from which the set
        of parts that explains the tracks best is one more candidate at
        each count; 0: none.
    seed : int
        Seed of the random draws.
    whole : ndarray, shape (T, 4, 4), optional
        Camera-frame poses of the whole object as one rigid body (e.g.
        :func:`~marionette.source.rigid.fit_rigid`'s), translations in units
        of the object's frame-0 depth: one more candidate for the first part,
        refined from there. The segmentation's own fits start from a
        fronto-parallel surface, which a long out-of-plane turn defeats (on
        ``davis_car-turn`` such a fit explains half the tracks, the full pose
        estimator's 94 %); a refit replaces a part's motion only when it
        explains the part's tracks better.

    Returns
    -------
    PartSegmentation
    """
    if not isinstance(tracks, Tracks):
        raise InputError(f"segment_parts: tracks must be a Tracks, got {type(tracks).__name__}")
    mask = np.asarray(object_mask0)
    if mask.ndim != 2 or not mask.any():
        raise InputError(f"segment_parts: object_mask0 must be a non-empty (H, W) mask, got shape {mask.shape}")
    mask = mask.astype(bool)
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"segment_parts: K must be a finite (3, 3) intrinsic matrix, got shape {K.shape}")
    auto = isinstance(num_parts, str) and num_parts == "auto"
    if not auto and (isinstance(num_parts, (bool, str)) or int(num_parts) != num_parts or num_parts < 1):
        raise InputError(f"segment_parts: num_parts must be 'auto' or an integer >= 1, got {num_parts!r}")
    for name, value in (("noise", noise), ("threshold", threshold), ("penalty", penalty)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"segment_parts: {name} must be a positive number, got {value!r}")

    # Rigidity shows as well on every other frame of a long clip: keep at most ``max_frames``.
    kept = np.arange(0, tracks.num_frames, -(-tracks.num_frames // max_frames))
    visible = tracks.visible[kept]
    usable = visible.sum(axis=0) >= min_length
    at_first = int((usable & visible[0]).sum())
    min_part = max(8, int(0.05 * at_first))
    if usable.sum() < min_part:
        raise TooFewTracks(f"segment_parts: {usable.sum()} tracks are visible in at least {min_length} frames; "
                         f"at least {min_part} are needed")
    if not at_first:  # parts are found and labelled on the first frame
        raise InputError("segment_parts: no track is on the object in the first frame (start where the object "
                         "is in view)")
    uv = tracks.uv[kept][:, usable].astype(np.float64)
    vis = visible[:, usable]
    homogeneous = np.concatenate([np.nan_to_num(uv), np.ones(uv.shape[:2] + (1,))], axis=2)
    obs = (homogeneous @ np.linalg.inv(K).T)[..., :2]
    focal = float(np.sqrt(K[0, 0] * K[1, 1]))
    frames = vis.sum(axis=0)
    problem = _Problem(obs=np.where(vis[..., None], obs, 0.0), vis=vis, start=np.argmax(vis, axis=0),
                       frames=frames, focal=focal, prior_weight=_DEPTH_PRIOR / focal**2, noise=np.nan, cap=np.nan,
                       fit_tracks=int(fit_tracks), rng=np.random.default_rng(seed))
    if noise is None:
        noise = max(_NOISE_SCALE * _estimate_noise(problem, uv, _NOISE_PATCHES, _NOISE_PATCH), _MIN_NOISE)
    if threshold is None:
        threshold = _THRESHOLD_SCALE * noise
    problem = problem._replace(noise=float(noise), cap=float(threshold / noise) ** 2)
    graph = _neighbour_graph(uv, vis, problem.start, neighbours)
    beta = smoothness * problem.cap * float(np.median(frames)) / neighbours
    start = None
    if whole is not None:
        whole = np.asarray(whole, dtype=np.float64)
        if whole.shape != (tracks.num_frames, 4, 4) or not np.isfinite(whole).all():
            raise InputError(f"segment_parts: whole must be finite ({tracks.num_frames}, 4, 4) poses, "
                             f"got shape {whole.shape}")
        rot, trans = whole[kept, :3, :3], whole[kept, :3, 3]
        # New points go at the depth of the frame-0 point on the optical axis at depth 1, moved.
        start = _fit(problem, np.arange(vis.shape[1]),
                     start=_Motion(rot, trans, rot[:, 2, 2] + trans[:, 2], vis.sum(axis=1) >= 4))
        problem = problem._replace(guarded_refits=True)

    margin = _SELECTION_MARGIN * penalty * problem.cap * 6 * (len(kept) - 1)  # of one part's penalty
    levels = _grow(problem, uv, graph, beta, static, max_parts if auto else int(num_parts), min_part,
                   penalty * problem.cap, hypotheses, patch, rounds, auto, whole=start, margin=margin, pool=pool)
    if not levels:  # everything is static
        num_tracks = vis.shape[1]
        chosen = _Level([_static_motion(len(vis))], np.zeros(num_tracks, np.int64), np.zeros((1, num_tracks)), 0.0)
        selection = "no moving part"
    elif auto:
        count, selection = _select_count({p: level.score for p, level in levels.items()}, margin)
        chosen = levels[count]
    else:
        chosen, selection = levels[max(levels)], f"{max(levels)} part(s) as asked"

    first_moving = 1 if static and levels else 0
    if first_moving and (chosen.labels[vis[0]] == 0).sum() < min_part:
        # Too small a static group to be one (points near a slowly turning part's axis barely
        # move): its tracks go to the moving parts.
        costs = _robust(problem, chosen.errors)
        costs[0] = np.inf
        start = np.where(chosen.labels == 0, np.argmin(chosen.errors[1:], axis=0) + 1, chosen.labels)
        chosen = chosen._replace(labels=_icm(costs, graph, beta, start))
    # Moving parts by size, then the static group and the outliers.
    sizes = np.bincount(chosen.labels, minlength=len(chosen.motions))[first_moving:]
    order = np.argsort(-sizes, kind="stable")
    code = np.empty(len(chosen.motions), np.int64)
    code[:first_moving] = STATIC
    code[first_moving + order] = np.arange(len(order))
    own = chosen.errors[chosen.labels, np.arange(vis.shape[1])]
    labels_u = np.where(own < threshold**2, code[chosen.labels], OUTLIER)
    labels = np.full(tracks.num_tracks, OUTLIER, np.int64)
    labels[usable] = labels_u
    residuals = np.full(tracks.num_tracks, np.nan)
    residuals[usable] = np.sqrt(own)

    # Pixels: from the labelled tracks seen at frame 0 (or where they start, if none is).
    labelled = labels >= STATIC
    at0 = labelled & visible[0]
    if at0.any():
        positions = tracks.uv[0, at0]
    else:
        at0 = labelled if labelled.any() else usable
        positions = tracks.uv[tracks.start[at0], np.nonzero(at0)[0]]
    pixel_labels = _pixel_labels(positions.astype(np.float64), np.maximum(labels[at0], STATIC), mask)
    return PartSegmentation(track_labels=labels, num_parts=int(len(order)), pixel_labels=pixel_labels,
                            scores={p: level.score for p, level in levels.items()}, selection=selection,
                            residuals=residuals,
                            noise=problem.noise, threshold=float(threshold))
