"""Shape priors for a single-view lift: what volume a silhouette most likely bounds.

One photo shows one side of an object; its depth must come from a prior.
Three are sheets, each a half-thickness map ``h`` (pixels) about a flat
mid-surface, so the front surface lies ``h`` before it and the back ``h``
behind:

- ``inflate``: the silhouette blown up into a rounded cushion,
  ``h = sqrt(u)`` with ``∇²u = -4`` inside and ``u = 0`` on the outline (a
  disc becomes a ball). The fallback for any outline.
- ``revolve``: a surface of revolution about a near-vertical axis in the
  image (pots, bottles, vases, cans): each row of the silhouette's
  mirror-symmetric core is a circle's chord, ``h = sqrt(R_v² - (u - c_v)²)``.
  What breaks the symmetry (a spout, a handle) is inflated on its own.
- ``extrude``: the outline pushed straight back with rounded edges (slabs,
  appliances, books): constant ``h`` away from the outline, a quarter circle
  of radius ``_EDGE_ROUNDING * depth`` at it. The depth is the shorter side
  of the silhouette's smallest enclosing rectangle.

The fourth, ``cuboid``, is no sheet: a box rebuilt as a box, six faces from
its outline (:mod:`.cuboid`); a hexagon whose sides pair up as a box's edges
do, or a rectangle. Lifts that keep to sheets (``LiftOptions.solids``
False) take a box's hexagon as sheets too: each pixel's front and back where
its ray enters and leaves the box. Likewise a ``revolve`` lift is rebuilt as
a solid of revolution about an axis that may lean towards the camera
(:mod:`.revolution`), its profile from :func:`revolve_profile`; where none
explains the outline, a ``revolve`` or ``inflate`` lift tries the fifth,
``mirror``: a mirror-symmetric object seen at an angle, carved out of the box
round it (:mod:`.mirror`). :func:`choose_shape` never names it: the lift
finds it (or ``--shape mirror`` asks for it).

:func:`choose_shape` picks one from the silhouette alone: ``cuboid`` when
the outline has a box's 4, 5 or 6 corners (:func:`box_outline`; where no box
fits it, the lift falls back to the sheets' choice), ``extrude`` when it is
another polygon of at most ``_MAX_CORNERS`` corners with straight sides (it
fits within ``_POLYGON_TOLERANCE`` of the object's size, and nine tenths of
the outline lie within ``_STRAIGHT`` of the tolerance, or a pixel and a
quarter, of its sides: a can's elliptical ends bow away from them, a box's
edges do not), else ``revolve`` when at least ``_MIN_SYMMETRY`` of the mask
lies in its mirror image about the best near-vertical axis, else ``inflate``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import cv2
import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.linalg import spsolve

from ..errors import InputError

if TYPE_CHECKING:
    from .shading import Light

__all__ = ["SHAPES", "ShapeChoice", "ShapeDepth", "choose_shape", "shape_depth", "inflate_silhouette",
           "revolve_profile", "largest_outline", "box_outline", "box_edges", "box_outline_edges"]

#: Shape prior names accepted by :func:`half_thickness` (``"auto"`` is :func:`choose_shape`'s).
SHAPES = ("inflate", "revolve", "extrude", "cuboid", "mirror")

# A polygon approximates the outline within this share of sqrt(area) (at least _MIN_TOLERANCE px): a
# circle needs 11 corners at this tolerance, a box seen at any angle at most 6 (a few more when small).
_POLYGON_TOLERANCE = 0.025
_MIN_TOLERANCE = 2.0
_MAX_CORNERS = 8
# Straight sides: the 90th percentile of the outline's distance to the polygon, over the tolerance
# (pixel steps alone give up to _STRAIGHT_PX). Measured: boxes 0.2-0.4 (0.6-0.8 px), cans and vases 0.5.
_STRAIGHT = 0.3
_STRAIGHT_PX = 1.25
# ...and covers the mask this well (intersection over union), the outline being convex enough.
_MIN_POLYGON_IOU = 0.95
_MIN_SOLIDITY = 0.9
# Share of the mask lying inside its mirror image for a surface of revolution.
_MIN_SYMMETRY = 0.85
# Axis tilts tried, as horizontal shift per row (±0.15: about ±8.5 degrees).
_TILTS = np.linspace(-0.15, 0.15, 7)
# Parts thinner than about twice this share of sqrt(area) are appendages of a body of revolution.
_APPENDAGE = 0.06
# ...and a piece closed on its own when it covers at least this share of the mask.
_MIN_PIECE = 0.01
# Edge radius of an extrusion, as a share of its depth.
_EDGE_ROUNDING = 0.15
# A box's outline is read as seen level when pairing the top chain's sides with the bottom's in the same
# order matches their lengths better by this much (sum of |log length ratio|).
_LEVEL_MARGIN = 0.1


@dataclass(frozen=True)
class ShapeChoice:
    """The shape prior used for a lift and why.

    Attributes
    ----------
    name : str
        One of :data:`SHAPES`.
    forced : bool
        True when the caller named it; False when :func:`choose_shape` did.
    confidence : float
        In [0, 1]: how well the silhouette fits the chosen prior (the polygon's
        IoU with the mask for ``extrude``, the symmetric share for
        ``revolve``; for ``inflate``, one minus the better of the other two).
    polygon_iou, corners, symmetry : float, int, float
        The measurements behind the choice.
    axis : tuple of float
        ``(column at the mask's centroid row, shift per row)`` of the best
        mirror axis.
    solid_iou : float or None
        How well the solid rebuilt for ``cuboid`` or ``revolve`` covers the
        mask (IoU of its outline); None when none was built (sheets).
    pitch : float or None
        Degrees a solid of revolution's axis leans towards the camera.
    fallback : str
        The sheets' prior a ``cuboid`` falls back to when no box covers the
        mask well enough.
    light : Light or None
        The photo's light read off a solid's surfaces
        (:mod:`~marionette.target.shading`); None when not relit.
    """

    name: str
    forced: bool
    confidence: float
    polygon_iou: float
    corners: int
    symmetry: float
    axis: tuple[float, float]
    solid_iou: float | None = None
    pitch: float | None = None
    fallback: str = "extrude"
    light: Light | None = None

    def describe(self) -> str:
        """One line for ``--verbose``."""
        how = "forced" if self.forced else "chosen from the silhouette"
        box = "" if self.solid_iou is None else f"; rebuilt as a solid covering {100 * self.solid_iou:.0f} %"
        if self.pitch is not None:
            box += f", its axis leaning {self.pitch:.1f}° towards the camera"
        if self.light is not None:
            x, y, z = self.light.direction
            box += f"; relit (light towards ({x:.2f}, {y:.2f}, {z:.2f}), ambient {self.light.ambient:.2f})"
        return (f"shape prior {self.name} ({how}, confidence {self.confidence:.2f}): outline a {self.corners}-corner "
                f"polygon at IoU {self.polygon_iou:.3f}, {100 * self.symmetry:.0f} % mirror-symmetric{box}")

    def as_dict(self) -> dict:
        """JSON-ready fields."""
        return {"name": self.name, "forced": self.forced, "confidence": round(self.confidence, 4),
                "polygon_iou": round(self.polygon_iou, 4), "corners": self.corners,
                "symmetry": round(self.symmetry, 4),
                "solid_iou": None if self.solid_iou is None else round(self.solid_iou, 4),
                "pitch": self.pitch, "light": None if self.light is None else self.light.as_dict()}


def largest_outline(mask: np.ndarray) -> np.ndarray:
    """(K, 1, 2) int32 outer contour of the largest connected component."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea)


def _tolerance(mask: np.ndarray) -> float:
    """How far (pixels) a polygon may stray from the outline of a (H, W) bool mask."""
    return max(_POLYGON_TOLERANCE * np.sqrt(mask.sum()), _MIN_TOLERANCE)


def _polygon_fit(mask: np.ndarray) -> tuple[float, int, float, bool]:
    """(IoU of the simplified outline with the mask, its corner count, solidity, whether its sides are straight)."""
    outline = largest_outline(mask)
    area = float(mask.sum())
    tolerance = _tolerance(mask)
    polygon = cv2.approxPolyDP(outline, tolerance, True)
    filled = np.zeros(mask.shape, np.uint8)
    cv2.fillPoly(filled, [polygon], 1)
    filled = filled.astype(bool)
    iou = float((filled & mask).sum() / max((filled | mask).sum(), 1))
    hull = cv2.convexHull(outline)
    solidity = area / max(cv2.contourArea(hull) + 0.5 * cv2.arcLength(hull, True), 1.0)  # pixel-centre outline
    if len(polygon) < 3:
        return iou, len(polygon), min(solidity, 1.0), False
    step = max(1, len(outline) // 2000)  # a few thousand outline points are plenty
    deviation = [abs(cv2.pointPolygonTest(polygon, (float(x), float(y)), True)) for x, y in outline[::step, 0]]
    straight = float(np.percentile(deviation, 90)) <= max(_STRAIGHT * tolerance, _STRAIGHT_PX)
    return iou, len(polygon), min(solidity, 1.0), straight


def _sheared(mask: np.ndarray, tilt: float, row0: float) -> np.ndarray:
    """The mask with row v read from column ``u + tilt * (v - row0)`` (nearest pixel): a tilted axis stands upright."""
    dst_to_src = np.float32([[1, tilt, -tilt * row0], [0, 1, 0]])
    return cv2.warpAffine(mask.astype(np.uint8), dst_to_src, mask.shape[::-1],
                          flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0).astype(bool)


def _mirror_axis(mask: np.ndarray) -> tuple[float, float, float]:
    """(column of the axis at the centroid row, tilt, share of the mask inside its mirror image).

    For an upright axis at column c, ``|mask ∩ mirror| = Σ_v (m_v ⋆ m_v)(2c)``, the rows' self-convolution
    summed: one FFT per tilt tries every axis at half-pixel steps.
    """
    rows = np.nonzero(mask.any(axis=1))[0]
    row0 = float(np.nonzero(mask)[0].mean())
    width = mask.shape[1]
    n = 1 << int(np.ceil(np.log2(2 * width)))
    best = (0.0, 0.0, -1.0)
    area = float(mask.sum())
    for tilt in _TILTS:
        upright = _sheared(mask, tilt, row0)[rows].astype(np.float64)
        spectrum = np.fft.rfft(upright, n, axis=1)
        overlap = np.fft.irfft((spectrum * spectrum).sum(axis=0), n)[: 2 * width - 1]  # index 2c
        index = int(np.argmax(overlap))
        share = float(overlap[index]) / area
        if share > best[2] + 1e-9:
            best = (index / 2.0, float(tilt), share)
    return best


def choose_shape(mask: np.ndarray, shape: str = "auto") -> ShapeChoice:
    """Pick (or, with ``shape`` named, report) the shape prior of a (H, W) bool silhouette."""
    mask = np.asarray(mask, dtype=bool)
    if shape != "auto" and shape not in SHAPES:
        raise InputError(f"shape must be auto or one of {', '.join(SHAPES)}, got {shape!r}")
    if not mask.any():
        raise InputError("target mask is empty")
    iou, corners, solidity, straight = _polygon_fit(mask)
    column, tilt, symmetry = _mirror_axis(mask)
    filled = iou >= _MIN_POLYGON_IOU and solidity >= _MIN_SOLIDITY
    polygonal = straight and corners <= _MAX_CORNERS and filled
    # A box's outline has 4 to 6 corners (perspective may bow its sides past the straightness test; a small
    # box's pixel steps may add corners at the finest tolerance, but then its sides are straight).
    box_like = filled and (corners <= 6 or polygonal) and box_outline(mask) is not None
    sheets = "extrude" if polygonal else "revolve" if symmetry >= _MIN_SYMMETRY else "inflate"
    name = shape if shape != "auto" else "cuboid" if box_like else sheets
    confidence = {"extrude": iou, "cuboid": iou, "revolve": symmetry, "mirror": symmetry,
                  "inflate": 1.0 - max(iou if polygonal else 0.0, symmetry)}[name]
    return ShapeChoice(name, shape != "auto", float(np.clip(confidence, 0.0, 1.0)), iou, int(corners), symmetry,
                       (column, tilt), fallback=sheets if shape == "auto" else "extrude")


def inflate_silhouette(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool mask → (H, W) float32 half-thickness in pixels, 0 outside.

    Solves the Poisson problem ``∇²u = −4`` inside the mask with ``u = 0``
    outside (5-point Laplacian, scipy.sparse), and takes ``h = sqrt(u)``: for
    a disc of radius ``R`` the solution is ``u = R² − r²``, so ``h`` is a
    ball's profile; any other silhouette gets a smooth, rounded volume that
    meets itself at the outline and is thicker where the shape is wide.
    """
    mask = np.asarray(mask, dtype=bool).copy()
    mask[[0, -1], :] = False  # the image border counts as outside
    mask[:, [0, -1]] = False
    out = np.zeros(mask.shape, np.float32)
    count = int(mask.sum())
    if count == 0:
        return out
    index = np.full(mask.shape, -1, np.int64)
    index[mask] = np.arange(count)
    rows, cols = np.nonzero(mask)
    centre = index[rows, cols]
    i, j = [centre], [centre]
    values = [np.full(count, 4.0)]
    for dv, du in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        nb = index[rows + dv, cols + du]
        inside = nb >= 0
        i.append(centre[inside])
        j.append(nb[inside])
        values.append(np.full(int(inside.sum()), -1.0))
    lap = sparse.csr_matrix((np.concatenate(values), (np.concatenate(i), np.concatenate(j))), shape=(count, count))
    u = spsolve(lap, np.full(count, 4.0))
    out[mask] = np.sqrt(np.clip(u, 0.0, None))
    return out


def revolve_profile(mask: np.ndarray, column: float, tilt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A surface of revolution's outline about a mirror axis: (radius (H,), chord (H, W) bool, pieces (H, W)).

    The axis is at ``column`` on the mask's centroid row and moves ``tilt`` columns per row. ``radius``: the
    half-length of each row's chord (its run of the mirror-symmetric body holding the axis), 0 off the body;
    ``pieces`` int32: 1 the body (its chords with the slivers around them), 2… each appendage, 0 outside.
    """
    h, w = mask.shape
    rows, cols = np.mgrid[0:h, 0:w]
    row0 = float(np.nonzero(mask)[0].mean())
    axis = column + tilt * (rows - row0)  # (H, W) axis column on each row
    # The body: the mask opened by a disc, which cuts off thin appendages (a handle and a spout whose
    # mirror images overlap would otherwise join the body's rows into one wide chord, a disc like a brim).
    radius_px = max(2, int(round(_APPENDAGE * np.sqrt(mask.sum()))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1,) * 2)
    body = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, disc).astype(bool)
    count, components = cv2.connectedComponents(body.astype(np.uint8), connectivity=4)
    if count > 2:
        body = components == 1 + np.argmax(np.bincount(components[body])[1:])
    mirrored_cols = np.rint(2 * axis - cols).astype(np.int64)
    inside = (mirrored_cols >= 0) & (mirrored_cols < w)
    core = body.copy()
    core[inside] &= body[rows[inside], mirrored_cols[inside]]
    core[~inside] = False
    # On each row, the run of the core that holds the axis is the chord; its half-length is R_v.
    runs, _ = ndimage.label(core, structure=[[0, 0, 0], [1, 1, 1], [0, 0, 0]])
    axis_col = np.clip(np.rint(axis[:, 0]).astype(np.int64), 0, w - 1)
    run_on_axis = runs[np.arange(h), axis_col]  # (H,) label of the run on the axis, 0 if none
    chord = (runs > 0) & (runs == run_on_axis[:, None])
    radius = 0.5 * chord.sum(axis=1)  # (H,) pixels; the chord's pixels reach 1/2 beyond their centres
    rest = mask & ~chord
    pieces = chord.astype(np.int32)
    if rest.any():
        components, count = ndimage.label(rest)
        # Appendages of some size are pieces of their own; slivers the opening shaved off the body stay with it.
        sizes = np.bincount(components.ravel(), minlength=count + 1)
        own = sizes >= _MIN_PIECE * mask.sum()
        own[0] = False
        piece_of = np.where(own, np.cumsum(own) + 1, 1)
        pieces = np.where(rest, piece_of[components], pieces).astype(np.int32)
    return radius, chord, pieces


def _revolve(mask: np.ndarray, column: float, tilt: float) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) half-thickness of the symmetric core as circles' chords, the rest inflated on its own, and the
    pieces (:func:`revolve_profile`)."""
    radius, chord, pieces = revolve_profile(mask, column, tilt)
    rows, cols = np.mgrid[0:mask.shape[0], 0:mask.shape[1]]
    axis = column + tilt * (rows - float(np.nonzero(mask)[0].mean()))
    half = np.sqrt(np.clip(radius[:, None] ** 2 - (cols - axis) ** 2, 0.0, None)) * chord
    rest = mask & ~chord
    if rest.any():
        half = np.where(rest, inflate_silhouette(rest), half)
    return half.astype(np.float32), pieces


def _extrude(mask: np.ndarray) -> np.ndarray:
    """(H, W) half-thickness of the outline pushed back by the short side of its enclosing rectangle."""
    (_, _), (a, b), _ = cv2.minAreaRect(largest_outline(mask))
    half_depth = 0.5 * max(min(a, b), 1.0)
    rounding = _EDGE_ROUNDING * 2 * half_depth
    inside = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1] - 0.5
    x = np.clip(inside, 0.0, rounding)
    edge = np.sqrt(np.clip(rounding**2 - (rounding - x) ** 2, 0.0, None))
    return np.where(mask, half_depth - rounding + edge, 0.0).astype(np.float32)


def box_outline(mask: np.ndarray) -> np.ndarray | None:
    """The corners (6|5|4, 2) of a box's outline in the (H, W) bool mask, pixels; None if it has none of these.

    Five: a hexagon one of whose corners lies nearly on a straight line (an edge seen almost end on).
    """
    outline = largest_outline(mask)
    tolerance = _tolerance(mask)
    for scale in (1.0, 1.5, 2.0):  # a small box's pixel steps may add a corner at the finest tolerance
        polygon = cv2.approxPolyDP(outline, scale * tolerance, True)
        if len(polygon) <= 6:
            break
    return polygon[:, 0].astype(np.float64) if len(polygon) in (4, 5, 6) else None


def box_edges(corners: np.ndarray) -> np.ndarray | None:
    """A box's three edges in 3D (3, 3), pixel units (orthographic), from its hexagonal outline (6, 2), or None.

    The outline's two most vertical sides are the box's outer vertical edge ``c``; the others form a top
    and a bottom chain of two sides each, left to right. Seen from above or below, the bottom chain runs
    the top's sides in the other order (the outline of a box is then the hexagon ``a, b, c, -a, -b, -c``),
    and orthogonal edges fix the depths: ``a_z b_z = -a·b`` and the two alike, so
    ``a_z² = -(a·b)(a·c)/(b·c)``; of its two mirror readings the one showing the upper face is taken. Seen
    level, both chains run alike (perspective bends them at the near vertical edge), ``c`` is
    perpendicular to ``a`` and ``b`` and the products are 0/0: then ``c_z = 0`` and the two faces beside
    the near edge turn away from it equally, ``-a_z = b_z = sqrt(a·b)``.
    """
    sides = np.roll(corners, -1, axis=0) - corners  # (6, 2), side k from corner k to k + 1
    steep = np.abs(sides[:, 1]) / np.maximum(np.linalg.norm(sides, axis=1), 1e-9)
    first = int(np.argmax(steep[:3] + steep[3:]))  # the pair k, k + 3 of most vertical opposite sides
    if min(steep[first], steep[first + 3]) < 0.7:
        return None
    order = np.roll(np.arange(6), -first)  # sides: vertical, chain, chain, vertical, chain, chain
    chains = [sides[order[1:3]], sides[order[4:6]]]
    # Left to right (a chain walked right to left is reversed and negated); the top one's middle corner is higher.
    chains = [ch if ch[:, 0].sum() > 0 else -ch[::-1] for ch in chains]
    top, bottom = chains if corners[order[2], 1] < corners[order[5], 1] else chains[::-1]
    down = [side if side[1] >= 0 else -side for side in (sides[order[0]], sides[order[3]])]
    vertical = 0.5 * (down[0] + down[1])
    # Which side of the bottom chain is which of the top's: the same edge projects to about the same length.
    length = lambda u, v: abs(np.log(np.linalg.norm(u) / max(np.linalg.norm(v), 1e-9)))  # noqa: E731
    same = length(top[0], bottom[0]) + length(top[1], bottom[1])
    swapped = length(top[0], bottom[1]) + length(top[1], bottom[0])
    if swapped < same + _LEVEL_MARGIN:  # seen from above or below (or alike either way: try that first)
        a, b, c = 0.5 * (top[0] + bottom[1]), 0.5 * (top[1] + bottom[0]), vertical
        ab, ac, bc = a @ b, a @ c, b @ c
        if min(abs(ab), abs(ac), abs(bc)) > 1e-9 and -ab * ac / bc > 0:
            a_z = np.sqrt(-ab * ac / bc)
            edges = np.array([[*a, a_z], [*b, -ab / a_z], [*c, -ac / a_z]])
            normals = edges / np.linalg.norm(edges, axis=1, keepdims=True)
            upper = normals[np.argmax(np.abs(normals[:, 1]))]
            if upper[1] * upper[2] < 0:  # the face toward the image's top faces the camera (y down, z away)
                edges[:, 2] *= -1
            return edges
    a, b = 0.5 * (top[0] + bottom[0]), 0.5 * (top[1] + bottom[1])
    if a @ b <= 0:
        return None
    depth = np.sqrt(a @ b)
    return np.array([[*a, -depth], [*b, depth], [*vertical, 0.0]])


def box_outline_edges(mask: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(axes (3, 3) rows, half-lengths (3,) in pixels) of the box an outline's corners (6|5|4, 2) show, or None.

    Read orthographically: a hexagon by :func:`box_edges`; a rectangle (the (H, W) bool ``mask``'s) as a box
    seen square on, as deep as its shorter side (what an extrusion assumes). Five corners are not read (None).
    """
    if len(corners) == 5:
        return None
    if len(corners) == 6:
        edges = box_edges(corners)
        if edges is None:
            return None
    else:  # seen square on: the rectangle's sides and a depth of its shorter side, as an extrusion has
        (_, _), (w, h), angle = cv2.minAreaRect(largest_outline(mask))
        t = np.radians(angle)
        edges = np.array([[w * np.cos(t), w * np.sin(t), 0.0], [-h * np.sin(t), h * np.cos(t), 0.0],
                          [0.0, 0.0, max(min(w, h), 1.0)]])
    lengths = np.linalg.norm(edges, axis=1)
    u, _, vt = np.linalg.svd(edges / lengths[:, None])  # the nearest rotation to the (nearly orthogonal) edges
    axes = u @ vt
    if np.linalg.det(axes) < 0:
        axes[2] *= -1
    return axes, 0.5 * lengths


def _cuboid(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """A box seen at an angle as sheets over its hexagonal outline: (offset, half) (H, W) pixels, or None.

    The box's edges come from :func:`box_edges`; each pixel's front and back are where its ray
    (taken orthographic) enters and leaves the box.
    """
    corners = box_outline(mask)
    if corners is None or len(corners) != 6:
        return None
    edges = box_edges(corners)
    if edges is None:
        return None
    normals = edges / np.linalg.norm(edges, axis=1, keepdims=True)
    centre = corners.mean(axis=0)
    vs, us = np.nonzero(mask)
    # Along each pixel's ray the slab |n·(x - centre)| <= |edge| / 2 of each edge direction is an interval in z.
    lateral = (np.stack([us, vs], axis=1) - centre) @ normals[:, :2].T  # (M, 3)
    half_lengths = 0.5 * np.linalg.norm(edges, axis=1)
    nz = normals[:, 2]
    slanted = np.abs(nz) > 1e-6  # an edge across the view bounds z; one along the image (a level box's
    with np.errstate(divide="ignore", invalid="ignore"):  # vertical edge) only bounds the pixels
        ends = np.stack([(-half_lengths - lateral) / nz, (half_lengths - lateral) / nz])  # (2, M, 3)
    within = np.abs(lateral) <= half_lengths
    ends[0] = np.where(slanted, ends[0], np.where(within, -np.inf, np.inf))
    ends[1] = np.where(slanted, ends[1], np.where(within, np.inf, -np.inf))
    near, far = ends.min(axis=0).max(axis=1), ends.max(axis=0).min(axis=1)  # (M,)
    inside = far > near
    if inside.mean() < 0.9:
        return None
    offset, half = np.zeros(mask.shape, np.float32), np.zeros(mask.shape, np.float32)
    offset[vs, us] = np.where(inside, 0.5 * (near + far), 0.0)
    half[vs, us] = np.where(inside, 0.5 * (far - near), 0.0)
    # Mask pixels just off the rebuilt box take their nearest box pixel's depths, half a pixel thick.
    known = np.zeros(mask.shape, bool)
    known[vs[inside], us[inside]] = True
    _, (iy, ix) = ndimage.distance_transform_edt(~known, return_indices=True)
    offset = np.where(mask & ~known, offset[iy, ix], offset)
    half = np.where(mask & ~known, 0.5, half)
    return offset.astype(np.float32), half.astype(np.float32)


class ShapeDepth(NamedTuple):
    """A prior's volume over the silhouette, in pixels (0 outside).

    offset, half : (H, W) float32, the mid-surface's depth offset and the half-thickness about it.
    pieces : (H, W) int32, 0 outside, 1… pieces closed on their own (a pot's spout is not joined to its
        body by a web of surface: it ends inside it).
    """

    offset: np.ndarray
    half: np.ndarray
    pieces: np.ndarray


def shape_depth(mask: np.ndarray, choice: ShapeChoice) -> ShapeDepth:
    """(H, W) bool silhouette → its volume under the chosen prior."""
    mask = np.asarray(mask, dtype=bool)
    flat, whole = np.zeros(mask.shape, np.float32), mask.astype(np.int32)
    if choice.name == "revolve":
        half, pieces = _revolve(mask, *choice.axis)
        return ShapeDepth(flat, half, pieces)
    if choice.name in ("extrude", "cuboid"):  # a box's sheets where its faces are not built (see lift_image)
        box = _cuboid(mask)
        return ShapeDepth(*box, whole) if box is not None else ShapeDepth(flat, _extrude(mask), whole)
    return ShapeDepth(flat, inflate_silhouette(mask), whole)
