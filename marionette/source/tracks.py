"""Dense 2D point tracks over a masked object (pyramidal Lucas–Kanade, drift-corrected).

Stage 1 of Motion Marionette (Sec. 3, Eq. 1) needs long-range 2D
trajectories ``u^k_t`` of object points. The paper uses learned trackers
(BootsTAP, CoTracker); we use the classical pyramidal Lucas–Kanade tracker
(Bouguet, "Pyramidal implementation of the affine Lucas Kanade feature
tracker", 2001; ``cv2.calcOpticalFlowPyrLK``), frame to frame:

- seeds on a grid with ``spacing`` pixels inside the object mask, each at the
  most textured pixel of its grid cell (Shi–Tomasi minimum eigenvalue, "Good
  features to track", CVPR 1994), skipping flat cells;
- per frame, pyramidal LK on the lightly blurred greyscale frames gives each
  point's new position, then two corrections: a refinement on locally
  contrast-normalised frames (:func:`_normalise`) whose window only weighs
  object pixels, symmetrically about the point (:func:`_refine_masked`;
  plain LK near the silhouette lags behind the object by a few percent of
  its motion), and an alignment with the track's window in the frame where
  it was anchored, under an affine warp with a gain and a bias
  (:func:`_align_affine`; chained LK lags by 1-2 % of the motion under
  rotation, which adds up to degrees over a turn). A track is anchored where
  it was seeded, and again wherever its window changed too much to align;
  or, ``strict``, it ends there and a fresh track starts at the same place,
  so that every track follows one surface point (``strict="auto"``: strict
  when the footage keeps windows matching, see :func:`track`);
- a forward-backward check (Kalal et al., "Forward-backward error", ICPR
  2010): a point tracked to the next frame and back must land within
  ``fb_threshold`` pixels of where it started;
- termination when a point leaves the image or the (slightly dilated) mask;
- re-seeding every ``reseed_every`` frames in mask regions with no live track
  nearby, so that surface revealed by a turning object gets tracks too. Such
  tracks start later; ``Tracks.start`` records where.

The two corrections are numba kernels, each with a NumPy twin of the same
name plus ``_numpy`` that the tests compare it with.

Pixel convention: (u, v) with (0, 0) at the centre of the top-left pixel
(docs/DESIGN.md), which is also OpenCV's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from ..errors import InputError
from ..io.video import PackedMasks, VideoFrames, check_frames
from .spd6 import cholesky6, cholesky6_solve

__all__ = ["Tracks", "track"]

# LK stops after 30 iterations or a step below 0.01 px; tighter than OpenCV's
# default (0.03 px) because pose accuracy hinges on sub-pixel tracks.
_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
# Block size of the Shi–Tomasi texture measure used to place and filter seeds.
_TEXTURE_BLOCK = 5
# Pre-blur (px) against aliasing, and the scale (px) and floor (grey levels)
# of the local contrast normalisation.
_BLUR_SIGMA = 1.0
_NORM_SIGMA = 4.0
_NORM_EPS = 4.0
# Blur (px) of the grey images the seed alignment compares: light, against
# aliasing, and applied alike to the seed and the current frame.
_ALIGN_BLUR = 0.7
# A track's window matches the one it is aligned against when the residual
# is below _ANCHOR_RESIDUAL (RMS mismatch of the normalised images, where the
# local contrast is 1) or, with ``strict``, _STRICT_RESIDUAL (of the lightly
# blurred grey images, over their RMS contrast, with gain, bias and the share
# the pixel noise explains removed), the position within _ANCHOR_SHIFT pixels
# of the chained estimate and the warp of sane area. A window that stops
# matching straddles a crease or an occluding edge, its surface turned away,
# or the video is blurred or compressed: the track is anchored again where it
# is (one chained step, some drift) or, strict, ends there (and a fresh one
# starts at the same place).
_ANCHOR_RESIDUAL = 1.0
_STRICT_RESIDUAL = 0.1
_MIN_GAIN = 1.0 / 3.0
_ANCHOR_SHIFT = 2.0
# ``strict="auto"``: tracks are strict while at least _STRICT_SHARE of all the
# windows aligned so far match their anchor, counted from _PROBE_FRAMES frame
# steps on; below it, the footage (compression, blur, changing light) cuts
# strict tracks into pieces a frame or two long, and tracking starts over
# anchored. 0.7: the synthetic one-part scenes keep 0.73-0.97, the real clips
# 0.36-0.66 over the whole clip (docs/benchmarks/extract.md).
_PROBE_FRAMES = 8
_STRICT_SHARE = 0.7


@dataclass(frozen=True)
class Tracks:
    """2D point tracks over T frames.

    Attributes
    ----------
    uv : (T, M, 2) float32
        Pixel position of track m at frame t; NaN where not visible.
    visible : (T, M) bool
        Whether track m is alive at frame t. A track is visible on one
        contiguous run of frames starting at ``start[m]``.
    start : (M,) int64
        Frame at which each track was seeded.
    strict : bool
        Whether a track ends where its window stops matching (each track one
        surface point) rather than being anchored again there.
    continues : (M,) int64
        The track each one carries on from: it starts where that one was at
        the frame before (a strict track cut where its window stopped
        matching); -1 where it was seeded. Always a lower index.
    anchor_match : float
        Share of the window alignments that matched their anchor closely (the
        strict criterion): over the whole video when strict, over the first
        frames where ``strict="auto"`` chose anchored tracks; NaN otherwise.
    """

    uv: np.ndarray
    visible: np.ndarray
    start: np.ndarray
    strict: bool = False
    anchor_match: float = float("nan")
    continues: np.ndarray | None = None

    def __post_init__(self) -> None:
        uv = np.asarray(self.uv, dtype=np.float32)
        vis = np.asarray(self.visible, dtype=bool)
        start = np.asarray(self.start, dtype=np.int64)
        if uv.ndim != 3 or uv.shape[2] != 2:
            raise ValueError(f"Tracks.uv must be (T, M, 2), got {uv.shape}")
        t, m = uv.shape[:2]
        if vis.shape != (t, m) or start.shape != (m,):
            raise ValueError(f"Tracks.visible must be ({t}, {m}) and start ({m},), got {vis.shape} and {start.shape}")
        if not np.array_equal(np.isfinite(uv).all(axis=2), vis):
            raise ValueError("Tracks.uv must be finite exactly where Tracks.visible is True")
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "visible", vis)
        object.__setattr__(self, "start", start)
        continues = np.full(m, -1, np.int64) if self.continues is None else np.asarray(self.continues, np.int64)
        if continues.shape != (m,) or (continues >= np.arange(m)).any():
            raise ValueError(f"Tracks.continues must be ({m},) with each entry below its own index")
        object.__setattr__(self, "continues", continues)

    @property
    def num_frames(self) -> int:
        return self.uv.shape[0]

    @property
    def num_tracks(self) -> int:
        return self.uv.shape[1]

    def chains(self) -> np.ndarray:
        """(M,) int64: the chain of tracks carrying on from one another that each track belongs to, numbered
        0..C-1 in the order of their first tracks."""
        root = np.arange(self.num_tracks)
        for m in np.nonzero(self.continues >= 0)[0]:  # ascending, and each carries on from a lower index
            root[m] = root[self.continues[m]]
        return np.unique(root, return_inverse=True)[1].astype(np.int64)

    def subset(self, keep: np.ndarray) -> "Tracks":
        """The tracks ``keep`` ((M,) bool) selects; a kept track whose predecessor is dropped counts as seeded.
        Keeping all of them gives these tracks themselves (a long clip's are hundreds of megabytes)."""
        if np.all(keep):
            return self
        index = np.full(self.num_tracks, -1, np.int64)
        index[keep] = np.arange(int(np.count_nonzero(keep)))
        continues = np.where(self.continues[keep] >= 0, index[np.maximum(self.continues[keep], 0)], -1)
        return Tracks(self.uv[:, keep], self.visible[:, keep], self.start[keep], self.strict, self.anchor_match,
                      continues)

    def joined(self, chain: np.ndarray | None = None) -> "Tracks":
        """One track per chain (:meth:`chains`, or ``chain`` (M,) when already at hand), each following its
        pieces in turn: long tracks that carry each cut's small step error on, for what needs them long (the
        part segmentation, the focal length, the amount of motion)."""
        chain = self.chains() if chain is None else chain
        count = int(chain.max()) + 1 if self.num_tracks else 0
        uv = np.full((self.num_frames, count, 2), np.nan, np.float32)
        frame, m = np.nonzero(self.visible)
        uv[frame, chain[m]] = self.uv[frame, m]
        start = np.full(count, self.num_frames, np.int64)
        np.minimum.at(start, chain, self.start)
        return Tracks(uv, np.isfinite(uv).all(axis=2), start, self.strict, self.anchor_match)


def _check_video(frames: np.ndarray | VideoFrames,
                 masks: np.ndarray | PackedMasks) -> tuple[np.ndarray | VideoFrames, np.ndarray | PackedMasks]:
    """Validate frames (T, H, W, 3) uint8 and masks (T, H, W); array masks → bool (non-zero = object).

    Frames may be decoded on demand (:class:`~marionette.io.video.VideoFrames`)
    and masks packed (:class:`~marionette.io.video.PackedMasks`).
    """
    check_frames(frames)
    if not isinstance(masks, (np.ndarray, PackedMasks)) or masks.shape != frames.shape[:3]:
        raise InputError(f"masks must be an array {frames.shape[:3]} matching frames, got shape {np.shape(masks)}")
    if masks.dtype != bool and not np.issubdtype(masks.dtype, np.integer):
        raise InputError(f"masks must be bool or integer (non-zero = object), got {masks.dtype}")
    masks = masks if isinstance(masks, PackedMasks) else masks.astype(bool, copy=False)
    if not masks[0].any():
        raise InputError("the object mask of frame 0 is empty")
    return frames, masks


def _texture(grey: np.ndarray) -> np.ndarray:
    """Shi–Tomasi minimum eigenvalue of the structure tensor (H, W) float32."""
    return cv2.cornerMinEigenVal(grey, _TEXTURE_BLOCK, 3)


def _grid_seeds(texture: np.ndarray, allowed: np.ndarray, spacing: int, min_eigen: float) -> np.ndarray:
    """One seed per ``spacing``-sized grid cell: its most textured allowed pixel.

    texture, allowed : (H, W); returns (S, 2) float32 pixel positions of the
    cells whose best allowed pixel has ``texture >= min_eigen``.
    """
    h, w = texture.shape
    hc, wc = -(-h // spacing), -(-w // spacing)
    score = np.full((hc * spacing, wc * spacing), -1.0, np.float32)
    score[:h, :w] = np.where(allowed, texture, -1.0)
    cells = score.reshape(hc, spacing, wc, spacing).transpose(0, 2, 1, 3).reshape(hc, wc, spacing * spacing)
    best = cells.argmax(axis=2)
    ok = np.take_along_axis(cells, best[..., None], axis=2)[..., 0] >= min_eigen
    ci, cj = np.nonzero(ok)
    dy, dx = np.divmod(best[ci, cj], spacing)
    return np.stack([cj * spacing + dx, ci * spacing + dy], axis=1).astype(np.float32)


def _free_of_tracks(points: np.ndarray, shape: tuple[int, int], radius: float) -> np.ndarray:
    """(H, W) bool: pixels farther than ``radius`` from every point (N, 2)."""
    h, w = shape
    occupied = np.full((h, w), 255, np.uint8)
    ij = np.clip(np.rint(points[:, ::-1]).astype(np.int64), 0, [h - 1, w - 1])
    occupied[ij[:, 0], ij[:, 1]] = 0
    return cv2.distanceTransform(occupied, cv2.DIST_L2, 5) > radius


def _inside(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N,) bool: points (N, 2) lie in the image and on a True pixel of ``mask`` (H, W)."""
    h, w = mask.shape
    u, v = points[:, 0], points[:, 1]
    ok = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    ok[ok] = mask[np.rint(v[ok]).astype(np.int64), np.rint(u[ok]).astype(np.int64)]
    return ok


def _normalise(grey: np.ndarray) -> np.ndarray:
    """Local contrast normalisation (H, W) uint8 → float32: ``(I - mean) / (std + ε)`` over a Gaussian window.

    Brightness of a turning surface changes with its angle to the light; LK
    assumes constant brightness, so a gain change biases it. Dividing by the
    local standard deviation removes gain and offset changes that are smooth
    over ``_NORM_SIGMA`` pixels. A light blur first keeps aliased texture
    (which does not move with the surface) from pulling tracks.
    """
    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), _BLUR_SIGMA)
    d = g - cv2.GaussianBlur(g, (0, 0), _NORM_SIGMA)
    return d / (np.sqrt(cv2.GaussianBlur(d * d, (0, 0), _NORM_SIGMA)) + _NORM_EPS)


def _noise_level(grey: np.ndarray) -> float:
    """Standard deviation (grey levels) of white pixel noise in ``grey`` (H, W) uint8.

    Immerkær's estimator ("Fast noise variance estimation", CVIU 1996): the
    mean absolute response to a Laplacian difference that cancels planes and
    smooth shading. Texture adds to it, so it errs high (0.5 on a clean render
    of the synthetic scenes).
    """
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    response = cv2.filter2D(grey.astype(np.float32), -1, kernel)[1:-1, 1:-1]  # whole numbers, exact
    # Summed in float64, where sums of whole numbers are exact in any order.
    return float(np.sqrt(np.pi / 2) * np.abs(response).astype(np.float64).mean() / 6) if response.size else 0.0


def _aligned_noise(grey: np.ndarray) -> float:
    """Standard deviation of the pixel noise of ``grey`` (H, W) uint8 once blurred by ``_ALIGN_BLUR``.

    The blur's gain on white noise is the norm of its impulse response.
    """
    impulse = np.zeros((9, 9), np.float32)
    impulse[4, 4] = 1.0
    return _noise_level(grey) * float(np.sqrt((cv2.GaussianBlur(impulse, (0, 0), _ALIGN_BLUR) ** 2).sum()))


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) at positions ``x, y`` (equal shapes) with exact bilinear weights, edges clamped.

    (``cv2.remap`` quantises positions to 1/32 px, coarser than the
    refinements' stopping steps.)
    """
    h, w = image.shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0, y0 = x.astype(np.int64), y.astype(np.int64)
    ax, ay = x - x0, y - y0
    flat, i = image.ravel(), y0 * w + x0
    return (1 - ay) * ((1 - ax) * flat[i] + ax * flat[i + 1]) + ay * ((1 - ax) * flat[i + w] + ax * flat[i + w + 1])


def _bilinear_patches(image: np.ndarray, points: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) at ``points`` (N, 2) + ``offsets`` (K, 2) → (N, K) float64."""
    points = points.astype(np.float64)
    return _bilinear(image, points[:, None, 0] + offsets[None, :, 0], points[:, None, 1] + offsets[None, :, 1])



def _window_samples(image: np.ndarray, mask: np.ndarray, points: np.ndarray, window: int):
    """Samples of the ``window``-sided windows around (N, 2) points, for the NumPy twins.

    Returns offsets (K, 2) (reversed order is ``-offsets``), weights (N, K)
    (mask, made point-symmetric, times a Gaussian of σ = 0.3 window side,
    zero outside the image), and the template, x and y gradients (N, K).
    """
    r = window // 2
    oy, ox = np.mgrid[-r:r + 1, -r:r + 1]
    offsets = np.stack([ox.ravel(), oy.ravel()], axis=1).astype(np.float64)
    h, w = image.shape
    x, y = points[:, None, 0] + offsets[None, :, 0], points[:, None, 1] + offsets[None, :, 1]
    in_image = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    weights = _bilinear_patches(mask, points, offsets) * in_image
    weights = weights * weights[:, ::-1] * np.exp(-(offsets**2).sum(axis=1) / (2 * (0.3 * (2 * r + 1)) ** 2))
    template = _bilinear_patches(image, points, offsets)
    gx = _bilinear_patches(cv2.Scharr(image, cv2.CV_32F, 1, 0) / 32.0, points, offsets)
    gy = _bilinear_patches(cv2.Scharr(image, cv2.CV_32F, 0, 1) / 32.0, points, offsets)
    return offsets, weights, template, gx, gy

def _refine_masked_numpy(prev: np.ndarray, cur: np.ndarray, prev_mask: np.ndarray, p0: np.ndarray,
                         p1: np.ndarray, window: int, iterations: int = 8) -> np.ndarray:
    """Refine LK positions with object-only, point-symmetric window weights (NumPy reference).

    OpenCV's LK weighs its whole window equally. Near the silhouette part of
    the window is static background, which pulls the track towards zero
    motion; and under rotation even a window cut to the object is biased,
    since translation-only LK measures the motion of the window's weighted
    centroid, which lies inside the object from the point. Here a translation
    LK (inverse compositional, Baker & Matthews, IJCV 2004) runs at full
    resolution with weights ``m(o) m(-o) g(o)``: ``m`` the object mask of
    ``prev`` around the point (0 outside the image), made point-symmetric so
    that the weighted centroid is the point itself, and ``g`` a Gaussian
    (σ = 0.3 window side).

    prev, cur : (H, W) float32 normalised images; prev_mask : (H, W) float32;
    p0 : (N, 2) points in ``prev``; p1 : (N, 2) their LK positions in ``cur``.
    Returns refined (N, 2) float32 positions in ``cur``. :func:`_refine_masked`
    is the same computation as a numba kernel.
    """
    offsets, weights, template, gx, gy = _window_samples(prev, prev_mask, p0, window)
    wx, wy = weights * gx, weights * gy
    hess = np.stack([np.stack([(wx * gx).sum(1), (wx * gy).sum(1)], -1),
                     np.stack([(wx * gy).sum(1), (wy * gy).sum(1)], -1)], -2)  # (N, 2, 2)
    # Points without texture in both directions keep OpenCV's estimate.
    ok = np.linalg.det(hess) > 1e-6 * np.trace(hess, axis1=1, axis2=2) ** 2 + 1e-12
    inv = np.linalg.inv(np.where(ok[:, None, None], hess, np.eye(2)))
    p = p1.astype(np.float64).copy()
    active = np.nonzero(ok)[0]  # points still moving by more than 1e-3 px per step
    for _ in range(iterations):
        if not len(active):
            break
        err = _bilinear_patches(cur, p[active], offsets) - template[active]
        b = np.stack([(wx[active] * err).sum(1), (wy[active] * err).sum(1)], -1)
        step = np.einsum("nij,nj->ni", inv[active], b)
        p[active] -= step
        active = active[np.abs(step).max(axis=1) >= 1e-3]
    return p.astype(np.float32)


@numba.njit(cache=True)
def _sample(image: np.ndarray, x: float, y: float) -> float:
    """Bilinear sample of ``image`` (H, W) at (x, y), clamped like :func:`_bilinear`."""
    h, w = image.shape
    x = min(max(x, 0.0), w - 1.001)
    y = min(max(y, 0.0), h - 1.001)
    x0, y0 = int(x), int(y)
    ax, ay = x - x0, y - y0
    return ((1 - ay) * ((1 - ax) * image[y0, x0] + ax * image[y0, x0 + 1])
            + ay * ((1 - ax) * image[y0 + 1, x0] + ax * image[y0 + 1, x0 + 1]))


@numba.njit(cache=True)
def _patch(image, px, py, radius, out):
    """Bilinear samples of ``image`` (H, W) on the (2r+1)² grid around (px, py) into ``out`` (raster order).

    The fractional weights are shared by the whole grid; windows that reach
    the clamped border fall back to :func:`_sample`.
    """
    h, w = image.shape
    side = 2 * radius + 1
    if px - radius >= 0 and py - radius >= 0 and px + radius <= w - 1.001 and py + radius <= h - 1.001:
        x0, y0 = int(px), int(py)
        ax, ay = px - x0, py - y0
        for j in range(side):
            r = y0 + j - radius
            for i in range(side):
                c = x0 + i - radius
                out[j * side + i] = ((1 - ay) * ((1 - ax) * image[r, c] + ax * image[r, c + 1])
                                     + ay * ((1 - ax) * image[r + 1, c] + ax * image[r + 1, c + 1]))
    else:
        for k in range(side * side):
            out[k] = _sample(image, px + (k % side - radius), py + (k // side - radius))


@numba.njit(cache=True)
def _window_gaussian(radius):
    """Gaussian weights (σ = 0.3 window side) over a window's pixels in row-major order."""
    side = 2 * radius + 1
    gauss = np.empty(side * side)
    for k in range(side * side):
        ox, oy = k % side - radius, k // side - radius
        gauss[k] = np.exp(-(ox * ox + oy * oy) / (2.0 * (0.3 * side) ** 2))
    return gauss


@numba.njit(cache=True)
def _refine_masked_kernel(prev, cur, gx_img, gy_img, prev_mask, p0, p1, radius, iterations, out):
    """Numba twin of :func:`_refine_masked_numpy`, one point at a time; writes (N, 2) ``out``."""
    h, w = prev.shape
    side = 2 * radius + 1
    count = side * side
    gauss = _window_gaussian(radius)
    for n in range(p0.shape[0]):
        m, tmpl, gx, gy, now = np.empty(count), np.empty(count), np.empty(count), np.empty(count), np.empty(count)
        px, py = p0[n, 0], p0[n, 1]
        _patch(prev_mask, px, py, radius, m)
        _patch(prev, px, py, radius, tmpl)
        _patch(gx_img, px, py, radius, gx)
        _patch(gy_img, px, py, radius, gy)
        for k in range(count):  # outside the image the mask weight is 0
            x, y = px + (k % side - radius), py + (k // side - radius)
            if not (0.0 <= x <= w - 1 and 0.0 <= y <= h - 1):
                m[k] = 0.0
        hxx = hxy = hyy = 0.0
        wts = np.empty(count)
        for k in range(count):
            wts[k] = m[k] * m[count - 1 - k] * gauss[k]
            hxx += wts[k] * gx[k] * gx[k]
            hxy += wts[k] * gx[k] * gy[k]
            hyy += wts[k] * gy[k] * gy[k]
        qx, qy = p1[n, 0], p1[n, 1]
        det = hxx * hyy - hxy * hxy
        if det > 1e-6 * (hxx + hyy) ** 2 + 1e-12:
            for _ in range(iterations):
                _patch(cur, qx, qy, radius, now)
                bx = by = 0.0
                for k in range(count):
                    e = now[k] - tmpl[k]
                    bx += wts[k] * gx[k] * e
                    by += wts[k] * gy[k] * e
                sx = (hyy * bx - hxy * by) / det
                sy = (hxx * by - hxy * bx) / det
                qx -= sx
                qy -= sy
                if max(abs(sx), abs(sy)) < 1e-3:
                    break
        out[n, 0] = qx
        out[n, 1] = qy


def _refine_masked(prev: np.ndarray, cur: np.ndarray, prev_mask: np.ndarray, p0: np.ndarray, p1: np.ndarray,
                   window: int, iterations: int = 8) -> np.ndarray:
    """Fast path of :func:`_refine_masked_numpy` (same arguments and result)."""
    out = np.empty((len(p0), 2))
    _refine_masked_kernel(prev, cur, cv2.Scharr(prev, cv2.CV_32F, 1, 0) / 32.0,
                          cv2.Scharr(prev, cv2.CV_32F, 0, 1) / 32.0, prev_mask, p0.astype(np.float64),
                          p1.astype(np.float64), window // 2, iterations, out)
    return out.astype(np.float32)


def _align_affine_numpy(ref: np.ndarray, ref_mask: np.ndarray, cur: np.ndarray, p_ref: np.ndarray,
                        p_init: np.ndarray, a_init: np.ndarray, window: int, *, photometric: bool = False,
                        noise: float = 0.0,
                        iterations: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Align each point's window in an anchor frame to the current frame with an affine warp (NumPy reference).

    Chained frame-to-frame tracking accumulates every step's error: under
    rotation LK lags by one or two percent of the motion, which adds up to
    degrees over a turn. Aligning with the window where the track started
    (the template-update strategy of Matthews, Ishikawa & Baker, PAMI 2004)
    leaves a single, bounded error instead. The window turns and shears
    between the two frames, so the warp is affine, ``x ↦ p + A x``, fitted by
    inverse-compositional Gauss–Newton (Baker & Matthews, IJCV 2004) with the
    object-only, point-symmetric weights of :func:`_refine_masked_numpy`.

    ``photometric``: the current window is matched as ``g T + b``, the gain
    and bias solved in closed form at every step and projected out of the
    steepest-descent images (Baker, Gross & Matthews, "Lucas-Kanade 20 years
    on", part 3, 2003), for grey images whose brightness changes as a
    surface turns to the light. (Locally contrast-normalised images, the
    alternative, are not covariant with an affine warp: a foreshortened or
    receding surface is normalised over a different patch of itself, which
    biases the alignment by about 1 % of the motion.)

    ref, cur : (H, W) float32 anchor and current images, normalised or (with
    ``photometric``) lightly blurred grey; ref_mask : (H, W) float32 object
    mask of the anchor frame; p_ref : (N, 2) points in the anchor frame;
    p_init, a_init : (N, 2) and (N, 2, 2) starting position and warp in the
    current frame; noise : with ``photometric``, standard deviation of the
    images' pixel noise.
    Returns positions (N, 2), warps (N, 2, 2), residuals (N,) and gains (N,).
    The residual is the weighted RMS of ``I - T`` (of the normalised images);
    with ``photometric``, that of ``(I - b) / g - T`` less what the noise of
    both images explains (``noise² (1 + 1/g²)`` per pixel in expectation),
    over the RMS contrast of ``T`` (0.1: a 10 % mismatch). It is inf where
    the window has too little texture or (``photometric``) its contrast
    vanished. The gain is 1 without ``photometric``.
    """
    offsets, weights, template, gx, gy = _window_samples(ref, ref_mask, p_ref, window)
    wsum = weights.sum(1)  # (N,)
    # Steepest-descent images for the parameters (D00, D01, D10, D11, d0, d1) of x ↦ (I + D) x + d.
    sd = np.stack([gx * offsets[:, 0], gx * offsets[:, 1], gy * offsets[:, 0], gy * offsets[:, 1], gx, gy], -1)
    contrast = np.ones(len(p_ref))
    if photometric:  # bias and gain (the constant and the template) projected out
        wsum = np.maximum(wsum, 1e-300)
        template = template - (weights * template).sum(1, keepdims=True) / wsum[:, None]
        contrast = (weights * template**2).sum(1)
        sd = sd - (weights[..., None] * sd).sum(1, keepdims=True) / wsum[:, None, None]
        along = (weights[..., None] * template[..., None] * sd).sum(1) / np.maximum(contrast, 1e-300)[:, None]
        sd = sd - template[..., None] * along[:, None, :]
    hess = np.einsum("nk,nki,nkj->nij", weights, sd, sd)  # (N, 6, 6)
    # Texture in both directions is needed for the translation; the shape
    # terms are lightly damped instead (a stripe pattern has no shear).
    move = hess[:, 4:, 4:]
    ok = (np.linalg.det(move) > 1e-6 * np.trace(move, axis1=1, axis2=2) ** 2 + 1e-12) & (contrast > 1e-12)
    hess = hess + (1e-6 * np.trace(hess, axis1=1, axis2=2) + 1e-12)[:, None, None] * np.eye(6)
    inv = np.linalg.inv(np.where(ok[:, None, None], hess, np.eye(6)))
    p, a = p_init.astype(np.float64).copy(), a_init.astype(np.float64).copy()
    residual, gain = np.full(len(p), np.inf), np.ones(len(p))
    active = np.nonzero(ok)[0]
    for _ in range(iterations):
        if not len(active):
            break
        warped = p[active, None, :] + np.einsum("nij,kj->nki", a[active], offsets)  # (n, K, 2)
        img = _bilinear(cur, warped[..., 0], warped[..., 1])
        wts = weights[active]
        if photometric:
            img = img - (wts * img).sum(1, keepdims=True) / wsum[active, None]
            g = (wts * img * template[active]).sum(1) / contrast[active]
            gain[active] = g
            lost = g < _MIN_GAIN  # the window's contrast vanished, or turned negative
            residual[active[lost]] = np.inf
            active, img, wts, g = active[~lost], img[~lost], wts[~lost], g[~lost]
            err = img / g[:, None] - template[active]
            floor = noise * noise * (1.0 + 1.0 / (g * g)) * wsum[active]
            residual[active] = np.sqrt(np.maximum((wts * err**2).sum(1) - floor, 0.0) / contrast[active])
        else:
            err = img - template[active]
            residual[active] = np.sqrt((wts * err**2).sum(1) / wsum[active])
        step = np.einsum("nij,nj->ni", inv[active], np.einsum("nkj,nk->nj", sd[active], wts * err))  # (n, 6)
        inc = np.linalg.inv(np.eye(2) + step[:, :4].reshape(-1, 2, 2))
        a[active] = a[active] @ inc
        p[active] -= np.einsum("nij,nj->ni", a[active], step[:, 4:])
        active = active[(np.abs(step[:, 4:]).max(axis=1) >= 1e-3) | (np.abs(step[:, :4]).max(axis=1) >= 1e-4)]
    return p, a, residual, gain


@numba.njit(cache=True)
def _align_affine_kernel(ref, gx_img, gy_img, ref_mask, cur, p_ref, p_init, a_init, radius, photometric, noise,
                         iterations, out_p, out_a, out_res, out_gain):
    """Numba twin of :func:`_align_affine_numpy`, one point at a time; writes ``out_p, out_a, out_res, out_gain``."""
    h, w = ref.shape
    side = 2 * radius + 1
    count = side * side
    gauss = _window_gaussian(radius)
    for n in range(p_ref.shape[0]):
        m, tmpl, gx, gy = np.empty(count), np.empty(count), np.empty(count), np.empty(count)
        px, py = p_ref[n, 0], p_ref[n, 1]
        _patch(ref_mask, px, py, radius, m)
        _patch(ref, px, py, radius, tmpl)
        _patch(gx_img, px, py, radius, gx)
        _patch(gy_img, px, py, radius, gy)
        for k in range(count):
            x, y = px + (k % side - radius), py + (k // side - radius)
            if not (0.0 <= x <= w - 1 and 0.0 <= y <= h - 1):
                m[k] = 0.0
        wts = np.empty(count)
        sd = np.empty((count, 6))
        wsum = 0.0
        for k in range(count):
            ox, oy = float(k % side - radius), float(k // side - radius)
            wts[k] = m[k] * m[count - 1 - k] * gauss[k]
            wsum += wts[k]
            sd[k, 0], sd[k, 1], sd[k, 2], sd[k, 3], sd[k, 4], sd[k, 5] = (
                gx[k] * ox, gx[k] * oy, gy[k] * ox, gy[k] * oy, gx[k], gy[k])
        contrast = 1.0
        if photometric:  # bias and gain projected out, as in the twin
            wsum = max(wsum, 1e-300)
            tsum = 0.0
            sd_mean = np.zeros(6)
            for k in range(count):
                tsum += wts[k] * tmpl[k]
                for i in range(6):
                    sd_mean[i] += wts[k] * sd[k, i]
            contrast = 0.0
            along = np.zeros(6)
            for k in range(count):
                tmpl[k] -= tsum / wsum
                contrast += wts[k] * tmpl[k] * tmpl[k]
                for i in range(6):
                    sd[k, i] -= sd_mean[i] / wsum
                    along[i] += wts[k] * tmpl[k] * sd[k, i]
            for k in range(count):
                for i in range(6):
                    sd[k, i] -= tmpl[k] * (along[i] / max(contrast, 1e-300))
        hess = np.zeros((6, 6))
        for k in range(count):
            for i in range(6):
                for j in range(i + 1):
                    hess[i, j] += wts[k] * sd[k, i] * sd[k, j]
        for i in range(6):
            for j in range(i):
                hess[j, i] = hess[i, j]
        out_p[n, 0], out_p[n, 1] = p_init[n, 0], p_init[n, 1]
        # Element by element: an array-to-array store compiles numba's shape-error formatting (~7 s).
        out_a[n, 0, 0], out_a[n, 0, 1], out_a[n, 1, 0], out_a[n, 1, 1] = (a_init[n, 0, 0], a_init[n, 0, 1],
                                                                          a_init[n, 1, 0], a_init[n, 1, 1])
        out_res[n], out_gain[n] = np.inf, 1.0
        if (hess[4, 4] * hess[5, 5] - hess[4, 5] ** 2 <= 1e-6 * (hess[4, 4] + hess[5, 5]) ** 2 + 1e-12
                or contrast <= 1e-12):
            continue
        damp = 1e-6 * np.trace(hess) + 1e-12
        for i in range(6):
            hess[i, i] += damp
        chol = cholesky6(hess)
        qx, qy = p_init[n, 0], p_init[n, 1]
        a00, a01, a10, a11 = a_init[n, 0, 0], a_init[n, 0, 1], a_init[n, 1, 0], a_init[n, 1, 1]
        img = np.empty(count)
        for _ in range(iterations):
            for k in range(count):  # pixels of weight 0 count nowhere: not sampled
                ox, oy = float(k % side - radius), float(k // side - radius)
                img[k] = 0.0 if wts[k] == 0.0 else _sample(cur, qx + a00 * ox + a01 * oy, qy + a10 * ox + a11 * oy)
            g = 1.0
            if photometric:
                isum = 0.0
                for k in range(count):
                    isum += wts[k] * img[k]
                cross = 0.0
                for k in range(count):
                    img[k] -= isum / wsum
                    cross += wts[k] * img[k] * tmpl[k]
                g = cross / contrast
                out_gain[n] = g
                if g < _MIN_GAIN:
                    out_res[n] = np.inf
                    break
            b = np.zeros(6)
            sse = used = 0.0
            for k in range(count):
                if wts[k] == 0.0:
                    continue
                e = img[k] / g - tmpl[k] if photometric else img[k] - tmpl[k]
                sse += wts[k] * e * e
                used += wts[k]
                for i in range(6):
                    b[i] += wts[k] * sd[k, i] * e
            if photometric:
                out_res[n] = np.sqrt(max(sse - noise * noise * (1.0 + 1.0 / (g * g)) * wsum, 0.0) / contrast)
            else:
                out_res[n] = np.sqrt(sse / used)
            step = cholesky6_solve(chol, b)
            # (I + D)⁻¹, then A ← A (I + D)⁻¹ and p ← p - A d.
            det = (1.0 + step[0]) * (1.0 + step[3]) - step[1] * step[2]
            i00, i01, i10, i11 = (1.0 + step[3]) / det, -step[1] / det, -step[2] / det, (1.0 + step[0]) / det
            a00, a01, a10, a11 = (a00 * i00 + a01 * i10, a00 * i01 + a01 * i11,
                                  a10 * i00 + a11 * i10, a10 * i01 + a11 * i11)
            qx -= a00 * step[4] + a01 * step[5]
            qy -= a10 * step[4] + a11 * step[5]
            if max(abs(step[4]), abs(step[5])) < 1e-3 and max(abs(step[0]), abs(step[1]), abs(step[2]),
                                                             abs(step[3])) < 1e-4:
                break
        out_p[n, 0], out_p[n, 1] = qx, qy
        out_a[n, 0, 0], out_a[n, 0, 1], out_a[n, 1, 0], out_a[n, 1, 1] = a00, a01, a10, a11


def _align_affine(ref: np.ndarray, ref_mask: np.ndarray, cur: np.ndarray, p_ref: np.ndarray, p_init: np.ndarray,
                  a_init: np.ndarray, window: int, *, photometric: bool = False, noise: float = 0.0,
                  iterations: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fast path of :func:`_align_affine_numpy` (same arguments and results)."""
    n = len(p_ref)
    out_p, out_a, out_res, out_gain = np.empty((n, 2)), np.empty((n, 2, 2)), np.empty(n), np.empty(n)
    _align_affine_kernel(ref, cv2.Scharr(ref, cv2.CV_32F, 1, 0) / 32.0, cv2.Scharr(ref, cv2.CV_32F, 0, 1) / 32.0,
                         ref_mask, cur, p_ref.astype(np.float64), p_init.astype(np.float64),
                         a_init.astype(np.float64), window // 2, bool(photometric), float(noise), iterations,
                         out_p, out_a, out_res, out_gain)
    return out_p, out_a, out_res, out_gain


def track(frames: np.ndarray, masks: np.ndarray, *, spacing: int = 6, window: int = 21, levels: int = 3,
          fb_threshold: float = 1.0, reseed_every: int = 4, min_eigen: float = 2e-4,
          border: int = 4, mask_tolerance: int = 3, refine: bool = True, strict: bool | str = False,
          progress: Callable[[int, int], None] | None = None) -> Tracks:
    """Track a grid of object points through a video with pyramidal Lucas–Kanade.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W, 3), uint8, or VideoFrames
        RGB video frames, read in order (from the start again where
        ``strict="auto"`` starts over).
    masks : ndarray, shape (T, H, W), bool or integer, or PackedMasks
        Object masks per frame (non-zero = object).
    spacing : int
        Seed grid spacing in pixels (one seed per ``spacing`` x ``spacing`` cell).
    window : int
        Lucas–Kanade window side in pixels, at every pyramid level.
    levels : int
        Pyramid levels above full resolution (OpenCV ``maxLevel``); each level
        doubles the largest motion LK can follow (about ``window/2 * 2^levels`` px).
    fb_threshold : float
        Forward-backward consistency threshold in pixels, per frame step.
    reseed_every : int
        Add seeds every this many frames where the mask has no live track
        within ``spacing`` pixels.
    min_eigen : float
        Minimum Shi–Tomasi texture (``cv2.cornerMinEigenVal``, 5x5 block, in
        OpenCV's normalised units, on the raw greyscale frame) for a seed.
        2e-4 is about ten times what sensor noise of 2 grey levels gives on a
        flat surface, and below the median of a natural image.
    border : int
        Seeds keep this many pixels away from the mask boundary, so that the
        silhouette's own contrast does not count as texture (the 5x5 texture
        block with its 3x3 derivative reaches 3 pixels).
    mask_tolerance : int
        A track dies when it leaves the mask dilated by this many pixels
        (masks are rarely exact at the boundary).
    refine : bool
        Refine each LK step within the mask and align against the track's
        anchor frame (no drift; the default). Off: plain pyramidal LK with
        the forward-backward check, several times faster, for sparse
        background tracks whose drift matters less.
    strict : bool or "auto"
        True: a track ends where its window stops matching its anchor window
        closely (10 % of its contrast, grey levels under a gain and a bias)
        and a fresh track starts at the same place, instead of the track being
        anchored again there. Every track then follows one surface point, no
        step's error is carried on, and the poses of clean footage come out
        several times closer; on compressed or blurred clips the tracks are
        cut into pieces a frame or two long, and the poses drift.
        ``"auto"``: strict while at least 70 % of the windows aligned so far
        match their anchor that closely (checked from the 8th frame step on);
        once fewer do, the tracking starts over anchored
        (``docs/benchmarks/extract.md``).
    progress : callable(done, total), optional
        Called after each frame step with ``total = T - 1``.

    Returns
    -------
    Tracks
        With ``M`` tracks; ``uv`` NaN where a track is not (yet, or any more)
        alive; ``strict`` says which way they were made.
    """
    frames, masks = _check_video(frames, masks)
    for name, value, low in (("spacing", spacing, 1), ("window", window, 3), ("levels", levels, 0),
                             ("reseed_every", reseed_every, 1), ("border", border, 0),
                             ("mask_tolerance", mask_tolerance, 0)):
        if isinstance(value, bool) or int(value) != value or value < low:
            raise InputError(f"track: {name} must be an integer >= {low}, got {value!r}")
    if not (np.isfinite(fb_threshold) and fb_threshold > 0):
        raise InputError(f"track: fb_threshold must be a positive number, got {fb_threshold!r}")
    if not (np.isfinite(min_eigen) and min_eigen >= 0):
        raise InputError(f"track: min_eigen must be a non-negative number, got {min_eigen!r}")
    if strict not in (True, False, "auto"):
        raise InputError(f"track: strict must be True, False or 'auto', got {strict!r}")
    settings = dict(spacing=int(spacing), window=int(window), levels=int(levels), fb_threshold=fb_threshold,
                    reseed_every=int(reseed_every), min_eigen=min_eigen, border=int(border),
                    mask_tolerance=int(mask_tolerance), refine=refine)
    if strict != "auto":
        return _track_pass(frames, masks, strict=bool(strict), probe=False, progress=progress, **settings)
    reached = 0

    def probing(done: int, total: int) -> None:
        nonlocal reached
        reached = done
        if progress is not None:
            progress(done, total)

    probed = _track_pass(frames, masks, strict=True, probe=True, progress=probing, **settings)
    if probed.strict:
        return probed

    def resumed(done: int, total: int) -> None:  # the bar waits while the frames probed are tracked again
        if progress is not None and done > reached:
            progress(done, total)

    again = _track_pass(frames, masks, strict=False, probe=False, progress=resumed, **settings)
    return dataclasses.replace(again, anchor_match=probed.anchor_match)


def _track_pass(frames: np.ndarray | VideoFrames, masks: np.ndarray | PackedMasks, *, spacing: int, window: int,
                levels: int, fb_threshold: float, reseed_every: int, min_eigen: float, border: int,
                mask_tolerance: int, refine: bool, strict: bool, probe: bool,
                progress: Callable[[int, int], None] | None) -> Tracks:
    """One tracking pass over validated inputs (:func:`track`'s arguments). With ``probe``, a strict pass gives
    up at the first frame step from _PROBE_FRAMES on where fewer than _STRICT_SHARE of the windows aligned so far
    matched their anchor, and returns the tracks so far with ``strict=False`` and that share."""
    num_frames, h, w = masks.shape
    lk = dict(winSize=(window, window), maxLevel=levels, criteria=_LK_CRITERIA)
    tolerance = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * mask_tolerance + 1,) * 2)
    inset = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * border + 1,) * 2)

    def load(t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Grey image (seeding), normalised image (refinement), blurred grey image (LK), float mask of frame t,
        and the image its windows are aligned on: the normalised one, or (strict) the lightly blurred grey one."""
        grey = cv2.cvtColor(frames[t], cv2.COLOR_RGB2GRAY)
        blurred = cv2.GaussianBlur(grey, (0, 0), _BLUR_SIGMA)
        normalised = _normalise(grey)
        aligned = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), _ALIGN_BLUR) if strict else normalised
        return grey, normalised, blurred, masks[t].astype(np.float32), aligned

    def seeds(t: int, grey: np.ndarray, live: np.ndarray) -> np.ndarray:
        allowed = cv2.erode(masks[t].astype(np.uint8), inset).astype(bool)
        if len(live):
            allowed &= _free_of_tracks(live, (h, w), spacing)
        return _grid_seeds(_texture(grey), allowed, spacing, min_eigen)

    grey, prev, prev_grey, prev_mask, aligned = load(0)
    noise = _aligned_noise(grey) if strict else 0.0  # what the strict residual discounts
    pts = seeds(0, grey, np.zeros((0, 2), np.float32))  # (N, 2) live positions
    ids = np.arange(len(pts))  # (N,) their track ids
    anchor = np.zeros(len(pts), np.int64)  # (N,) frame each live track is aligned against
    anchor_pts = pts.astype(np.float64)  # (N, 2) its position there
    warp = np.tile(np.eye(2), (len(pts), 1, 1))  # (N, 2, 2) affine from that frame's window to the current one
    # Aligned image and mask (bool: a quarter of float32) of the anchor frames in use, when refining.
    images = {0: (aligned, masks[0])} if refine else {}
    limit = _STRICT_RESIDUAL if strict else _ANCHOR_RESIDUAL
    starts = [np.zeros(len(pts), np.int64)]
    continued = [np.full(len(pts), -1, np.int64)]  # per batch of new ids: the tracks they carry on from
    aligned_count = matched_count = 0  # window alignments, and those that matched their anchor
    share = float("nan")
    history = [(ids, pts)]  # per frame: (ids, positions) of the visible tracks
    for t in range(1, num_frames):
        grey, cur, cur_grey, cur_mask, aligned = load(t)
        if len(pts):
            fwd, st_f, _ = cv2.calcOpticalFlowPyrLK(prev_grey, cur_grey, pts[:, None], None, **lk)
            fwd = _refine_masked(prev, cur, prev_mask, pts, fwd[:, 0], window) if refine else fwd[:, 0]
            matched = np.ones(len(pts), bool)
            for a in np.unique(anchor) if refine else ():
                sel = np.nonzero(anchor == a)[0]
                ref, ref_mask = images[a]
                p, aff, res, gain = _align_affine(ref, ref_mask.astype(np.float32), aligned, anchor_pts[sel],
                                                  fwd[sel], warp[sel], window, photometric=strict, noise=noise)
                det = np.linalg.det(aff)
                good = ((res < limit) & (gain < 1.0 / _MIN_GAIN) & (det > 0.25) & (det < 4.0)
                        & (np.linalg.norm(p - fwd[sel], axis=1) < _ANCHOR_SHIFT))
                fwd[sel[good]], warp[sel[good]] = p[good], aff[good]
                matched[sel] = good
            aligned_count, matched_count = aligned_count + len(pts), matched_count + int(matched.sum())
            # The window changed too much since its anchor: the track is anchored again here or, strict, ends and
            # a fresh one starts here.
            anchor[~matched], anchor_pts[~matched], warp[~matched] = t, fwd[~matched], np.eye(2)
            back, st_b, _ = cv2.calcOpticalFlowPyrLK(cur_grey, prev_grey, fwd[:, None], None, **lk)
            back = _refine_masked(cur, prev, cur_mask, fwd, back[:, 0], window) if refine else back[:, 0]
            keep = (st_f[:, 0] == 1) & (st_b[:, 0] == 1)
            keep &= np.linalg.norm(back - pts, axis=1) <= fb_threshold
            keep &= _inside(fwd, cv2.dilate(masks[t].astype(np.uint8), tolerance).astype(bool))
            ids, pts = ids[keep], fwd[keep].astype(np.float32)
            anchor, anchor_pts, warp = anchor[keep], anchor_pts[keep], warp[keep]
            if strict and refine:
                ended = ~matched[keep]
                first = sum(len(s) for s in starts)
                continued.append(ids[ended])
                ids[ended] = np.arange(first, first + ended.sum())
                starts.append(np.full(int(ended.sum()), t, np.int64))
        share = matched_count / aligned_count if aligned_count else float("nan")
        if probe and t >= min(_PROBE_FRAMES, num_frames - 1) and not share >= _STRICT_SHARE:
            return Tracks(*_assemble(history, starts, num_frames), strict=False, anchor_match=share,
                          continues=np.concatenate(continued))
        if t % reseed_every == 0:
            new = seeds(t, grey, pts)
            first = sum(len(s) for s in starts)
            ids = np.concatenate([ids, np.arange(first, first + len(new))])
            pts = np.concatenate([pts, new])
            anchor = np.concatenate([anchor, np.full(len(new), t)])
            anchor_pts = np.concatenate([anchor_pts, new])
            warp = np.concatenate([warp, np.tile(np.eye(2), (len(new), 1, 1))])
            starts.append(np.full(len(new), t, np.int64))
            continued.append(np.full(len(new), -1, np.int64))
        if refine:
            images[t] = (aligned, masks[t])
            images = {a: images[a] for a in np.unique(anchor)}
        history.append((ids, pts.astype(np.float32)))
        prev, prev_grey, prev_mask = cur, cur_grey, cur_mask
        if progress is not None:
            progress(t, num_frames - 1)

    return Tracks(*_assemble(history, starts, num_frames), strict=strict,
                  anchor_match=share if strict else float("nan"), continues=np.concatenate(continued))


def _assemble(history: list[tuple[np.ndarray, np.ndarray]], starts: list[np.ndarray],
              num_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, M, 2) positions, (T, M) visibility and (M,) start frames from the per-frame (ids, positions) of the
    visible tracks and the start frames of each batch of new ids."""
    start = np.concatenate(starts)
    uv = np.full((num_frames, len(start), 2), np.nan, np.float32)
    visible = np.zeros((num_frames, len(start)), bool)
    for t, (i, p) in enumerate(history):
        uv[t, i] = p
        visible[t, i] = True
    return uv, visible, start
