"""Exact renderer for planar textured faces: per-pixel ray–plane intersection.

For each front-facing face, the pixels of its projected bounding box are cast
as rays from the camera centre and intersected with the face's plane (a
numba kernel, with a vectorised NumPy twin that tests compare it against); a
z-buffer resolves occlusion across faces and parts.
Colours come from a bilinear texture lookup at the hit's ``(s, t)`` times a
Lambertian term from a fixed light. Anti-aliasing renders at ``SUPERSAMPLE``
times the resolution and averages blocks; coverage > 0.5 is the mask.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from ..camera import Camera
from ._objects import Face, Shape

#: Samples per pixel side. Odd, so one sample sits on the pixel centre and
#: "coverage > 0.5" is a majority vote with no ties.
SUPERSAMPLE = 3

#: Direction towards the light in camera coordinates: above, left and in front.
LIGHT = np.array([-0.4, -0.65, -0.65]) / np.linalg.norm([-0.4, -0.65, -0.65])
AMBIENT = 0.4

_NEAR = 1e-3
_EDGE_SLACK = 1e-4


def _sample_texture(face: Face, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Bilinear lookup: face coordinates (N,), (N,) → colours (N, 3) float64."""
    ht, wt = face.texture.shape[:2]
    s0, s1, t0, t1 = face.window
    x = (s0 + s * (s1 - s0)) * (wt - 1)
    y = (t0 + t * (t1 - t0)) * (ht - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, wt - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, ht - 2)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    tex = face.texture
    top = tex[y0, x0] * (1 - fx) + tex[y0, x0 + 1] * fx
    bottom = tex[y0 + 1, x0] * (1 - fx) + tex[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def _draw_face_numpy(face: Face, part: int, camera: Camera, box: tuple[int, int, int, int],
                     color: np.ndarray, depth: np.ndarray, ids: np.ndarray) -> None:
    """Z-buffer one face (camera coordinates) over pixel box ``u0, u1, v0, v1`` (inclusive).

    Plain-NumPy twin of :func:`_draw_face_kernel`; writes ``color`` (H, W, 3),
    ``depth`` (H, W) and ``ids`` (H, W) in place.
    """
    u0, u1, v0, v1 = box
    o, es, et, n = face.origin, face.edge_s, face.edge_t, face.normal
    # Ray directions d = ((u - cx) / fx, (v - cy) / fy, 1); the hit p = lam * d has n.p = n.o.
    dx = ((np.arange(u0, u1 + 1) - camera.cx) / camera.fx)[None, :]
    dy = ((np.arange(v0, v1 + 1) - camera.cy) / camera.fy)[:, None]
    nd = n[0] * dx + n[1] * dy + n[2]
    # Rays parallel to the plane give inf / nan, which every comparison below rejects.
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (n @ o) / nd  # the hit's depth z, since d_z = 1
        # (p - o).e / |e|^2 with p = lam * d gives the face coordinates.
        s = (lam * (es[0] * dx + es[1] * dy + es[2]) - es @ o) / (es @ es)
        t = (lam * (et[0] * dx + et[1] * dy + et[2]) - et @ o) / (et @ et)
        hit = ((nd < 0) & (lam < depth[v0:v1 + 1, u0:u1 + 1]) & (s >= -_EDGE_SLACK) & (s <= 1 + _EDGE_SLACK)
               & (t >= -_EDGE_SLACK) & (t <= 1 + _EDGE_SLACK))
    if face.disk:
        hit &= (2 * s - 1) ** 2 + (2 * t - 1) ** 2 <= 1
    rows, cols = np.nonzero(hit)
    s, t = s[rows, cols], t[rows, cols]
    # Shading normal interpolated across the face (constant on flat faces).
    nn = (1 - s)[:, None] * face.normals[0] + s[:, None] * face.normals[1]
    lit = np.maximum((nn @ LIGHT) / np.linalg.norm(nn, axis=1), 0.0)
    rows, cols = rows + v0, cols + u0
    color[rows, cols] = _sample_texture(face, s, t) * (AMBIENT + (1 - AMBIENT) * lit)[:, None]
    depth[rows, cols] = lam[rows - v0, cols - u0]
    ids[rows, cols] = part


@numba.njit(cache=True)
def _draw_face_kernel(o, es, et, n, normals, window, disk, texture, part, fx, fy, cx, cy,
                      u0, u1, v0, v1, light, ambient, slack, color, depth, ids):
    """Numba twin of :func:`_draw_face_numpy`, one pixel at a time (same arguments, unpacked)."""
    ht, wt = texture.shape[0], texture.shape[1]
    no = n[0] * o[0] + n[1] * o[1] + n[2] * o[2]
    eso = es[0] * o[0] + es[1] * o[1] + es[2] * o[2]
    eto = et[0] * o[0] + et[1] * o[1] + et[2] * o[2]
    ess = es[0] * es[0] + es[1] * es[1] + es[2] * es[2]
    ett = et[0] * et[0] + et[1] * et[1] + et[2] * et[2]
    for v in range(v0, v1 + 1):
        dy = (v - cy) / fy
        for u in range(u0, u1 + 1):
            dx = (u - cx) / fx
            nd = n[0] * dx + n[1] * dy + n[2]
            if nd >= 0:
                continue
            lam = no / nd
            if not lam < depth[v, u]:
                continue
            s = (lam * (es[0] * dx + es[1] * dy + es[2]) - eso) / ess
            t = (lam * (et[0] * dx + et[1] * dy + et[2]) - eto) / ett
            if s < -slack or s > 1 + slack or t < -slack or t > 1 + slack:
                continue
            if disk and (2 * s - 1) ** 2 + (2 * t - 1) ** 2 > 1:
                continue
            nx = (1 - s) * normals[0, 0] + s * normals[1, 0]
            ny = (1 - s) * normals[0, 1] + s * normals[1, 1]
            nz = (1 - s) * normals[0, 2] + s * normals[1, 2]
            lit = max((nx * light[0] + ny * light[1] + nz * light[2]) / np.sqrt(nx * nx + ny * ny + nz * nz), 0.0)
            shade = ambient + (1 - ambient) * lit
            x = (window[0] + s * (window[1] - window[0])) * (wt - 1)
            y = (window[2] + t * (window[3] - window[2])) * (ht - 1)
            x0 = min(max(int(np.floor(x)), 0), wt - 2)
            y0 = min(max(int(np.floor(y)), 0), ht - 2)
            ax, ay = x - x0, y - y0
            for c in range(3):
                top = texture[y0, x0, c] * (1 - ax) + texture[y0, x0 + 1, c] * ax
                bottom = texture[y0 + 1, x0, c] * (1 - ax) + texture[y0 + 1, x0 + 1, c] * ax
                color[v, u, c] = (top * (1 - ay) + bottom * ay) * shade
            depth[v, u] = lam
            ids[v, u] = part


def _face_box(face: Face, camera: Camera) -> tuple[int, int, int, int] | None:
    """Pixel box ``u0, u1, v0, v1`` (inclusive) of a face in camera coordinates.

    None if the face is back-facing or off the image.
    """
    if face.normal @ face.origin >= 0:  # the camera centre is behind the face's plane
        return None
    corners = face.origin + np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) @ np.stack([face.edge_s, face.edge_t])
    if corners[:, 2].min() <= _NEAR:
        raise ValueError("synthetic renderer: a face crosses the camera plane")
    u = corners[:, 0] / corners[:, 2] * camera.fx + camera.cx
    v = corners[:, 1] / corners[:, 2] * camera.fy + camera.cy
    u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())), camera.width - 1)
    v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())), camera.height - 1)
    return (u0, u1, v0, v1) if u0 <= u1 and v0 <= v1 else None


def render_shape(shape: Shape, poses: np.ndarray, camera: Camera, *, reference: bool = False,
                 with_depth: bool = False) -> tuple[np.ndarray, ...]:
    """Render parts moved by ``poses`` (P, 4, 4) (world transforms) at ``SUPERSAMPLE`` times ``camera``'s size.

    ``reference=True`` uses the plain-NumPy twin instead of the numba kernel.

    Returns
    -------
    color : (H*S, W*S, 3) float32
        Shaded colour, 0 where no part is hit.
    ids : (H*S, W*S) int8
        Part index per sample, -1 for background.
    depth : (H*S, W*S) float64
        Only with ``with_depth``: z-depth of each sample in ``camera``'s frame, inf for background.
    """
    big = camera.resized(camera.width * SUPERSAMPLE, camera.height * SUPERSAMPLE)
    color = np.zeros((big.height, big.width, 3), np.float32)
    depth = np.full((big.height, big.width), np.inf)
    ids = np.full((big.height, big.width), -1, np.int8)
    for k, part in enumerate(shape.parts):
        to_cam = camera.world_to_camera @ poses[k]
        for face in part:
            face = face.transformed(to_cam)
            box = _face_box(face, big)
            if box is None:
                continue
            if reference:
                _draw_face_numpy(face, k, big, box, color, depth, ids)
            else:
                _draw_face_kernel(face.origin, face.edge_s, face.edge_t, face.normal, face.normals, face.window,
                                  face.disk, face.texture, k, big.fx, big.fy, big.cx, big.cy, *box, LIGHT,
                                  AMBIENT, _EDGE_SLACK, color, depth, ids)
    return (color, ids, depth) if with_depth else (color, ids)


def pixel_depth(depth: np.ndarray) -> np.ndarray:
    """Supersampled z-depth (H*S, W*S) → per-pixel depth (H, W) float32.

    Takes the sample at each pixel's centre (``SUPERSAMPLE`` is odd), so the
    value is the exact depth along the ray through the pixel centre, the ray
    that ``d K^-1 [u, v, 1]`` lifts. It is inf where that ray misses the
    object, which on silhouette edges can disagree with the coverage mask.
    """
    c = SUPERSAMPLE // 2
    return depth[c::SUPERSAMPLE, c::SUPERSAMPLE].astype(np.float32)


def view_background(image: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, distance: float) -> np.ndarray:
    """A background seen from a moved camera: ``image`` (H, W, 3) float32 is a plane at depth ``distance``.

    The plane ``z = distance`` in the world (camera frame 0) looks like
    ``image`` from frame 0; from camera ``world_to_camera`` (4, 4) it maps by
    the plane-induced homography ``K (R + t n^T / distance) K^-1``, ``n = e_z``.
    Beyond its edges the plane repeats ``image`` mirrored. Returns (H, W, 3) float32.
    """
    r, t = world_to_camera[:3, :3], world_to_camera[:3, 3]
    homography = K @ (r + np.outer(t, [0.0, 0.0, 1.0 / distance])) @ np.linalg.inv(K)
    h, w = image.shape[:2]
    return cv2.warpPerspective(np.ascontiguousarray(image, np.float32), homography, (w, h),
                               flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)


def resolve(color: np.ndarray, ids: np.ndarray, num_parts: int,
            background: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Downsample a supersampled render to pixels by averaging SUPERSAMPLE x SUPERSAMPLE blocks.

    Parameters
    ----------
    color : (H*S, W*S, 3) float32
    ids : (H*S, W*S) int8
    num_parts : int
    background : (H, W, 3) float32 or None
        Composited behind the object; None leaves colour premultiplied by coverage.

    Returns
    -------
    image : (H, W, 3) float32
    coverage : (H, W) float32
        Fraction of samples on the object.
    part_ids : (H, W) int8
        Majority part where coverage > 0.5, else -1.
    """
    ss = SUPERSAMPLE
    h, w = ids.shape[0] // ss, ids.shape[1] // ss
    image = np.zeros((h, w, 3), np.float32) if background is None else np.array(background, np.float32)
    coverage = np.zeros((h, w), np.float32)
    part_ids = np.full((h, w), -1, np.int8)
    rows, cols = np.nonzero(np.any(ids >= 0, axis=1))[0], np.nonzero(np.any(ids >= 0, axis=0))[0]
    if rows.size == 0:
        return image, coverage, part_ids
    # Only the object's bounding box (in whole pixels) needs averaging.
    r0, r1, c0, c1 = rows[0] // ss, rows[-1] // ss + 1, cols[0] // ss, cols[-1] // ss + 1
    box = (slice(r0 * ss, r1 * ss), slice(c0 * ss, c1 * ss))
    size = (c1 - c0, r1 - r0)
    # INTER_AREA at an integer factor is an exact block mean.
    cover = np.stack([cv2.resize((ids[box] == k).astype(np.float32), size, interpolation=cv2.INTER_AREA)
                      for k in range(num_parts)])
    coverage[r0:r1, c0:c1] = cover.sum(axis=0)
    premult = cv2.resize(color[box], size, interpolation=cv2.INTER_AREA)
    image[r0:r1, c0:c1] = premult + (1.0 - coverage[r0:r1, c0:c1, None]) * image[r0:r1, c0:c1]
    part_ids[r0:r1, c0:c1] = np.where(coverage[r0:r1, c0:c1] > 0.5, np.argmax(cover, axis=0), -1)
    return image, coverage, part_ids
