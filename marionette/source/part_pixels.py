"""Which part each frame-0 pixel of an object belongs to, from what each part's motion predicts (issue 52).

The tracks label the points they follow, and the pixels between them took the label of their nearest tracks;
where a part has few tracks (a plain face) or its tracks are swept by another part (a cabinet's front as the
drawer slides over it) that vote draws the border in the wrong place, and a plain door on a plain cabinet has
too few tracks to be a part at all. Here each pixel is tested under every part's motion: lifted to that
part's frame-0 surface (its triangulated tracks, interpolated: a still body's tracks place none, so a door's
pixel is not judged where the body's guess puts it), moved by the part's pose into later frames and compared
there with the frame and the mask:

    cost_l(p) = Σ_t min(|c_t(π(K (R_lt X(p) + T_lt))) − c_0(p) − g_lt|² / (3 σ²), τ²)     (τ² off the mask)

with ``c`` the log of the blurred colour (blurred so that a slightly wrong depth does not decide; a log, so
that a dark colour changing counts like a bright one) and ``g_lt`` the part's change of shading, the median
over its own pixels. A frame where the pixel's surface turns away from the camera, or another part comes in
front of it, says nothing and costs a fixed ``_UNSEEN``. The costs are summed over a small window (a part is
one piece of surface); pixels one motion explains clearly better than the others take its label, those no
motion explains keep the tracks' label, and the rest (near a hinge, inside a plain face) are reached by a
random walk on frame 0 stopped by its edges (Grady, "Random walks for image segmentation", PAMI 2006). A
second round decides what hides what by the first round's labels.

:func:`find_still_part` asks the same question of one motion and none: where the tracks show one moving part,
a still part beside it (the cabinet under a plain door) shows as pixels that keep their very colour.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import QhullError, cKDTree
from skimage.segmentation import random_walker

__all__ = ["find_still_part", "label_pixels", "part_depth"]

#: Colour noise (log colour) of a frame against frame 0 at a pixel that its part's motion explains.
_COLOUR_SIGMA = 0.15
#: Added to colours (0-1) before their log: below this, differences are noise.
_DARK = 0.05
#: A frame's cost is capped at this many σ² (an occluded or unexplained pixel costs the cap).
_CAP = 9.0
#: A surface is compared only while it faces the camera by more than this cosine.
_EDGE_ON = 0.1
#: Edge sensitivity of the random walk that spreads the labels (skimage's ``beta``).
_EDGE_BETA = 2000.0
#: A pixel some part's motion explains costs less than this share of the cap per frame tested.
_EXPLAINED = 1 / 3
#: A still pixel is compared in this share of the frames tested at least, and its colour error per frame
#: compared (in σ², log colour) stays below _STILL_ERROR: a still body shows the very same pixels.
_STILL_COMPARED = 0.75
_STILL_ERROR = 0.5
#: A connected piece of a part's label smaller than this share of the object joins the label around it.
_ISLAND_SHARE = 0.02
#: A point is hidden by another part that is nearer by this share of its depth.
_OCCLUSION_MARGIN = 0.03
#: Blur (pixels) of frame 0 for the random walk: a little, against noise; its edges are what stop it.
_EDGE_SIGMA = 1.0
#: Smoothing (pixels) of a part's depth before its normals are taken.
_NORMAL_SIGMA = 4.0
#: The cost of a frame where the surface faces away: it says nothing, but a part whose motion turns a pixel
#: out of view must not win on the few frames it kept it in view.
_UNSEEN = 1.5
#: Blur (pixels) of the frames before the colours are compared.
_BLUR_SIGMA = 2.5


def part_depth(points: np.ndarray | None, k: np.ndarray, mask: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """(H, W) frame-0 depth of a part's surface over ``mask``: its points' depths interpolated across the image.

    points : (N, 3) frame-0 camera coordinates of the part's triangulated tracks (None or < 4: ``fallback``);
    fallback : (H, W) depth used where the points say nothing (the object's inflated front).
    """
    depth = np.array(fallback, np.float64)
    if points is None or len(points) < 4:
        return depth
    # Points with too little parallax to place them land far off (or behind): only those near the others count.
    middle = np.median(points[:, 2])
    points = points[(points[:, 2] > 0.5 * middle) & (points[:, 2] < 2.0 * middle)]
    if len(points) < 4:
        return depth
    uv = (points @ np.asarray(k).T)[:, :2] / points[:, 2:3]
    vv, uu = np.nonzero(mask)
    query = np.stack([uu, vv], axis=1).astype(np.float64)
    try:  # inverse depth, which is affine in the pixel over a plane
        values = 1.0 / LinearNDInterpolator(uv, 1.0 / points[:, 2])(query)
    except QhullError:  # degenerate layouts (all points on a line): local planes only
        values = np.full(len(query), np.nan)
    missing = ~np.isfinite(values)
    if missing.any():  # beyond the points: the plane of the nearest ones carried on (a face goes on flat)
        values[missing] = _local_planes(uv, points[:, 2], query[missing])
    values = np.clip(values, 0.5 * middle, 2.0 * middle)
    depth[vv, uu] = values
    return depth


def _local_planes(uv: np.ndarray, z: np.ndarray, query: np.ndarray, count: int = 16) -> np.ndarray:
    """(Q,) depth at ``query`` (Q, 2) pixels of the plane through the ``count`` points (``uv`` (N, 2) at depths
    ``z`` (N,)) nearest to each: inverse depth is affine in the pixel on a plane, fitted by least squares
    (slightly damped, so that points in a line do not tilt it without bound)."""
    count = min(count, len(z))
    _, nearest = cKDTree(uv).query(query, k=count)
    nearest = nearest.reshape(len(query), count)
    offset = uv[nearest] - query[:, None]  # (Q, k, 2) about the query, so the constant term is the answer
    design = np.concatenate([np.ones(offset.shape[:2] + (1,)), offset], axis=2)  # (Q, k, 3)
    normal = np.einsum("qki,qkj->qij", design, design) + np.diag([1e-9, 1e-3, 1e-3])
    rhs = np.einsum("qki,qk->qi", design, 1.0 / z[nearest])
    inverse = np.linalg.solve(normal, rhs[..., None])[:, 0, 0]
    return 1.0 / np.maximum(inverse, 1e-9)


def _normals(depth: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(3, H, W) unit normals of the surface ``depth`` (H, W) lifts frame 0's pixels to, facing the camera."""
    h, w = depth.shape
    vv, uu = np.mgrid[:h, :w].astype(np.float64)
    rays = np.einsum("ij,jhw->ihw", np.linalg.inv(k), np.stack([uu, vv, np.ones_like(uu)]))
    # Smoothed first: the depth of interpolated tracks is noisy, and its slopes more so.
    valid = np.isfinite(depth).astype(np.float64)
    smooth = cv2.GaussianBlur(np.where(valid > 0, depth, 0.0), (0, 0), _NORMAL_SIGMA) / np.maximum(
        cv2.GaussianBlur(valid, (0, 0), _NORMAL_SIGMA), 1e-9)
    surface = rays * smooth[None]
    normal = np.cross(np.gradient(surface, axis=2), np.gradient(surface, axis=1), axis=0)
    normal *= -np.sign(np.sum(normal * surface, axis=0, keepdims=True) + 1e-12)
    return normal / np.maximum(np.linalg.norm(normal, axis=0, keepdims=True), 1e-12)


def _depth_buffer(x: np.ndarray, y: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 nearest depth of points at pixels ``x``, ``y`` (N,) with depths ``z`` (N,); inf where none.
    Each point covers its pixel and the 3x3 around it (a part's pixels spread apart as it comes closer)."""
    buffer = np.full(shape, np.inf, np.float32)
    finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    x, y, z = x[finite], y[finite], z[finite]
    xi, yi = np.round(x).astype(np.int64), np.round(y).astype(np.int64)
    inside = (xi >= 0) & (xi < shape[1]) & (yi >= 0) & (yi < shape[0]) & (z > 0)
    np.minimum.at(buffer, (yi[inside], xi[inside]), z[inside].astype(np.float32))
    return cv2.erode(buffer, np.ones((3, 3), np.uint8))  # a minimum filter


def _sample(image: np.ndarray, x: np.ndarray, y: np.ndarray, interpolation: int, **border) -> np.ndarray:
    """``image`` (H, W[, C]) at the points ``x``, ``y`` (N,) float32: (N[, C]), by ``cv2.remap`` (its maps are
    limited to 32767 rows, so the points go in rows of 1024)."""
    n = len(x)
    width = 1024
    rows = max(-(-n // width), 1)
    mx, my = np.zeros(rows * width, np.float32), np.zeros(rows * width, np.float32)
    mx[:n], my[:n] = x, y
    out = cv2.remap(image, mx.reshape(rows, width), my.reshape(rows, width), interpolation, **border)
    return out.reshape((rows * width,) + out.shape[2:])[:n]


def _log_colour(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 log of the blurred colour: shading is an offset, and dark colours differ as much as
    bright ones."""
    return np.log(_blurred(frame) + _DARK)


def _frames_to_test(poses: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` frames spread over the clip after frame 0."""
    num_frames = poses.shape[1]
    return np.unique(np.linspace(1, num_frames - 1, min(count, num_frames - 1)).round().astype(int))


def _blurred(frame: np.ndarray, sigma: float = _BLUR_SIGMA) -> np.ndarray:
    """(H, W, 3) float32 in 0..1, blurred by ``sigma`` pixels."""
    image = np.asarray(frame, np.float32) / 255.0
    return cv2.GaussianBlur(image, (0, 0), sigma)


def _motion_costs(frames, masks, k: np.ndarray, poses: np.ndarray, depths: np.ndarray, labels: np.ndarray,
                  tested: np.ndarray, *, occlusion: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Per part, each object pixel's summed colour cost over the frames where it was compared, and how many
    those were: (P, H, W) each. ``labels`` (H, W), 0 .. P-1 on the object, place each pixel on its part's
    surface and say where each part is (what hides what, unless not ``occlusion``)."""
    num_parts = poses.shape[0]
    vv, uu = np.nonzero(labels >= 0)
    own = labels[vv, uu]
    rays = np.linalg.solve(k, np.stack([uu, vv, np.ones_like(uu)]).astype(np.float64))  # (3, N)
    # A pixel tested as part p's is where p's surface is: a still body's tracks place no surface (no parallax),
    # and the door beside it, placed there, would be judged by where it is not.
    points = rays[None] * depths[:, vv, uu][:, None]  # (P, 3, N)
    normals = np.stack([_normals(np.where(labels >= 0, d, np.nan), k)[:, vv, uu] for d in depths])  # (P, 3, N)
    cost = np.zeros((num_parts,) + labels.shape, np.float32)
    compared = np.zeros_like(cost)
    colour0 = _log_colour(frames[0])[vv, uu]  # (N, 3)
    for t in tested:
        image, mask = _log_colour(frames[t]), np.asarray(masks[t], np.uint8)
        rotations = poses[:, t, :3, :3]
        moved = np.einsum("pij,pjn->pin", rotations, points) + poses[:, t, :3, 3:4]  # (P, 3, N)
        pixel = np.einsum("ij,pjn->pin", k, moved)
        ahead = pixel[:, 2] > 1e-6
        z = np.where(ahead, pixel[:, 2], 1.0)
        mx, my = (pixel[:, 0] / z).astype(np.float32), (pixel[:, 1] / z).astype(np.float32)  # (P, N)
        # Each part where its own pixels are now, nearest first: what hides the others.
        buffers = [_depth_buffer(mx[p, own == p], my[p, own == p], z[p, own == p], mask.shape) if occlusion
                   else None for p in range(num_parts)]
        for part in range(num_parts):
            at = (mx[part], my[part])
            # A surface turned away from the camera (or edge-on), or behind another part, is not compared.
            facing = (np.sum((rotations[part] @ normals[part]) * moved[part], axis=0)
                      < -_EDGE_ON * np.linalg.norm(moved[part], axis=0))
            hidden = np.zeros(len(vv), bool)
            for other in range(num_parts):
                if other != part and occlusion:
                    front = _sample(buffers[other], *at, cv2.INTER_NEAREST, borderValue=np.inf)
                    hidden |= front < z[part] * (1.0 - _OCCLUSION_MARGIN)
            colour = _sample(image, *at, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            on = ahead[part] & (_sample(mask, *at, cv2.INTER_NEAREST, borderValue=0) > 0)
            # The part's shading changes as it turns: one gain per part and frame (an offset of the log colour),
            # from its own pixels.
            difference = colour - colour0
            usable = on & facing & ~hidden & (own == part)
            if usable.sum() >= 16:
                difference -= np.median(difference[usable].mean(axis=1))
            error = np.sum(difference ** 2, axis=1) / (3 * _COLOUR_SIGMA ** 2)
            seen = (facing & ~hidden) | ~on  # off the mask counts (at the cap) whichever way it faces
            cost[part, vv, uu] += np.where(seen, np.where(on, np.minimum(error, _CAP), _CAP), 0.0)
            compared[part, vv, uu] += seen
    return cost, compared


def label_pixels(frames, masks, k: np.ndarray, poses: np.ndarray, depths: np.ndarray, vote: np.ndarray, *,
                 samples: int = 12, window: int = 7, confidence: float = 0.5, rounds: int = 2) -> np.ndarray:
    """Each frame-0 object pixel's part: the one whose motion explains it best (module docstring).

    Parameters
    ----------
    frames : (T, H, W, 3) uint8, or anything indexed by frame (a VideoFrames).
    masks : (T, H, W) bool, or anything indexed by frame (PackedMasks).
    k : (3, 3) intrinsics.
    poses : (P, T, 4, 4) each part's frame-0 → frame-t camera-frame poses.
    depths : (P, H, W) each part's frame-0 surface depth (:func:`part_depth`).
    vote : (H, W) int, the tracks' label of each object pixel (0 .. P-1; negative off the object).
    samples : frames tested, spread over the clip.
    window : side of the square over which a pixel's costs are summed.
    confidence : the cost margin, in capped frames, by which one part's motion must beat the others' for a
        pixel to be taken as told apart.
    rounds : labellings, each deciding what hides what by the one before.

    Returns
    -------
    (H, W) int16 labels 0 .. P-1 on the object, ``vote``'s value off it.
    """
    num_parts = poses.shape[0]
    object_mask = vote >= 0
    vv, uu = np.nonzero(object_mask)
    if num_parts < 2 or len(vv) == 0:
        return vote.astype(np.int16)
    tested = _frames_to_test(poses, samples)
    inside = object_mask.astype(np.float32)
    count = np.maximum(cv2.boxFilter(inside, -1, (window, window), normalize=False), 1.0)
    edges = _blurred(frames[0], _EDGE_SIGMA).astype(np.float64)
    own = np.where(object_mask, np.clip(vote, 0, num_parts - 1), -1)
    labels = own.copy()
    for _ in range(rounds):
        cost, compared = _motion_costs(frames, masks, k, poses, depths, labels, tested)
        # Summed over a window of object pixels (one piece of surface moves as one); a frame not compared
        # costs _UNSEEN.
        total = np.stack([cv2.boxFilter((c + (len(tested) - n) * _UNSEEN) * inside, -1, (window, window),
                                        normalize=False) for c, n in zip(cost, compared)]) / count
        ranked = np.sort(total[:, vv, uu], axis=0)
        best = np.argmin(total[:, vv, uu], axis=0)
        confident = ranked[1] - ranked[0] > confidence * _CAP
        if len(np.unique(best[confident])) < 2:  # the motions do not tell the parts apart: the labels stay
            break
        # Where the motions predict alike (near a hinge, on plain faces) the label spreads from the pixels
        # they tell apart, stopped by frame 0's edges (a random walk on the image: Grady, PAMI 2006); where
        # no part's motion explains a pixel (a motion the tracks got wrong, a shadow) the tracks decide.
        seeds = np.full(vote.shape, -1, np.int32)
        seeds[vv, uu] = np.where(confident, best + 1, 0)
        unexplained = ranked[0] >= _EXPLAINED * _CAP * len(tested)
        seeds[vv[unexplained], uu[unexplained]] = own[vv[unexplained], uu[unexplained]] + 1
        walk = random_walker(edges, seeds, beta=_EDGE_BETA, mode="bf", channel_axis=-1)
        labels = np.where(object_mask, walk - 1, -1)
    out = vote.astype(np.int16).copy()
    out[vv, uu] = _without_islands(labels, len(vv) * _ISLAND_SHARE)[vv, uu]
    return out


def _without_islands(labels: np.ndarray, min_pixels: float) -> np.ndarray:
    """``labels`` (H, W) (negative off the object) with each connected piece of a label smaller than
    ``min_pixels`` given to the label around it (a part is a sizeable piece of surface, not a speckle)."""
    out = labels.copy()
    for label in np.unique(labels[labels >= 0]):
        count, pieces, stats, _ = cv2.connectedComponentsWithStats((out == label).astype(np.uint8), connectivity=8)
        for piece in np.nonzero(stats[1:, cv2.CC_STAT_AREA] < min_pixels)[0] + 1:
            inside = pieces == piece
            ring = cv2.dilate(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~inside
            around = out[ring]
            around = around[(around >= 0) & (around != label)]
            if len(around):
                out[inside] = np.bincount(around).argmax()
    return out


def find_still_part(frames, masks, k: np.ndarray, poses: np.ndarray, depth: np.ndarray, mask: np.ndarray, *,
                    samples: int = 12, min_share: float = 0.05) -> np.ndarray | None:
    """(H, W) bool frame-0 pixels of ``mask`` that stay still while the rest moves by ``poses`` (T, 4, 4), or
    None when fewer than ``min_share`` of the object's pixels are seen to, or fewer than that are left moving.

    A plain door or lid has too few tracks to make a part, and its few tracks then drag the object's one
    motion with them; the cabinet or box it hangs on is told apart by its pixels. A pixel is seen to stay
    still when it keeps its colour where it is (within a tenth of its value) in nearly every frame tested,
    and the motion fitted to the tracks explains it clearly worse; the still part then spreads from those
    pixels over what neither motion tells apart, stopped by frame 0's edges, as in :func:`label_pixels`.
    ``depth`` (H, W): frame-0 depth of the moving surface.
    """
    identity = np.tile(np.eye(4), (len(poses), 1, 1))
    both = np.stack([poses, identity])
    tested = _frames_to_test(both, samples)
    labels = np.where(mask, 0, -1)
    cost, compared = _motion_costs(frames, masks, k, both, np.stack([depth, depth]), labels, tested,
                                   occlusion=False)  # which pixels move is not known yet
    total = cost + (len(tested) - compared) * _UNSEEN
    vv, uu = np.nonzero(mask)
    steady = compared[1, vv, uu] >= _STILL_COMPARED * len(tested)
    quiet = cost[1, vv, uu] < _STILL_ERROR * np.maximum(compared[1, vv, uu], 1)
    apart = total[0, vv, uu] - total[1, vv, uu] > _CAP
    still = steady & quiet & apart
    if still.sum() < min_share * len(vv):
        return None
    moving = total[1, vv, uu] - total[0, vv, uu] > _CAP
    seeds = np.full(mask.shape, -1, np.int32)
    seeds[vv, uu] = np.where(still, 2, np.where(moving, 1, 0))
    if not moving.any():
        return None
    walk = random_walker(_blurred(frames[0], _EDGE_SIGMA).astype(np.float64), seeds, beta=_EDGE_BETA, mode="bf",
                         channel_axis=-1)
    still = mask & (walk == 2)
    return still if (mask & ~still).sum() >= min_share * len(vv) else None  # something must move
