"""The source camera's focal length, estimated from the object's own tracks.

Real clips come without intrinsics; the extraction assumes a 60° horizontal
field of view. Where the object turns or comes closer, perspective tells the
focal length: a rigid body seen through the wrong one does not fit its
tracks as well (a wide angle exaggerates how the near side grows). Bundle
adjustment with the focal length free does not find it (the focal trades
against every depth and translation along a long, flat valley; tried, it
stays where it starts), so it is searched in one dimension instead:

1. the body's poses and points are fitted once at the given focal ``f``
   (:func:`~marionette.source.rigid.fit_rigid`);
2. for each candidate ``a f`` on a log grid, that fit is carried over
   exactly as far as the projections allow (camera-frame depths scaled by
   ``a``, which keeps every projected point where it was; rotations snapped
   to the nearest rotation) and bundle adjusted
   (:func:`~marionette.source.bundle.bundle_adjust`) on a fixed sample of
   inlier tracks, without the depth prior;
3. the robust reprojection cost against ``log a`` is a smooth valley; a
   parabola through the best grid point and its neighbours gives the focal;
4. the first fit carries the start's shape guess, which pulls the answer
   towards the start, so where it moved the focal length a second search
   starts from its answer (docs/benchmarks/focal.md).

When the cost barely changes next to its best candidate, or does not climb
steadily away from it on both sides (a translating or in-plane turning
object: the focal leaves no trace in the tracks, and what is left is noise),
or is still falling at the edge of the last search, the given focal is kept.
With several parts the fit follows the body's dominant rigid motion (its
RANSAC inliers).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..camera import fov_from_focal
from ..reproducible import snap
from .bundle import bundle_adjust, huber_cost
from .rigid import RigidOptions, ShapePrior, fit_rigid
from .tracks import Tracks

__all__ = ["FocalEstimate", "estimate_focal", "FOCAL_SCALES"]

#: Candidate focal lengths, as factors of the given one: 2^(k/3), k = -3..3 (at a 60° start, 98° to 32°).
FOCAL_SCALES = 2.0 ** (np.arange(-3, 4) / 3.0)
#: The focal length counts as measured when the cost at the best candidate's neighbours on the grid (26 %
#: longer or shorter) is higher by this share on average, and climbs on from there: 4-50 % where the object
#: turns in depth (the synthetic out-of-plane turns, car-turn), 0.0-0.5 % where it translates (car-shadow).
_MIN_RISE = 0.01
#: Tracks in the bundle adjustments (a fixed random sample of those with enough inlier observations).
_TRACKS = 400
_MIN_OBSERVATIONS = 3
#: A second search starts from the first one's answer when that moved the focal length by more than this share.
_SETTLED = 0.05
#: Cost evaluations of each bundle adjustment.
_BA_EVALUATIONS = 40
#: An estimate is rounded to this many pixels: far finer than its accuracy (a few percent), far coarser than
#: the 1e-9 px by which another BLAS kernel moves it (docs/benchmarks/reproducibility_real.md).
_FOCAL_STEP = 2.0 ** -6
#: Huber scale of the reprojection cost (pixels), as the pose fit's refinement uses.
_LOSS_SCALE = 1.0


@dataclass(frozen=True)
class FocalEstimate:
    """What :func:`estimate_focal` found.

    Attributes
    ----------
    focal : float
        The focal length to use, pixels (the given one when not measured).
    measured : bool
        Whether the tracks determine it (else ``focal`` is the given one).
    scales : (S,) float64
        The candidates of the last search, as factors of the given focal length.
    costs : (S,) float64
        Robust reprojection cost of each, after bundle adjustment.
    note : str
        One line on the outcome, for the metadata and ``--verbose``.
    """

    focal: float
    measured: bool
    scales: np.ndarray
    costs: np.ndarray
    note: str


def _nearest_rotations(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices closest (Frobenius) to the matrices ``m``."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    u[..., :, 2] *= d[..., None]
    return u @ vt


def _cost_at(scale: float, k: np.ndarray, poses: np.ndarray, points: np.ndarray, uv: np.ndarray,
             observed: np.ndarray, free: np.ndarray) -> float:
    """Robust reprojection cost after bundle adjustment with the focal length ``scale`` times that of ``k``.

    poses (T, 4, 4) and points (N, 3) fitted at ``k``; uv (T, N, 2) observed where ``observed`` (T, N).
    """
    depth = np.diag([1.0, 1.0, scale])
    moved = poses.copy()
    moved[:, :3, :3] = _nearest_rotations(depth @ poses[:, :3, :3] @ np.linalg.inv(depth))
    moved[:, :3, 3] = poses[:, :3, 3] @ depth
    start = points @ depth
    k_scaled = k.copy()
    k_scaled[:2, :2] *= scale
    rays = start / np.linalg.norm(start, axis=1, keepdims=True)
    poses_ba, points_ba = bundle_adjust(observed, uv, k_scaled, moved, start, rays, free, 0.0, _LOSS_SCALE,
                                        max_evaluations=_BA_EVALUATIONS)
    cam = np.einsum("tij,nj->tni", poses_ba[:, :3, :3], points_ba) + poses_ba[:, None, :3, 3]  # (T, N, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        projected = cam[..., :2] / cam[..., 2:3] * np.diag(k_scaled)[:2] + k_scaled[:2, 2]
    residuals = (projected - uv)[observed]
    return huber_cost(residuals, _LOSS_SCALE) if np.all(np.isfinite(residuals)) else np.inf


def _vertex(x: np.ndarray, y: np.ndarray) -> float:
    """Abscissa of the lowest point of the parabola through three points (x, y), clipped to their span."""
    a, b, _ = np.polyfit(x, y, 2)
    return float(np.clip(-b / (2 * a), x.min(), x.max())) if a > 0 else float(x[np.argmin(y)])


def _search(tracks: Tracks, mask: np.ndarray, k: np.ndarray, options: RigidOptions, seed: int,
            progress: Callable[[int], None]) -> FocalEstimate:
    """One search about the focal length of ``k``: a pose fit there, then the candidates (module docstring).
    ``progress(done)`` after the fit and after each candidate, ``len(FOCAL_SCALES) + 1`` in all."""
    given = float(k[0, 0])
    fit = fit_rigid(tracks, ShapePrior.inflate(mask, k), options=options)
    progress(1)
    usable = np.nonzero(np.isfinite(fit.points).all(axis=1)
                        & (fit.inliers.sum(axis=0) >= _MIN_OBSERVATIONS))[0]
    if len(usable) < 2 * options.min_points:
        return FocalEstimate(given, False, FOCAL_SCALES.copy(), np.full(len(FOCAL_SCALES), np.nan),
                             f"kept: only {len(usable)} tracks fit the body")
    rng = np.random.default_rng(seed)
    sample = np.sort(rng.choice(usable, min(_TRACKS, len(usable)), replace=False))
    observed = fit.inliers[:, sample]
    uv = np.where(observed[..., None], tracks.uv[:, sample], 0.0).astype(np.float64)
    free = np.array([t for t in range(1, len(observed)) if observed[t].sum() >= options.min_points], np.int64)
    costs = np.empty(len(FOCAL_SCALES))
    for i, scale in enumerate(FOCAL_SCALES):
        costs[i] = _cost_at(scale, k, fit.poses, fit.points[sample], uv, observed, free)
        progress(i + 2)
    best = int(np.argmin(costs))
    if best in (0, len(costs) - 1):
        scale = float(FOCAL_SCALES[best])
    else:
        around = slice(best - 1, best + 2)
        scale = float(np.exp(_vertex(np.log(FOCAL_SCALES[around]), costs[around])))
    neighbours = [costs[j] for j in (best - 1, best + 1) if 0 <= j < len(costs)]
    rise = float(np.mean(neighbours) / costs[best] - 1) if np.isfinite(costs[best]) and costs[best] > 0 else 0.0
    # One valley: the cost climbs all the way out on either side (noise over a flat curve does not).
    valley = bool(np.all(np.diff(costs[:best + 1]) < 0) and np.all(np.diff(costs[best:]) > 0))
    if not (rise >= _MIN_RISE and valley):
        why = (f"the cost {rise:.1%} higher 26 % off the best" if rise < _MIN_RISE else
               "the cost has no single valley over the candidates")
        return FocalEstimate(given, False, FOCAL_SCALES.copy(), costs,
                             f"kept {given:.0f} px ({_fov(given, k):.0f}° wide): the tracks barely tell focal "
                             f"lengths apart ({why})")
    # Rounded: the next search and the prior start from it, and the last bits of the costs (their bundle
    # adjustments run on BLAS) must not reach the pose fit's RANSAC (:mod:`~marionette.reproducible`).
    return FocalEstimate(float(snap(given * scale, _FOCAL_STEP)), True, FOCAL_SCALES.copy(), costs, "")


def _fov(focal: float, k: np.ndarray) -> float:
    """Horizontal field of view (degrees) of a focal length (pixels) at the image width ``k``'s centre implies."""
    return fov_from_focal(2 * k[0, 2] + 1, focal)


def estimate_focal(tracks: Tracks, mask: np.ndarray, k: np.ndarray, *, options: RigidOptions = RigidOptions(),
                   seed: int = 0, progress: Callable[[int, int], None] | None = None) -> FocalEstimate:
    """Estimate the focal length (fx = fy, principal point kept) from a rigid body's tracks.

    A search starts from the given focal length; where it moves it by more than :data:`_SETTLED`, a
    second search starts from its answer (step 4 of the module docstring).

    Parameters
    ----------
    tracks : Tracks
        T frames, M tracks on the body.
    mask : (H, W) bool
        The body's frame-0 mask (its shape prior for the first fit).
    k : (3, 3)
        Intrinsics to start from; the first search spans :data:`FOCAL_SCALES` times their focal length.
    options : RigidOptions
        Settings of the pose fits.
    seed : int
        Seed of the track sample.
    progress : callable(done, total), optional
        Called after each fit and each candidate.

    Returns
    -------
    FocalEstimate
        Its ``scales`` and ``costs`` are the last search's, the scales as factors of the given focal length.
    """
    k = np.asarray(k, np.float64)
    given = float(k[0, 0])
    steps = len(FOCAL_SCALES) + 1

    def report(done: int, offset: int = 0) -> None:
        if progress:
            progress(offset + done, 2 * steps)

    first = _search(tracks, mask, k, options, seed, report)
    if not first.measured:
        report(2 * steps)
        return first
    last, searches = first, 1
    if abs(np.log(first.focal / given)) > np.log1p(_SETTLED):
        again = k.copy()
        again[:2, :2] *= first.focal / given
        second = _search(tracks, mask, again, options, seed, lambda done: report(done, steps))
        if second.measured:
            scales = second.scales * first.focal / given
            last, searches = FocalEstimate(second.focal, True, scales, second.costs, ""), 2
    report(2 * steps)
    if np.argmin(last.costs) in (0, len(last.costs) - 1):
        # Still falling at the last search's edge, from its own start too: a drift of the fit, not a valley.
        return FocalEstimate(given, False, last.scales, last.costs,
                             f"kept {given:.0f} px ({_fov(given, k):.0f}° wide): the cost still falls at the edge of "
                             f"the search ({last.focal:.0f} px, {searches} search{'es' if searches > 1 else ''})")
    return FocalEstimate(last.focal, True, last.scales, last.costs,
                         f"estimated {last.focal:.0f} px ({_fov(last.focal, k):.0f}° wide), from "
                         f"{given:.0f} px ({searches} search{'es' if searches > 1 else ''})")
