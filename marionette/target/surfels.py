"""A lifted silhouette's closed surface, sampled by area into flat Gaussians (surfels).

The surface is given on a grid of cells (one per ``stride`` x ``stride``
pixels) by a mid-surface depth and a half-thickness: a front sheet
``mid - half`` on the pixels' rays, a back sheet ``2 half`` behind it along
the ray to the object's centre, and walls joining them along the outline.
Depths are set at the cells' corners (the mean over the adjacent inside
cells, so the outline is as smooth as the prior), and every cell is a
bilinear patch between its corners; outline corners are pulled in toward
their cells (``_INSET``).

Each patch gets samples in proportion to its area: a patch is split into
``k_u x k_v`` sub-patches, ``k`` its 3D edge over the cell's own width (a
wall gets a row of samples from front to back). On the sheets a sample may
be up to ``_SLOPE_ASPECT`` cells long: a steep patch near the outline is
seen edge-on in the photo, which holds about a pixel of detail down it, so
one long sample covers it where a row of small ones would only cost render
time. Each sample is a Gaussian flattened along the patch normal
(``_FLATNESS``) and as wide as its sub-patch (``_OVERLAP`` of it, so
neighbours close), so side views stay sharp and closed.

Colour comes from the photo at the sample's own pixel position, and only
from object pixels (a mask-normalised blur). A steep patch is seen in the
photo at a slant: the detail along it is not there, and copying pixels along
the slope draws stripes ("barcodes") on a side view. Such samples read a
blurred photo instead, the blur growing with the patch's stretch (its area
over its footprint), and walls read the most blurred one. The back sheet
takes the colour of the front pixel it lies behind (a mirror image).
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numba
import numpy as np

from ..camera import Camera
from ..gaussians import Gaussians
from ..geometry import matrix_to_quaternion
from ..parallel import chunks, parallel_for

__all__ = ["MaskedTexture", "sample_surface"]

# Gaussian standard deviation over sample spacing (neighbours overlap, no gaps), and thickness over width.
_OVERLAP = 0.6
# On the outline, narrower: a rim pixel's Gaussian at 0.6 px covers the pixel outside with alpha 0.24, and
# its sheet, the other sheet and the wall add up to grow the silhouette by a pixel.
_RIM_OVERLAP = 0.4
# Share of the way from an outline corner to its inside cells' centres it is moved.
_INSET = 0.8
_FLATNESS = 0.2
# At most this many samples along one patch edge.
_MAX_SPLIT = 64
# A sheet's surfel may be this many times longer down a slope than the cell is wide: the photo holds about
# one pixel of detail along a steep slope (it is seen edge-on), so more samples there add only cost.
_SLOPE_ASPECT = 3.0
# Blur levels (share of the object's pixel radius) for slanted patches and walls.
_BLUR_LEVELS = (0.0, 0.01, 0.02, 0.04)
_WALL_LEVEL = 1
# Below this share of object pixels under a texture read, the object's mean colour is used.
_MIN_WEIGHT = 1e-3
# Patches per item of the emission loop shared among threads (a patch emits up to _MAX_SPLIT² surfels).
_EMIT_CHUNK = 64


class MaskedTexture:
    """The photo's object pixels at a few blur levels, read bilinearly without background bleeding in."""

    def __init__(self, rgb: np.ndarray, mask: np.ndarray, radius_px: float):
        weight = mask.astype(np.float32)
        premultiplied = rgb.astype(np.float32) / 255.0 * weight[..., None]
        levels = []
        for share in _BLUR_LEVELS:
            sigma = share * radius_px
            blur = (lambda a: a) if sigma < 0.5 else (lambda a: cv2.GaussianBlur(a, (0, 0), sigma))  # noqa: E731
            levels.append(np.concatenate([blur(premultiplied), blur(weight)[..., None]], axis=2))
        self.levels = np.stack(levels)  # (L, H, W, 4): premultiplied colour and weight
        self.fallback = rgb[mask].astype(np.float32).mean(axis=0) / 255.0

    def sample(self, u: np.ndarray, v: np.ndarray, level: np.ndarray) -> np.ndarray:
        """(N,) pixel positions and blur level indices → (N, 3) colours in [0, 1]."""
        out = np.empty((len(u), 3), np.float32)
        for index, image in enumerate(self.levels):
            sel = np.nonzero(level == index)[0]
            if not len(sel):
                continue
            read = _bilinear(image, u[sel], v[sel])
            c, w = read[:, :3], read[:, 3]
            out[sel] = np.where(w[:, None] > _MIN_WEIGHT, c / np.maximum(w, _MIN_WEIGHT)[:, None], self.fallback)
        return np.clip(out, 0.0, 1.0)


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(H, W, C) image read at (N,) pixel positions (clamped to the image) → (N, C)."""
    h, w = image.shape[:2]
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), w - 2) if w > 1 else np.zeros(len(u), np.int64)
    v0 = np.minimum(np.floor(v).astype(np.int64), h - 2) if h > 1 else np.zeros(len(v), np.int64)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    return ((1 - fv) * ((1 - fu) * image[v0, u0] + fu * image[v0, u1])
            + fv * ((1 - fu) * image[v1, u0] + fu * image[v1, u1]))


def _unproject(camera: Camera, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Pixel positions and camera depths (...) → camera-frame points (..., 3)."""
    return np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z], axis=-1)


def _split(length: np.ndarray, width: np.ndarray, aspect: float) -> np.ndarray:
    """Samples along an edge of 3D ``length`` on a cell ``width`` wide, each up to ``aspect`` widths long:
    the nearest whole number of those lengths."""
    return np.clip(np.rint(length / (aspect * width)), 1, _MAX_SPLIT).astype(np.int64)


def _sub_grid(ku: np.ndarray, kv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per patch (P,) split counts → (patch index, a, b) of every sample, ``a, b`` in (0, 1) at sub-patch centres."""
    counts = ku * kv
    patch = np.repeat(np.arange(len(ku)), counts)
    local = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    a = (local % ku[patch] + 0.5) / ku[patch]
    b = (local // ku[patch] + 0.5) / kv[patch]
    return patch, a, b


def _perpendicular(v: np.ndarray) -> np.ndarray:
    """(N, 3) → (N, 3) unit vectors perpendicular to each ``v`` (any of them; x when ``v`` is zero)."""
    helper = np.eye(3)[np.argmin(np.abs(v), axis=1)]
    out = np.cross(v, helper)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(norm > 1e-12, out / np.maximum(norm, 1e-300), np.array([1.0, 0.0, 0.0]))


def _unit(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """(N, 3) vectors normalised; rows too short to have a direction take ``fallback`` (N, 3)."""
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(norm > 1e-12, v / np.maximum(norm, 1e-300), fallback)


def _frames(e1: np.ndarray, e2: np.ndarray, w1: np.ndarray, w2: np.ndarray, overlap: np.ndarray,
            rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patch edge vectors (P, 3) in the camera frame, sample widths along them (P,) and deviation over
    width (P,) → (world-frame quaternions (P, 4), scales (P, 3)), ``rotation`` (3, 3) camera to world.

    The Gaussian's axes: along ``e1``, across it within the patch, and the normal.
    """
    t1 = _unit(e1, _perpendicular(e2))
    normal = _unit(np.cross(t1, e2), _perpendicular(t1))  # a degenerate patch still gets a rotation
    t2 = np.cross(normal, t1)
    axes = np.stack([t1, t2, normal], axis=2)  # columns: local axes in the camera frame
    width2 = np.abs(np.einsum("ij,ij->i", e2, t2)) / np.maximum(np.linalg.norm(e2, axis=1), 1e-12) * w2
    tangent = np.stack([w1, np.maximum(width2, 0.25 * w1)], axis=1) * overlap[:, None]
    scales = np.concatenate([tangent, _FLATNESS * tangent.min(axis=1, keepdims=True)], axis=1)
    return matrix_to_quaternion(rotation @ axes), scales


class _Grid(NamedTuple):
    """The cell grid's corners and its inside cells (P of them)."""

    u: np.ndarray  # (Hc+1, Wc+1) corner pixel positions
    v: np.ndarray
    front: np.ndarray  # (Hc+1, Wc+1, 3) corner points of the front sheet, camera frame
    back: np.ndarray  # (Hc+1, Wc+1, 3) and of the back sheet
    ci: np.ndarray  # (P,) row and column of each inside cell
    cj: np.ndarray
    width: np.ndarray  # (P,) its width on the front sheet, world units
    overlap: np.ndarray  # (P,) its surfels' deviation over spacing


class _Samples(NamedTuple):
    """N surfels in the camera frame (rotations already in the world frame)."""

    means: np.ndarray  # (N, 3)
    quats: np.ndarray  # (N, 4)
    scales: np.ndarray  # (N, 3)
    colours: np.ndarray  # (N, 3)
    pixel_of: np.ndarray  # (N, 2)


def _corner_grid(cells: np.ndarray, mid: np.ndarray, half: np.ndarray, camera: Camera, s: int) -> _Grid:
    """Corner positions and points of the two sheets over the (Hc, Wc) cells."""
    hc, wc = cells.shape
    # Corner (i, j) sits between cells (i-1, j-1) and (i, j): means over the adjacent inside cells.
    pad = lambda a: np.pad(a, 1)  # noqa: E731
    corner_sum = lambda a: a[:-1, :-1] + a[:-1, 1:] + a[1:, :-1] + a[1:, 1:]  # noqa: E731
    count = corner_sum(pad(cells.astype(np.float64)))
    mid_c = corner_sum(pad(np.where(cells, mid, 0.0))) / np.maximum(count, 1)
    half_c = np.sqrt(corner_sum(pad(np.where(cells, half, 0.0) ** 2)) / np.maximum(count, 1))
    corner_v, corner_u = np.meshgrid(s // 2 + (np.arange(hc + 1) - 0.5) * s, s // 2 + (np.arange(wc + 1) - 0.5) * s,
                                     indexing="ij")
    # Corners on the outline move toward their inside cells' centres: the 0.3 px² low-pass of the
    # rasterizer widens every splat, and the sheets and walls that meet there, seen edge-on, would
    # otherwise grow the silhouette by a pixel.
    cell_v, cell_u = np.meshgrid(s // 2 + np.arange(hc) * s, s // 2 + np.arange(wc) * s, indexing="ij")
    outline = (count > 0) & (count < 4)
    for grid, centres in ((corner_u, cell_u), (corner_v, cell_v)):
        inner = corner_sum(pad(np.where(cells, centres, 0.0))) / np.maximum(count, 1)
        grid[outline] += _INSET * (inner[outline] - grid[outline])
    # The front sheet on the pixels' rays; the back sheet behind it along the ray to the object's centre,
    # so the back is as large as the front rather than widened by perspective (a box's back face
    # projects smaller than its front, as it should).
    front = _unproject(camera, corner_u, corner_v, mid_c - half_c)
    toward = _unproject(camera, np.mean(cell_u[cells]), np.mean(cell_v[cells]), 1.0)
    back = front + (2.0 * half_c)[..., None] * (toward / np.linalg.norm(toward))
    ci, cj = np.nonzero(cells)
    padded = np.pad(cells, 1)
    interior = padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]
    return _Grid(corner_u, corner_v, front, back, ci, cj,
                 np.maximum(s * (mid[ci, cj] - half[ci, cj]) / camera.fx, 1e-9),
                 np.where(interior[ci, cj], _OVERLAP, _RIM_OVERLAP))


class _Patches(NamedTuple):
    """P bilinear patches and how each is split into samples."""

    corners: np.ndarray  # (P, 4, 3) camera-frame corners, ordered 00, 10, 01, 11
    uv: np.ndarray  # (P, 4, 2) the photo positions their samples read, at the same corners
    fold: np.ndarray  # (P, 2) read offset per unit of min(b, 1 - b) (a wall's photo folded across the outline)
    split_a: np.ndarray  # (P,) int64 sub-patches along a (corner 00 → 10)
    split_b: np.ndarray  # (P,) int64 and along b (00 → 01)
    level: np.ndarray  # (P,) int64 blur level of the photo they read
    overlap: np.ndarray  # (P,) their surfels' deviation over spacing
    pixel: np.ndarray  # (P, 2) pixel of the cell they came from


def _edge_vectors(p4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear patches' corners (P, 4, 3) (ordered 00, 10, 01, 11) → their mean edge vectors (P, 3) along a, b."""
    return 0.5 * (p4[:, 1] - p4[:, 0] + p4[:, 3] - p4[:, 2]), 0.5 * (p4[:, 2] - p4[:, 0] + p4[:, 3] - p4[:, 1])


def _edges(p4: np.ndarray, width: np.ndarray, aspect: float = 1.0
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear patches with corners (P, 4, 3) (ordered 00, 10, 01, 11) split by area on cells ``width`` wide,
    into samples up to ``aspect`` widths long.

    Returns the mean edge vectors (P, 3) ``e_a``, ``e_b`` and the splits (P,) ``k_a``, ``k_b``.
    """
    e_a, e_b = _edge_vectors(p4)
    return (e_a, e_b, _split(np.linalg.norm(e_a, axis=1), width, aspect),
            _split(np.linalg.norm(e_b, axis=1), width, aspect))


def _sheet(grid: _Grid, points: np.ndarray, s: int) -> _Patches:
    """Patches of one sheet, given its corner points (Hc+1, Wc+1, 3)."""
    ci, cj = grid.ci, grid.cj
    corners = [(ci, cj), (ci, cj + 1), (ci + 1, cj), (ci + 1, cj + 1)]
    p4 = np.stack([points[i, j] for i, j in corners], axis=1)  # (P, 4, 3)
    e_u, e_v, ku, kv = _edges(p4, grid.width, _SLOPE_ASPECT)
    stretch = np.linalg.norm(np.cross(e_u, e_v), axis=1) / grid.width**2  # area over footprint, >= ~1
    level = np.clip(np.floor(np.log2(np.maximum(stretch, 1.0)) / 2), 0, len(_BLUR_LEVELS) - 1).astype(np.int64)
    # Both sheets read the pixel the sample lies on (or behind): the back is the front's mirror image.
    uv = np.stack([np.stack([grid.u[i, j], grid.v[i, j]], axis=1) for i, j in corners], axis=1)
    return _Patches(p4, uv, np.zeros((len(ci), 2)), ku, kv, level, grid.overlap,
                    np.stack([s // 2 + cj * s, s // 2 + ci * s], axis=1))


def _walls(grid: _Grid, cells: np.ndarray, s: int) -> list[_Patches]:
    """Patches of the walls: along every cell edge on the outline, from the front sheet's corners to the back's."""
    hc, wc = cells.shape
    padded = np.pad(cells, 1)
    out = []
    for di, dj, (a_i, a_j), (b_i, b_j) in ((-1, 0, (0, 0), (0, 1)), (1, 0, (1, 0), (1, 1)),
                                          (0, -1, (0, 0), (1, 0)), (0, 1, (0, 1), (1, 1))):
        ei, ej = np.nonzero(cells & ~padded[1 + di:1 + di + hc, 1 + dj:1 + dj + wc])
        if not len(ei):
            continue
        end0, end1 = (ei + a_i, ej + a_j), (ei + b_i, ej + b_j)
        p4 = np.stack([grid.front[end0], grid.front[end1], grid.back[end0], grid.back[end1]], axis=1)  # (E, 4, 3)
        width = grid.width[np.searchsorted(grid.ci * wc + grid.cj, ei * wc + ej)]
        along, down, ke, kd = _edges(p4, width)
        # The wall's texture is the photo folded in across the outline from the nearer sheet, so its
        # detail runs across the wall as it does on the front, not as rim pixels drawn out along depth.
        uv0, uv1 = np.stack([grid.u[end0], grid.v[end0]], axis=1), np.stack([grid.u[end1], grid.v[end1]], axis=1)
        fold = -np.array([dj, di], np.float64) * (np.linalg.norm(down, axis=1) / width * s)[:, None]
        out.append(_Patches(p4, np.stack([uv0, uv1, uv0, uv1], axis=1), fold, ke, kd,
                            np.full(len(ke), _WALL_LEVEL, np.int64), np.full(len(ke), _RIM_OVERLAP),
                            np.stack([s // 2 + ej * s, s // 2 + ei * s], axis=1)))
    return out


def _emit_numpy(patches: _Patches, texture: MaskedTexture, rotation: np.ndarray) -> _Samples:
    """Every patch's samples at its sub-patch centres; ``rotation`` (3, 3) camera to world.

    The plain-NumPy twin of :func:`_emit_chunks`.
    """
    (e_a, e_b), k_a, k_b = _edge_vectors(patches.corners), patches.split_a, patches.split_b
    quats, scales = _frames(e_a, e_b, np.linalg.norm(e_a, axis=1) / k_a, np.linalg.norm(e_b, axis=1) / k_b,
                            patches.overlap, rotation)  # one frame per patch, shared by its samples
    patch, a, b = _sub_grid(k_a, k_b)
    weights = np.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], axis=1)
    means = np.einsum("nk,nkc->nc", weights, patches.corners[patch])
    uv = np.einsum("nk,nkc->nc", weights, patches.uv[patch]) + np.minimum(b, 1 - b)[:, None] * patches.fold[patch]
    return _Samples(means, quats[patch], scales[patch], texture.sample(uv[:, 0], uv[:, 1], patches.level[patch]),
                    patches.pixel[patch])


@numba.njit(cache=True)
def _lerp2(image, v0, u0, v1, u1, fv, fu, c):
    """Channel ``c`` of ``image`` (H, W, C) between pixels (v0, u0) and (v1, u1) at fractions (fv, fu)."""
    return ((1 - fv) * ((1 - fu) * image[v0, u0, c] + fu * image[v0, u1, c])
            + fv * ((1 - fu) * image[v1, u0, c] + fu * image[v1, u1, c]))


# The kernel's vector helpers work on (x, y, z) tuples: they stay in registers, where small arrays would be
# allocated per patch.
@numba.njit(cache=True)
def _cross3(a, b):
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


@numba.njit(cache=True)
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True)
def _unit_or(v, fallback):
    """``v`` normalised, or ``fallback`` when too short to have a direction (as :func:`_unit`)."""
    norm = np.sqrt(_dot3(v, v))
    if norm > 1e-12:
        return v[0] / norm, v[1] / norm, v[2] / norm
    return fallback


@numba.njit(cache=True)
def _perpendicular_one(v):
    """As :func:`_perpendicular` for one vector: ``v`` crossed with the axis it has least of."""
    x, y, z = abs(v[0]), abs(v[1]), abs(v[2])
    if x <= y and x <= z:
        helper = (1.0, 0.0, 0.0)
    elif y <= z:
        helper = (0.0, 1.0, 0.0)
    else:
        helper = (0.0, 0.0, 1.0)
    return _unit_or(_cross3(v, helper), (1.0, 0.0, 0.0))


@numba.njit(cache=True)
def _quaternion_one(m, out):
    """As :func:`marionette.geometry.matrix_to_quaternion` for one rotation (3, 3), written into ``out`` (4,)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    diag = (1 + tr, 1 + m[0, 0] - m[1, 1] - m[2, 2], 1 - m[0, 0] + m[1, 1] - m[2, 2], 1 - m[0, 0] - m[1, 1] + m[2, 2])
    best = 0
    for i in range(1, 4):
        if diag[i] > diag[best]:
            best = i
    s = 2.0 * np.sqrt(max(diag[best], 1e-300))
    d21, d02, d10 = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]
    s10, s02, s21 = m[1, 0] + m[0, 1], m[0, 2] + m[2, 0], m[2, 1] + m[1, 2]
    if best == 0:
        q = (s / 4, d21 / s, d02 / s, d10 / s)
    elif best == 1:
        q = (d21 / s, s / 4, s10 / s, s02 / s)
    elif best == 2:
        q = (d02 / s, s10 / s, s / 4, s21 / s)
    else:
        q = (d10 / s, s02 / s, s21 / s, s / 4)
    sign = -1.0 if q[0] < 0 else 1.0
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    for i in range(4):
        out[i] = sign * q[i] / norm


@numba.njit(nogil=True, cache=True)
def _emit_chunks(first, step, nchunks, corners, uv, fold, split_a, split_b, level, overlap, pixel, first_sample, levels,
                 fallback, rotation, means, quats, scales, colours, pixel_of):
    """:func:`_emit_numpy` for chunks ``first, first + step, ...`` of ``_EMIT_CHUNK`` patches (one thread's share),
    writing sample ``first_sample[p] + j k_a + i`` of patch ``p`` (``first_sample`` (P,) the patches' offsets;
    ``levels`` the texture's (L, H, W, 4); outputs preallocated)."""
    h, w = levels.shape[1], levels.shape[2]
    for chunk in range(first, nchunks, step):
        for p in range(chunk * _EMIT_CHUNK, min(corners.shape[0], (chunk + 1) * _EMIT_CHUNK)):
            ka, kb = split_a[p], split_b[p]
            # The patch's frame, as _frames: along e_a, across it within the patch, and the normal.
            c0, c1, c2, c3 = corners[p, 0], corners[p, 1], corners[p, 2], corners[p, 3]
            e_a = (0.5 * (c1[0] - c0[0] + c3[0] - c2[0]), 0.5 * (c1[1] - c0[1] + c3[1] - c2[1]),
                   0.5 * (c1[2] - c0[2] + c3[2] - c2[2]))
            e_b = (0.5 * (c2[0] - c0[0] + c3[0] - c1[0]), 0.5 * (c2[1] - c0[1] + c3[1] - c1[1]),
                   0.5 * (c2[2] - c0[2] + c3[2] - c1[2]))
            w_a = np.sqrt(_dot3(e_a, e_a)) / ka
            w_b = np.sqrt(_dot3(e_b, e_b)) / kb
            t1 = _unit_or(e_a, _perpendicular_one(e_b))
            normal = _unit_or(_cross3(t1, e_b), _perpendicular_one(t1))
            t2 = _cross3(normal, t1)
            world = np.empty((3, 3))  # rotation @ [t1 t2 normal]
            for r in range(3):
                row = (rotation[r, 0], rotation[r, 1], rotation[r, 2])
                world[r, 0], world[r, 1], world[r, 2] = _dot3(row, t1), _dot3(row, t2), _dot3(row, normal)
            quat = np.empty(4)
            _quaternion_one(world, quat)
            across = abs(_dot3(e_b, t2)) / max(np.sqrt(_dot3(e_b, e_b)), 1e-12) * w_b
            tangent_a, tangent_b = w_a * overlap[p], max(across, 0.25 * w_a) * overlap[p]
            thickness = _FLATNESS * min(tangent_a, tangent_b)
            image = levels[level[p]]
            for j in range(kb):
                b = (j + 0.5) / kb
                for i in range(ka):
                    a = (i + 0.5) / ka
                    n = first_sample[p] + j * ka + i
                    w00, w10, w01, w11 = (1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b
                    for c in range(3):
                        means[n, c] = (w00 * corners[p, 0, c] + w10 * corners[p, 1, c] + w01 * corners[p, 2, c]
                                       + w11 * corners[p, 3, c])
                    # Element by element: an array-to-array store compiles numba's shape-error formatting (~7 s).
                    quats[n, 0], quats[n, 1], quats[n, 2], quats[n, 3] = quat[0], quat[1], quat[2], quat[3]
                    scales[n, 0], scales[n, 1], scales[n, 2] = tangent_a, tangent_b, thickness
                    pixel_of[n, 0], pixel_of[n, 1] = pixel[p, 0], pixel[p, 1]
                    folded = min(b, 1 - b)
                    u = (w00 * uv[p, 0, 0] + w10 * uv[p, 1, 0] + w01 * uv[p, 2, 0] + w11 * uv[p, 3, 0]
                         + folded * fold[p, 0])
                    v = (w00 * uv[p, 0, 1] + w10 * uv[p, 1, 1] + w01 * uv[p, 2, 1] + w11 * uv[p, 3, 1]
                         + folded * fold[p, 1])
                    # Bilinear read of the blur level, clamped as _bilinear clamps.
                    u = min(max(u, 0.0), w - 1.0)
                    v = min(max(v, 0.0), h - 1.0)
                    u0 = min(int(np.floor(u)), w - 2) if w > 1 else 0
                    v0 = min(int(np.floor(v)), h - 2) if h > 1 else 0
                    u1, v1 = min(u0 + 1, w - 1), min(v0 + 1, h - 1)
                    fu, fv = u - u0, v - v0
                    weight = _lerp2(image, v0, u0, v1, u1, fv, fu, 3)
                    for c in range(3):
                        value = (_lerp2(image, v0, u0, v1, u1, fv, fu, c) / weight if weight > _MIN_WEIGHT
                                 else fallback[c])
                        colours[n, c] = min(max(value, 0.0), 1.0)


def _emit(patches: _Patches, texture: MaskedTexture, rotation: np.ndarray, reference: bool = False) -> _Samples:
    """The surfels of ``patches``, each split into sub-patches with one surfel at each centre (camera-frame
    means, world-frame rotations: ``rotation`` (3, 3) camera to world)."""
    if reference:
        return _emit_numpy(patches, texture, rotation)
    counts = patches.split_a * patches.split_b
    total = int(counts.sum())
    out = _Samples(np.empty((total, 3)), np.empty((total, 4)), np.empty((total, 3)), np.empty((total, 3), np.float32),
                   np.empty((total, 2), patches.pixel.dtype))
    parallel_for(_emit_chunks, chunks(len(counts), _EMIT_CHUNK), patches.corners, patches.uv, patches.fold,
                 patches.split_a, patches.split_b, patches.level, patches.overlap, patches.pixel,
                 np.cumsum(counts) - counts, texture.levels, texture.fallback, rotation, *out)
    return out


def sample_surface(image: np.ndarray, mask: np.ndarray, cells: np.ndarray, mid: np.ndarray, half: np.ndarray,
                   camera: Camera, stride: int, opacity: float, radius_px: float,
                   reference: bool = False) -> tuple[Gaussians, np.ndarray]:
    """Surfels of the closed surface over a cell grid, in the camera frame.

    Parameters
    ----------
    image : (H, W, 3|4) uint8 photo; mask : (H, W) bool its object pixels.
    cells : (Hc, Wc) int, the piece of cell (i, j) (centre pixel ``(s//2 + j s, s//2 + i s)``), 0 outside the
        object; each piece is a closed surface of its own (a bool mask is one piece).
    mid, half : (Hc, Wc) float, mid-surface depth and half-thickness of each cell (world units; any
        value outside).
    camera : the photo's camera (pinhole; the result is in its frame).
    stride : int, cell size ``s`` in pixels.
    opacity : float, of every surfel.
    radius_px : float, the object's RMS radius in pixels (scales the blur of slanted patches).
    reference : bool, emit the samples with the plain-NumPy twin instead of the numba kernel.

    Returns
    -------
    (Gaussians, pixel_of): N surfels, and the (N, 2) int32 (u, v) pixel of the cell each came from.
    """
    texture = MaskedTexture(image[..., :3], mask, radius_px)
    c2w = np.linalg.inv(camera.world_to_camera)
    parts = []
    for piece in np.unique(cells[cells > 0]):  # each piece closed on its own
        inside = cells == piece
        grid = _corner_grid(inside, mid, half, camera, stride)
        patches = [_sheet(grid, grid.front, stride), _sheet(grid, grid.back, stride), *_walls(grid, inside, stride)]
        parts += [_emit(p, texture, c2w[:3, :3], reference) for p in patches]
    joined = _Samples(*(np.concatenate(column) for column in zip(*parts)))
    gaussians = Gaussians.from_rgb(joined.means @ c2w[:3, :3].T + c2w[:3, 3], joined.colours, joined.scales,
                                   opacity, joined.quats)
    return gaussians, joined.pixel_of.astype(np.int32)
