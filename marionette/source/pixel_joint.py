"""A part's joint read from its pixels and the masks, for a part too plain to track (issue 52).

A plain door has tracks at a few corners at best, so neither its free poses nor a hinge fitted to its tracks
can be trusted; what it does show is its outline: where the part is in each frame is where the mask has
pixels the body does not explain, and where its face keeps its colour. The joint is searched among a few
candidates the part's frame-0 region suggests:

- a hinge along each straight stretch of the region's outline (a door turns about one of its edges), lifted
  to 3D at the depth of frame 0's surface, and
- a slider along the region's surface normal (a drawer comes out of its face),

each frame's angle or travel found by a one-dimensional search started from the previous frame's, against

    cost_t = Σ_p [min(|c_t(x_p) − c_0(p) − g_t|² / (3 σ²), τ²) or τ² off the mask] · (pixels per point)
             + τ² · #{mask pixels that neither the body nor the part covers}

(the colour term as in :mod:`~marionette.source.part_pixels`, on a sample of the part's pixels). The
candidate with the lowest total cost is the joint, kept when it beats the poses it started from.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import axis_angle_to_matrix
from .part_pixels import _CAP, _COLOUR_SIGMA, _EDGE_ON, _UNSEEN, _log_colour, _normals, _sample

__all__ = ["PixelJoint", "fit_pixel_joint", "place_unseen_angles"]

#: Changing the angle (travel) by its largest step between frames tested costs this share of a frame's cost.
_SMOOTHNESS = 0.15
#: Points of the part (and of the body) sampled from their frame-0 pixels.
_POINTS = 3000
#: An outline stretch shorter than this share of the outline does not carry a hinge.
_MIN_STRETCH = 0.12
#: Angles searched (degrees), moving at most _ANGLE_MOVE between frames tested, then refined in _ANGLE_FINE
#: steps.
_ANGLES, _ANGLE_MOVE, _ANGLE_FINE = np.arange(-120.0, 120.1, 3.0), 30.0, 0.5
#: Travels searched, in shares of the part's depth, alike.
_TRAVELS, _TRAVEL_MOVE, _TRAVEL_FINE = np.arange(-0.4, 0.401, 0.0125), 0.1, 0.0025
#: A hinge's angle in frames its tracks do not see is searched this far (degrees) from the last seen one, moving at
#: most _UNSEEN_MOVE between frames.
_UNSEEN_ANGLES, _UNSEEN_MOVE = np.arange(-45.0, 45.1, 1.0), 8.0
#: The first look: every _COARSE-th value of the grid, on these of the frames tested; _FINALISTS go on.
_COARSE, _PROXY_FRAMES, _FINALISTS = 3, slice(2, None, 3), 3


@dataclass
class PixelJoint:
    """A joint fitted to a part's pixels.

    kind : ``"hinge"`` or ``"slider"``;
    axis : (3,) unit direction (body frame 0); point : (3,) a point of a hinge's axis (None for a slider);
    values : (T,) angle (radians) or travel (the poses' units) per frame, 0 at frame 0;
    poses : (T, 4, 4) the part's frame-0 → frame-t poses;
    cost : the fit's total cost; start_cost : the same under the poses it started from.
    """

    kind: str
    axis: np.ndarray
    point: np.ndarray | None
    values: np.ndarray
    poses: np.ndarray
    cost: float
    start_cost: float


def _turn(axis: np.ndarray, point: np.ndarray, angle: float) -> np.ndarray:
    """(4, 4) rotation by ``angle`` about the line through ``point`` along unit ``axis``."""
    out = np.eye(4)
    out[:3, :3] = axis_angle_to_matrix(axis * angle)
    out[:3, 3] = point - out[:3, :3] @ point
    return out


def _shift(axis: np.ndarray, distance: float) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = axis * distance
    return out


class _Frames:
    """What a frame's cost needs, computed once: its mask, log colours and the body's footprint."""

    def __init__(self, frames, masks, k, body_poses, body_points, part_points, normals, colour0, weight):
        self.k, self.frames, self.masks, self.body_poses = k, frames, masks, body_poses
        self.body_points, self.points, self.colour0, self.weight = body_points, part_points, colour0, weight
        self.normals = normals
        self._cache: dict[int, tuple] = {}

    def _frame(self, t: int):
        if t not in self._cache:
            mask = np.asarray(self.masks[t], np.uint8)
            body = _footprint(self.k, self.body_poses[t], self.body_points, mask.shape, self.weight)
            self._cache = {t: (mask, _log_colour(self.frames[t]), body)}
        return self._cache[t]

    def cost(self, t: int, pose: np.ndarray) -> float:
        mask, colour, body = self._frame(t)
        moved = self.points @ pose[:3, :3].T + pose[:3, 3]
        ahead = moved[:, 2] > 1e-6
        pixel = moved @ self.k.T
        z = np.where(ahead, pixel[:, 2], 1.0)
        x, y = (pixel[:, 0] / z).astype(np.float32), (pixel[:, 1] / z).astype(np.float32)
        on = ahead & (_sample(mask, x, y, cv2.INTER_NEAREST, borderValue=0) > 0)
        difference = _sample(colour, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) - self.colour0
        if on.sum() >= 16:
            difference -= np.median(difference[on].mean(axis=1))
        error = np.minimum(np.sum(difference ** 2, axis=1) / (3 * _COLOUR_SIGMA ** 2), _CAP)
        # A face turned away shows its back there: no colour to compare, but it still covers the mask.
        facing = np.sum((self.normals @ pose[:3, :3].T) * moved, axis=1) < -_EDGE_ON * np.linalg.norm(moved, axis=1)
        part_cost = np.where(on, np.where(facing, error, _UNSEEN), _CAP).sum() * self.weight
        covered = body | _splat(x[ahead], y[ahead], mask.shape, self.weight)
        return float(part_cost + _CAP * np.count_nonzero(mask & ~covered))


def _frame_costs(frames, masks, k, body_poses, body_pixels, part_pixels, depth, seed: int) -> _Frames | None:
    """The cost of :func:`fit_pixel_joint` on samples of the body's and the part's frame-0 pixels placed at
    ``depth``; None when the part has fewer than 16 pixels with a depth."""
    rng = np.random.default_rng(seed)
    body_points, _ = _sample_points(body_pixels, depth, k, _POINTS, rng)
    points, at = _sample_points(part_pixels, depth, k, _POINTS, rng)
    if len(points) < 16:
        return None
    normals = _normals(np.where(part_pixels, depth, np.nan), k)[:, at[:, 1], at[:, 0]].T  # (N, 3)
    return _Frames(frames, masks, k, body_poses, body_points, points, normals,
                   _log_colour(frames[0])[at[:, 1], at[:, 0]], part_pixels.sum() / len(points))


def _splat(x: np.ndarray, y: np.ndarray, shape: tuple[int, int], weight: float) -> np.ndarray:
    """(H, W) uint8 footprint of points at ``x``, ``y`` that each stand for ``weight`` pixels."""
    out = np.zeros(shape, np.uint8)
    xi, yi = np.round(x).astype(np.int64), np.round(y).astype(np.int64)
    inside = (xi >= 0) & (xi < shape[1]) & (yi >= 0) & (yi < shape[0])
    out[yi[inside], xi[inside]] = 1
    size = 2 * int(np.ceil(np.sqrt(weight) / 2)) + 1
    return cv2.dilate(out, np.ones((size, size), np.uint8))


def _footprint(k, pose, points, shape, weight) -> np.ndarray:
    moved = points @ pose[:3, :3].T + pose[:3, 3]
    pixel = moved @ k.T
    ahead = pixel[:, 2] > 1e-6
    return _splat(pixel[ahead, 0] / pixel[ahead, 2], pixel[ahead, 1] / pixel[ahead, 2], shape, weight)


def _sample_points(pixels: np.ndarray, depth: np.ndarray, k: np.ndarray, count: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) frame-0 points of up to ``count`` of ``pixels`` (H, W) at ``depth``, and their (N, 2) pixels."""
    vv, uu = np.nonzero(pixels & np.isfinite(depth))
    pick = rng.choice(len(vv), size=min(count, len(vv)), replace=False) if len(vv) > count else np.arange(len(vv))
    vv, uu = vv[pick], uu[pick]
    rays = np.linalg.solve(k, np.stack([uu, vv, np.ones_like(uu)]).astype(np.float64)).T
    return rays * depth[vv, uu, None], np.stack([uu, vv], axis=1)


def _outline_axes(pixels: np.ndarray, depth: np.ndarray, k: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hinge candidates (unit axis, point) along the straight stretches of the outline of ``pixels`` (H, W):
    a line fitted to each stretch's outline points, lifted to 3D at the depth of the part's surface there."""
    contours, _ = cv2.findContours(pixels.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return []
    outline = max(contours, key=cv2.contourArea)[:, 0]  # (L, 2) x, y
    length = cv2.arcLength(outline[:, None], True)
    corners = cv2.approxPolyDP(outline[:, None], 0.02 * length, True)[:, 0]
    at = [int(np.argmin(np.abs(outline - c).sum(axis=1))) for c in corners]
    surface = np.where(np.isfinite(depth), depth, np.nanmedian(depth[pixels]))
    axes = []
    for start, stop in zip(at, at[1:] + at[:1]):
        stretch = outline[start:stop + 1] if stop > start else np.concatenate([outline[start:], outline[:stop + 1]])
        if len(stretch) < _MIN_STRETCH * len(outline):
            continue
        inner = stretch[len(stretch) // 8: len(stretch) - len(stretch) // 8]  # away from the corners
        # The line through the stretch's points in 3D.
        rays = np.linalg.solve(k, np.column_stack([inner, np.ones(len(inner))]).T).T
        points = rays * surface[inner[:, 1], inner[:, 0], None]
        centre = points.mean(axis=0)
        direction = np.linalg.svd(points - centre)[2][0]
        axes.append((direction, centre))
    return axes


def _plane_normal(points: np.ndarray) -> np.ndarray:
    """(3,) unit normal of the plane that fits ``points`` (N, 3) best, facing the camera."""
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre)[2][2]
    return -normal if normal @ centre > 0 else normal


def _search(frames: _Frames, tested: np.ndarray, make_pose, grid: np.ndarray, max_step: float, fine: float):
    """The value (angle or travel) per tested frame: each frame's cost over ``grid`` (from 0 at frame 0,
    changing by at most ``max_step`` from one tested frame to the next), the cheapest path through them by
    dynamic programming, then each value refined on a ``fine`` grid around it. Returns the values
    (len(tested),) and the path's total cost."""
    table = np.array([[frames.cost(t, make_pose(t, value)) for value in grid] for t in tested])  # (F, G)
    moves = np.abs(grid[:, None] - grid[None, :])  # (G, G)
    # Each unit of change costs a little, so that a path does not dip to a neighbouring minimum and back.
    toll = _SMOOTHNESS * np.median(table) / max_step
    total = np.where(np.abs(grid) <= max_step, table[0] + toll * np.abs(grid), np.inf)
    back = np.zeros(table.shape, np.int64)
    for i in range(1, len(tested)):
        options = np.where(moves <= max_step, total[None, :] + toll * moves, np.inf)  # (to, from)
        back[i] = np.argmin(options, axis=1)
        total = table[i] + options[np.arange(len(grid)), back[i]]
    path = [int(np.argmin(total))]
    for i in range(len(tested) - 1, 0, -1):
        path.append(int(back[i, path[-1]]))
    values = grid[path[::-1]].astype(np.float64)
    step = grid[1] - grid[0]
    cost = 0.0
    for i, t in enumerate(tested):
        around = values[i] + np.arange(-step, step + fine / 2, fine)
        costs = [frames.cost(t, make_pose(t, value)) for value in around]
        values[i] = around[int(np.argmin(costs))]
        cost += min(costs)
    return values, cost


def _candidates(costs: _Frames, part_pixels: np.ndarray, depth: np.ndarray, k: np.ndarray, body_poses):
    """(kind, axis, point, make_pose, grid, max_step, fine, scale) of each joint the region suggests on the
    surface ``depth``."""
    out = []
    for axis, point in _outline_axes(part_pixels, depth, k):
        def hinge(t, angle, axis=axis, point=point):
            return body_poses[t] @ _turn(axis, point, np.radians(angle))
        out.append(("hinge", axis, point, hinge, _ANGLES, _ANGLE_MOVE, _ANGLE_FINE, np.pi / 180))
    scale = float(np.median(costs.points[:, 2]))
    normal = _plane_normal(costs.points)

    def slide(t, travel):
        return body_poses[t] @ _shift(normal, travel * scale)
    out.append(("slider", normal, None, slide, _TRAVELS, _TRAVEL_MOVE, _TRAVEL_FINE, scale))
    return out


def fit_pixel_joint(frames, masks, k: np.ndarray, body_poses: np.ndarray, body_pixels: np.ndarray,
                    part_pixels: np.ndarray, depth: np.ndarray, start_poses: np.ndarray, *,
                    max_frames: int = 12, seed: int = 0) -> PixelJoint | None:
    """The joint (hinge or slider on the body) that best explains a part's pixels and the masks.

    Parameters
    ----------
    frames, masks : (T, H, W, 3) uint8 and (T, H, W) bool, or anything indexed by frame.
    k : (3, 3) intrinsics.
    body_poses : (T, 4, 4) the body's frame-0 → frame-t poses.
    body_pixels, part_pixels : (H, W) bool frame-0 pixels of the body's outline (the whole object's: a part lies
        on or in front of its body) and of the part.
    depth : (H, W) frame-0 depth of the visible surface over both (the poses' units).
    start_poses : (T, 4, 4) the part's poses so far (its tracks', or the whole object's).
    max_frames : frames searched (spread over the clip); the others are interpolated.

    Returns
    -------
    The best joint, or None when the part has too few pixels.
    """
    num_frames = len(body_poses)
    tested = np.unique(np.linspace(1, num_frames - 1, min(max_frames, num_frames - 1)).round().astype(int))
    costs = _frame_costs(frames, masks, k, body_poses, body_pixels, part_pixels, depth, seed)
    if costs is None:
        return None
    start_cost = sum(costs.cost(t, start_poses[t]) for t in tested)
    trials = []
    for candidate in _candidates(costs, part_pixels, depth, k, body_poses):
        # A first look on a few frames and a coarse grid: only the most promising are searched in full.
        make_pose, grid = candidate[3], candidate[4][::_COARSE]
        trials.append((sum(min(costs.cost(t, make_pose(t, v)) for v in grid) for t in tested[_PROXY_FRAMES]),
                       candidate))
    best = None
    for _, (kind, axis, point, make_pose, grid, max_step, fine, unit) in sorted(trials, key=lambda c: c[0])[
            :_FINALISTS]:
        values, total = _search(costs, tested, make_pose, grid, max_step, fine)
        if best is None or total < best[0]:
            best = (total, kind, axis, point, values * unit)
    total, kind, axis, point, values = best
    every = np.interp(np.arange(num_frames), np.concatenate([[0], tested]), np.concatenate([[0.0], values]))
    poses = np.stack([body_poses[t] @ (_turn(axis, point, every[t]) if kind == "hinge" else _shift(axis, every[t]))
                      for t in range(num_frames)])
    return PixelJoint(kind, axis, point, every, poses, float(total), float(start_cost))


def place_unseen_angles(frames, masks, k: np.ndarray, body_poses: np.ndarray, body_pixels: np.ndarray,
                        part_pixels: np.ndarray, depth: np.ndarray, axis: np.ndarray, point: np.ndarray,
                        angles: np.ndarray, unseen: np.ndarray, *, seed: int = 0) -> np.ndarray | None:
    """A hinge's angles with those of the frames its tracks do not see found from the part's pixels and the masks.

    A screen or lid turned away from the camera loses its tracks, and its angle there is only what the start of
    the fit held; its outline and whatever of its face still shows place it. Each run of ``unseen`` frames
    carries on from the angle before it, searched as in :func:`fit_pixel_joint` (the cheapest smooth path,
    within :data:`_UNSEEN_ANGLES` of that angle), the axis kept.

    Parameters as :func:`fit_pixel_joint`; axis, point : (3,) the hinge's line (body frame 0); angles : (T,)
    radians; unseen : (T,) bool, False at frame 0.

    Returns
    -------
    (T,) angles (radians), or None when the part has too few pixels.
    """
    costs = _frame_costs(frames, masks, k, body_poses, body_pixels, part_pixels, depth, seed)
    if costs is None:
        return None
    placed = np.array(angles, np.float64)
    frames_unseen = np.flatnonzero(unseen)
    runs = np.split(frames_unseen, np.flatnonzero(np.diff(frames_unseen) > 1) + 1) if len(frames_unseen) else []
    for run in runs:
        base = placed[run[0] - 1]

        def turned(t, angle, base=base):
            return body_poses[t] @ _turn(axis, point, base + np.radians(angle))
        values, _ = _search(costs, run, turned, _UNSEEN_ANGLES, _UNSEEN_MOVE, _ANGLE_FINE)
        placed[run] = base + np.radians(values)
    return placed
