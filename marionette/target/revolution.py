"""A pot, a can or a bottle rebuilt as a surface of revolution about its own axis, tilted as the photo shows it.

The sheets of the ``revolve`` prior (:mod:`.shapes`) put the axis in the image
plane; a photo taken from a little above shows the top, and the object turned
about its own axis then swings out of its outline. Here the axis leans out of
the image plane by the angle the outline's ends show: under a pitch ``p`` a
ring of radius ``r`` projects to an ellipse ``r sin p`` tall, so the ends of the
outline are half ellipses and the profile read between them is shortened by
``cos p``. Any pitch's profile can bend to fit the outline, so among those
that fit it about equally well the one with a ring (the top rim, a band of
paint, a step) that runs along an edge of the photo is taken, else the best
fit (:func:`fit_revolution`). The pitch chosen, each ring is scaled
until the outline is as wide as the mask's on the row of the ring's widest
points, which perspective puts rows away from its centre's.

The closed surface (side and both end discs) is sampled on grids of flat
Gaussians (:func:`revolution_surfels`) coloured, like a box's faces
(:mod:`.cuboid`), from the photo where its own pixels show it (a z-buffer of
the surface decides what shows), else from its mirror image through the
plane of the axis across the view, else by texture synthesis from the
visible side: nothing is stretched from the rim, and what a handle hides
is not filled with the handle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np
from scipy import ndimage

from ..camera import Camera
from ..gaussians import Gaussians
from ..geometry import matrix_to_quaternion
from ._solid import FLATNESS, OVERLAP, blur_level, project, sample_spacing, surface_zbuffer
from .surfels import MaskedTexture
from .synthesis import fill_unseen, quilt

__all__ = ["Revolution", "fit_revolution", "revolution_surfels", "MIN_REVOLUTION_IOU"]

# The rebuilt body must cover the body's mask this well (IoU of its outline) to be taken.
MIN_REVOLUTION_IOU = 0.9

# Pitches tried (degrees): how far the axis leans out of the image plane, its top towards the camera.
_PITCHES = np.arange(0.0, 45.1, 2.5)
# Pitches whose outline covers the mask within this IoU of the best one's are told apart by their rings.
_IOU_TOLERANCE = 0.01
# A ring's edge: the photo blurred this much (px), sampled at this many points along the ring's near half,
# and taken when it is this many times the object's median gradient.
_EDGE_BLUR = 1.5
_RING_SAMPLES = 64
_RING_CONTRAST = 2.5
# Running median of the profile over this share of its rows.
_PROFILE_MEDIAN = 0.1
# Rounds of scaling the rings until the outline's rows are as wide as the mask's.
_WIDTH_STEPS = 3
# ...the scale smoothed over this many rings (standard deviation): a pixel's step in the outline is no rib.
_RATIO_SMOOTHING = 2.0
# Vertices of each ring's ellipse when the body's outline is drawn.
_RING_VERTICES = 96
# Samples seen past ~66° (cosine) take no colour from the photo: there a ring is a smear of its neighbours
# (and of a ribbed body's ledges) that, turned to face the camera, would print as a band; they are filled as
# unseen ones are.
_MIN_COLOUR_COSINE = 0.4
# A sample shows in the photo when it lies within this many spacings of the nearest surface at its pixel.
_DEPTH_SLACK = 1.5


@dataclass(frozen=True)
class Revolution:
    """A surface of revolution in the camera frame (world units).

    Attributes
    ----------
    base : (3,) the axis at the bottom end.
    axis : (3,) unit, bottom to top.
    heights : (S,) increasing from 0: along the axis from ``base``.
    radii : (S,) the radius at each height.
    iou : float, the IoU of its projection with the body's mask.
    pitch : float, degrees the axis leans out of the image plane (top towards the camera).
    """

    base: np.ndarray
    axis: np.ndarray
    heights: np.ndarray
    radii: np.ndarray
    iou: float = 0.0
    pitch: float = 0.0

    def axis_depth(self, camera: Camera, row: float) -> float:
        """Camera z of the axis where it crosses image row ``row``'s plane of sight."""
        k = (row - camera.cy) / camera.fy
        along = (k * self.base[2] - self.base[1]) / (self.axis[1] - k * self.axis[2])
        return float(self.base[2] + along * self.axis[2])

    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(2, 3) two unit vectors across the axis: the first lies in the image plane."""
        across = np.cross(self.axis, [0.0, 0.0, 1.0])
        across /= max(np.linalg.norm(across), 1e-12)
        return across, np.cross(self.axis, across)


def _build(radius_rows: np.ndarray, column: float, tilt: float, row0: float, pitch: float, camera: Camera,
           depth: float, max_column: int, at_widest: bool = True) -> Revolution | None:
    """The body whose outline has half-width ``radius_rows`` (H,) per image row, under ``pitch`` degrees
    (``max_column``: the image's width). ``at_widest`` False reads each ring's width at its centre's row (see
    :func:`fit_revolution`)."""
    rows = np.nonzero(radius_rows > 0)[0]
    if len(rows) < 3:
        return None
    top, bottom = float(rows[0]) - 0.5, float(rows[-1]) + 0.5  # the outline's extent, pixel edges
    s = np.sin(np.radians(pitch))
    c = np.cos(np.radians(pitch))
    # Each end is seen from its own elevation, the pitch plus the angle of its rows below the image centre,
    # from above or from below: its ellipse reaches r |sin e| past its centre either way.
    s_top = abs(np.sin(np.radians(pitch) + np.arctan((top - camera.cy) / camera.fy)))
    s_bottom = abs(np.sin(np.radians(pitch) + np.arctan((bottom - camera.cy) / camera.fy)))
    # An end ring of radius r shows as half an ellipse r sin p tall past it: the end ring lies d rows in,
    # the first d at which the outline is no wider than d / sin p.
    inward = np.arange(len(rows))
    d_top = inward[np.argmax(radius_rows[rows] * s_top <= inward + 0.5)]
    d_bottom = inward[np.argmax(radius_rows[rows[::-1]] * s_bottom <= inward + 0.5)]
    r_top, r_bottom = radius_rows[rows[d_top]], radius_rows[rows[::-1][d_bottom]]
    y_top, y_bottom = top + r_top * s_top, bottom - r_bottom * s_bottom
    if y_bottom - y_top < 2.0:
        return None
    ys = np.arange(np.ceil(y_top), np.floor(y_bottom) + 1.0)
    radii = np.concatenate([[r_top], radius_rows[ys.astype(int)], [r_bottom]])[::-1]  # pixels, bottom to top
    ys = np.concatenate([[y_top], ys, [y_bottom]])[::-1]
    # The axis in the image runs up along (-tilt, -1); out of the plane it leans by the pitch towards the camera.
    up = np.array([-tilt, -1.0]) / np.hypot(tilt, 1.0)
    axis = np.array([up[0] * c, up[1] * c, -s])
    centre_row = 0.5 * (y_top + y_bottom)
    centre_px = np.array([column + tilt * (centre_row - row0), centre_row])
    centre = np.array([(centre_px[0] - camera.cx) / camera.fx, (centre_px[1] - camera.cy) / camera.fy, 1.0]) * depth
    # Each row's ring sits where the axis crosses that row's plane of sight, its radius scaled at its own depth.
    k = (ys - camera.cy) / camera.fy
    along = (centre[1] - k * centre[2]) / (k * axis[2] - axis[1])
    ring_depth = centre[2] + along * axis[2]
    # Perspective puts the axis' middle off the rows' middle: scaled about the camera (its outline unchanged),
    # the body has its middle, not that row's point, at ``depth``.
    scale = depth / (centre[2] + 0.5 * (along[0] + along[-1]) * axis[2])
    heights = (along - along[0]) * scale
    base = (centre + along[0] * axis) * scale
    body = Revolution(base, axis, heights, radii * ring_depth * scale / (0.5 * (camera.fx + camera.fy)),
                      pitch=float(pitch))
    # Perspective widens a near ring's outline past its radius: scale each ring until the outline is as wide
    # as the mask's on the row of the ring's widest points (perspective puts them rows off its centre's; read
    # at the centre's row, a ring would answer for a neighbour and the scales would swing into ribs). The end
    # rings follow their neighbours.
    for _ in range(_WIDTH_STEPS):
        row_of = np.clip(np.rint(_widest_rows(body, camera) if at_widest else ys).astype(int), rows[0], rows[-1])
        drawn = _outline_mask(body, camera, (len(radius_rows), max_column)).sum(axis=1) * 0.5
        ratio = np.clip(radius_rows[row_of] / np.maximum(drawn[row_of], 0.5), 0.7, 1.3)
        ratio[[0, -1]] = ratio[[1, -2]]
        ratio = ndimage.gaussian_filter1d(ratio, _RATIO_SMOOTHING, mode="nearest")  # no ribs from pixel steps
        body = Revolution(base, axis, heights, body.radii * ratio, pitch=float(pitch))
    return body


def _rings(body: Revolution, camera: Camera) -> np.ndarray:
    """(S, V, 2) the body's rings drawn in the camera, ``_RING_VERTICES`` points each."""
    across, depthwise = body.frame()
    angles = np.linspace(0.0, 2 * np.pi, _RING_VERTICES, endpoint=False)
    ring = np.cos(angles)[:, None] * across + np.sin(angles)[:, None] * depthwise  # (V, 3)
    return project(body.base + body.heights[:, None, None] * body.axis + body.radii[:, None, None] * ring, camera)


def _widest_rows(body: Revolution, camera: Camera) -> np.ndarray:
    """(S,) the image row of each ring's leftmost and rightmost points (their mean)."""
    uv = _rings(body, camera)
    index = np.arange(len(uv))
    return 0.5 * (uv[index, np.argmin(uv[..., 0], axis=1), 1] + uv[index, np.argmax(uv[..., 0], axis=1), 1])


def _outline_mask(body: Revolution, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool pixels the body covers: each pair of neighbouring rings' convex hull, filled."""
    uv = _rings(body, camera)
    out = np.zeros(shape, np.uint8)
    for k in range(len(uv) - 1):
        hull = cv2.convexHull(np.concatenate([uv[k], uv[k + 1]]).astype(np.float32))
        cv2.fillConvexPoly(out, np.rint(hull * 16).astype(np.int32), 1, cv2.LINE_8, shift=4)
    return out.astype(bool)


def _ring_edge(body: Revolution, camera: Camera, gradient: np.ndarray, interior: np.ndarray) -> float:
    """Strength of the photo's edge along the body's best-marked ring: the mean, over a ring's near half, of
    the gradient across it, for the ring (top rim, band of paint, step) where that is largest. Rings less
    than half on ``interior`` pixels score 0 (a rim seen edge-on is the outline itself).

    ``gradient`` (H, W, 2): the photo's x and y gradient; only its part across the ring counts, so a
    straight edge a ring's ellipse happens to cross scores little. Every ring of the true body is an ellipse
    of the same lean, so any edge that runs round the body (a rim, a label's edge) tells the lean.
    """
    across, depthwise = body.frame()
    angles = np.linspace(0.0, np.pi, _RING_SAMPLES)
    near = -np.sign(depthwise[2]) if depthwise[2] != 0 else 1.0  # depthwise points away from or to the camera
    ring = np.cos(angles)[:, None] * across + near * np.sin(angles)[:, None] * depthwise
    uv = project(body.base + body.heights[:, None, None] * body.axis + body.radii[:, None, None] * ring, camera)
    tangent = np.gradient(uv, axis=1)  # (S, K, 2): every ring at once
    normal = np.stack([-tangent[..., 1], tangent[..., 0]], axis=-1) / np.maximum(
        np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-9)
    col, row = np.rint(uv[..., 0]).astype(int), np.rint(uv[..., 1]).astype(int)
    inside = (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    col, row = np.clip(col, 0, camera.width - 1), np.clip(row, 0, camera.height - 1)
    on = inside & interior[row, col]
    across = np.abs((gradient[row, col] * normal).sum(axis=-1))
    counted = on.mean(axis=1) >= 0.5
    if not counted.any():
        return 0.0
    return float(((across * on).sum(axis=1) / np.maximum(on.sum(axis=1), 1))[counted].max())


def fit_revolution(mask: np.ndarray, radius_rows: np.ndarray, column: float, tilt: float, camera: Camera,
                   depth: float, image: np.ndarray) -> Revolution | None:
    """The surface of revolution that explains the body's (H, W) bool ``mask`` and the photo, or None.

    ``radius_rows`` (H,): the outline's half-width on each row about the mirror axis (column ``column`` at the
    mask's centroid row, ``tilt`` columns per row); ``depth``: the axis' middle's distance from the camera;
    ``image`` (H, W, 3|4) uint8: the photo. Under any pitch the profile can bend to fit the outline's ends (a
    flat lid seen from above, or a dome seen level), so the outline only narrows the pitches down to those
    within ``_IOU_TOLERANCE`` of the best; of those, the one with a ring whose near half runs along the
    strongest edge inside the object (:func:`_ring_edge`: a lid's rim, a label's edge) is taken, or, when no
    ring shows (no such edge ``_RING_CONTRAST`` times the object's median gradient), the best outline's.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return None
    row0 = float(np.nonzero(mask)[0].mean())
    # Where a handle or a spout meets the body its chords break: a running median keeps such steps out of the
    # profile (they would turn into ledges round the whole body).
    rows = np.nonzero(radius_rows > 0)[0]
    window = 2 * int(_PROFILE_MEDIAN * len(rows) / 2) + 1
    radius_rows = radius_rows.copy()
    radius_rows[rows[0]:rows[-1] + 1] = ndimage.median_filter(radius_rows[rows[0]:rows[-1] + 1], window,
                                                              mode="nearest")
    candidates = []
    for pitch in _PITCHES:
        body = _build(radius_rows, column, tilt, row0, float(pitch), camera, depth, mask.shape[1], at_widest=False)
        if body is not None:
            drawn = _outline_mask(body, camera, mask.shape)
            candidates.append((float((drawn & mask).sum() / max((drawn | mask).sum(), 1)), body))
    if not candidates:
        return None
    best_iou = max(iou for iou, _ in candidates)
    near = [(iou, body) for iou, body in candidates if iou >= best_iou - _IOU_TOLERANCE]
    # The object's colours carried outwards over the background: the outline itself makes no edge.
    grey = cv2.cvtColor(np.ascontiguousarray(image[..., :3]), cv2.COLOR_RGB2GRAY).astype(np.float32)
    _, (near_row, near_col) = ndimage.distance_transform_edt(~mask, return_indices=True)
    grey = cv2.GaussianBlur(grey[near_row, near_col], (0, 0), _EDGE_BLUR)
    gradient = np.stack([cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1)], axis=-1)
    interior = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    typical = float(np.median(np.linalg.norm(gradient[interior], axis=1))) if interior.any() else 0.0
    rings = [_ring_edge(body, camera, gradient, interior) for _, body in near]
    if max(rings) > _RING_CONTRAST * max(typical, 1.0):
        iou, body = near[int(np.argmax(rings))]
    else:
        iou, body = max(near, key=lambda candidate: candidate[0])
    # The lean chosen, its rings are scaled where their outline is widest: no ribs round the body.
    smooth = _build(radius_rows, column, tilt, row0, body.pitch, camera, depth, mask.shape[1])
    if smooth is not None:
        drawn = _outline_mask(smooth, camera, mask.shape)
        iou, body = float((drawn & mask).sum() / max((drawn | mask).sum(), 1)), smooth
    return Revolution(body.base, body.axis, body.heights, body.radii, iou, body.pitch)


class _Grid(NamedTuple):
    """Samples of one surface patch on a rectangular (n_a, n_b) grid.

    points, normals (outward), tangent_a, tangent_b (unit, in the surface): (n_a, n_b, 3) each.
    step_a, step_b: (n_a, n_b) sample spacing along each tangent (0: no sample, off an end disc).
    """

    points: np.ndarray
    normals: np.ndarray
    tangent_a: np.ndarray
    tangent_b: np.ndarray
    step_a: np.ndarray
    step_b: np.ndarray


def _side(body: Revolution, spacing: float) -> _Grid:
    """The side on a grid of heights (every ``spacing`` along the profile) by angles (the widest ring's)."""
    across, depthwise = body.frame()
    length = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(body.heights), np.diff(body.radii)))])
    n_a = max(2, int(np.ceil(length[-1] / spacing)))
    n_b = max(8, int(np.ceil(2 * np.pi * body.radii.max() / spacing)))
    at = (np.arange(n_a) + 0.5) / n_a * length[-1]
    h = np.interp(at, length, body.heights)
    r = np.interp(at, length, body.radii)
    slope = np.gradient(r, h) if n_a > 2 else np.zeros(n_a)
    angles = (np.arange(n_b) + 0.5) / n_b * 2 * np.pi
    radial = np.cos(angles)[:, None] * across + np.sin(angles)[:, None] * depthwise  # (n_b, 3)
    points = body.base + h[:, None, None] * body.axis + r[:, None, None] * radial[None]
    along = body.axis + slope[:, None, None] * radial[None]
    along /= np.linalg.norm(along, axis=-1, keepdims=True)
    around = np.broadcast_to(np.cross(body.axis, radial)[None], points.shape)
    normals = np.cross(along, around)
    normals *= np.sign((normals * radial[None]).sum(-1, keepdims=True) + 1e-12)
    step_a = np.broadcast_to((length[-1] / n_a) * np.ones((n_a, 1)), (n_a, n_b))
    step_b = np.broadcast_to((2 * np.pi * np.maximum(r, 1e-9) / n_b)[:, None], (n_a, n_b))
    return _Grid(points, normals, along, np.ascontiguousarray(around), step_a, step_b)


def _disc(body: Revolution, spacing: float, top: bool) -> _Grid | None:
    """An end disc on a square grid (cells outside the disc dropped later by their zero spacing)."""
    radius = body.radii[-1] if top else body.radii[0]
    if radius < spacing:
        return None
    across, depthwise = body.frame()
    n = max(2, int(np.ceil(2 * radius / spacing)))
    x = ((np.arange(n) + 0.5) / n * 2 - 1) * radius
    centre = body.base + (body.heights[-1] if top else 0.0) * body.axis
    points = centre + x[:, None, None] * across + x[None, :, None] * depthwise
    inside = (x[:, None] ** 2 + x[None, :] ** 2) <= radius**2
    normal = body.axis if top else -body.axis
    step = np.where(inside, 2 * radius / n, 0.0)
    shape = points.shape
    return _Grid(points, np.broadcast_to(normal, shape), np.broadcast_to(across, shape),
                 np.broadcast_to(depthwise, shape), step, step)


def _shown(points: np.ndarray, normals: np.ndarray, camera: Camera, pixels: np.ndarray, zbuffer: np.ndarray,
           slack: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M,) whether each point (M, 3) shows in the photo on one of ``pixels`` (H, W) bool, its (M, 2) pixel
    position, and its (M,) cosine to the camera."""
    uv = project(points, camera)
    cosine = -(normals * points).sum(-1) / np.maximum(np.linalg.norm(points, axis=-1), 1e-12)
    col = np.clip(np.rint(uv[:, 0]).astype(int), 0, camera.width - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(int), 0, camera.height - 1)
    shown = (cosine >= _MIN_COLOUR_COSINE) & pixels[row, col] & (points[:, 2] <= zbuffer[row, col] + slack)
    return shown, uv, cosine


def revolution_surfels(body: Revolution, image: np.ndarray, pixels: np.ndarray, camera: Camera, stride: int,
                       opacity: float, radius_px: float) -> tuple[Gaussians, np.ndarray]:
    """Flat Gaussians over the body's closed surface, coloured as the module says, in the camera's world frame.

    ``pixels`` (H, W) bool: the photo's pixels that show the body (its mask less what stands in front, a
    handle or a spout). Otherwise as :func:`~marionette.target.cuboid.cuboid_surfels`.
    """
    depth = float(np.linalg.norm(body.base + 0.5 * body.heights[-1] * body.axis))
    area = 2 * np.pi * np.sum(0.5 * (body.radii[1:] + body.radii[:-1])
                              * np.hypot(np.diff(body.heights), np.diff(body.radii)))
    area += np.pi * (body.radii[0] ** 2 + body.radii[-1] ** 2)
    spacing = sample_spacing(area, depth, camera, stride, int(pixels.sum()))
    grids = [g for g in (_side(body, spacing), _disc(body, spacing, True), _disc(body, spacing, False))
             if g is not None]
    zbuffer = surface_zbuffer(np.concatenate([g.points.reshape(-1, 3) for g in grids]), camera)
    texture = MaskedTexture(image[..., :3], pixels, radius_px)
    slack = _DEPTH_SLACK * spacing
    # The mirror across the view: through the axis, its normal the view's direction square to the axis.
    view = body.base + 0.5 * body.heights[-1] * body.axis
    view = view - (view @ body.axis) * body.axis
    view /= max(np.linalg.norm(view), 1e-12)
    c2w = np.linalg.inv(camera.world_to_camera)
    means, scales, quats, rgbs, pixel_of = [], [], [], [], []
    side = None  # the side's colours (n_a, n_b, 3), once made: the source of an end no view shows
    for grid in grids:  # the side first
        shape = grid.points.shape[:2]
        points, normals = grid.points.reshape(-1, 3), grid.normals.reshape(-1, 3)
        offset = ((points - body.base) @ view)[:, None] * view
        mirrored, mirrored_normals = points - 2 * offset, normals - 2 * (normals @ view)[:, None] * view
        own, own_uv, own_cos = _shown(points, normals, camera, pixels, zbuffer, slack)
        other, other_uv, other_cos = _shown(mirrored, mirrored_normals, camera, pixels, zbuffer, slack)
        use_uv = np.where(own[:, None], own_uv, other_uv)
        cosine = np.where(own, own_cos, other_cos)
        colour = texture.sample(use_uv[:, 0], use_uv[:, 1], blur_level(cosine))
        known = (own | other).reshape(shape)
        rng = np.random.default_rng(0)
        if known.any() or side is None:  # the side keeps its bands round the body
            colour = fill_unseen(colour.reshape(*shape, 3), known, rng, keep_rows=side is None)
        else:  # an end no view shows (a bottom seen from above): the side's texture, quilted
            colour = quilt(side, shape, rng)
        if side is None:
            side = colour
        colour = colour.reshape(-1, 3)
        keep = (grid.step_a > 0).ravel() & (grid.step_b > 0).ravel()
        frame = np.stack([grid.tangent_a.reshape(-1, 3), grid.tangent_b.reshape(-1, 3), normals], axis=2)
        flip = np.linalg.det(frame) < 0
        frame[flip, :, 0] *= -1
        width = np.stack([OVERLAP * grid.step_a.ravel(), OVERLAP * grid.step_b.ravel()], axis=1)
        means.append(points[keep])
        scales.append(np.concatenate([width, FLATNESS * width.min(axis=1, keepdims=True)], axis=1)[keep])
        quats.append(matrix_to_quaternion(c2w[:3, :3] @ frame[keep]))
        rgbs.append(colour[keep])
        pixel_of.append(np.clip(np.rint(use_uv[keep]), 0, [camera.width - 1, camera.height - 1]))
    means = np.concatenate(means) @ c2w[:3, :3].T + c2w[:3, 3]
    gaussians = Gaussians.from_rgb(means, np.clip(np.concatenate(rgbs), 0.0, 1.0), np.concatenate(scales), opacity,
                                   np.concatenate(quats))
    return gaussians, np.concatenate(pixel_of).astype(np.int32)
