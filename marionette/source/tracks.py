"""Dense 2D point tracks over a masked object (pyramidal Lucas–Kanade).

Stage 1 of Motion Marionette (Sec. 3, Eq. 1) needs long-range 2D
trajectories ``u^k_t`` of object points. The paper uses learned trackers
(BootsTAP, CoTracker); we use the classical pyramidal Lucas–Kanade tracker
(Bouguet, "Pyramidal implementation of the affine Lucas Kanade feature
tracker", 2001; ``cv2.calcOpticalFlowPyrLK``), frame to frame, with

- seeds on a grid with ``spacing`` pixels inside the object mask, each at the
  most textured pixel of its grid cell (Shi–Tomasi minimum eigenvalue,
  "Good features to track", CVPR 1994), skipping flat cells;
- a forward-backward check (Kalal et al., "Forward-backward error", ICPR
  2010): a point tracked to the next frame and back must land within
  ``fb_threshold`` pixels of where it started;
- termination when a point leaves the image or the (slightly dilated) mask;
- re-seeding every ``reseed_every`` frames in mask regions with no live track
  nearby, so that surface revealed by a turning object gets tracks too. Such
  tracks start later; ``Tracks.start`` records where.

Pixel convention: (u, v) with (0, 0) at the centre of the top-left pixel
(DESIGN.md), which is also OpenCV's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["Tracks", "track"]

# LK stops after 30 iterations or a step below 0.01 px; tighter than OpenCV's
# default (0.03 px) because pose accuracy hinges on sub-pixel tracks.
_LK_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
# Block size of the Shi–Tomasi texture measure used to place and filter seeds.
_TEXTURE_BLOCK = 5


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
    """

    uv: np.ndarray
    visible: np.ndarray
    start: np.ndarray

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

    @property
    def num_frames(self) -> int:
        return self.uv.shape[0]

    @property
    def num_tracks(self) -> int:
        return self.uv.shape[1]


def _check_video(frames: np.ndarray, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate frames (T, H, W, 3) uint8 and masks (T, H, W); masks → bool (non-zero = object)."""
    if not isinstance(frames, np.ndarray) or frames.ndim != 4 or frames.shape[3] != 3:
        raise InputError(f"frames must be an array (T, H, W, 3), got shape {np.shape(frames)}")
    if frames.dtype != np.uint8:
        raise InputError(f"frames must be uint8, got {frames.dtype}")
    if frames.shape[0] < 1 or min(frames.shape[1:3]) < 8:
        raise InputError(f"frames must hold at least one frame of at least 8x8 pixels, got shape {frames.shape}")
    if not isinstance(masks, np.ndarray) or masks.shape != frames.shape[:3]:
        raise InputError(f"masks must be an array {frames.shape[:3]} matching frames, got shape {np.shape(masks)}")
    if masks.dtype != bool and not np.issubdtype(masks.dtype, np.integer):
        raise InputError(f"masks must be bool or integer (non-zero = object), got {masks.dtype}")
    masks = masks.astype(bool, copy=False)
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


import os
NORM = os.environ.get("NORM", "1") == "1"
SIG = float(os.environ.get("SIG", "6"))
EPS = float(os.environ.get("EPS", "4"))
BLUR = float(os.environ.get("BLUR", "0"))
def _normalise(g):
    f = g.astype(np.float32)
    mean = cv2.GaussianBlur(f, (0, 0), SIG)
    d = f - mean
    std = np.sqrt(cv2.GaussianBlur(d * d, (0, 0), SIG))
    return np.clip(128 + 48 * d / (std + EPS), 0, 255).astype(np.uint8)


MASKED = os.environ.get("MASKED", "1") == "1"
GSIG = float(os.environ.get("GSIG", "0.3"))


def _masked_refine(prev, cur, weight_img, p0, p1, window, iterations=10):
    """Translation LK at full resolution with template weights from a mask."""
    r = window // 2
    oy, ox = np.mgrid[-r:r + 1, -r:r + 1]
    off = np.stack([ox.ravel(), oy.ravel()], 1).astype(np.float32)  # (K, 2)
    g = np.exp(-(off ** 2).sum(1) / (2 * (GSIG * window) ** 2)) if GSIG > 0 else np.ones(len(off))
    prev_f = prev.astype(np.float32); cur_f = cur.astype(np.float32)
    gx_img = cv2.Scharr(prev_f, cv2.CV_32F, 1, 0) / 32.0
    gy_img = cv2.Scharr(prev_f, cv2.CV_32F, 0, 1) / 32.0
    def samp(img, pts):
        mx = (pts[:, None, 0] + off[None, :, 0]).astype(np.float32)
        my = (pts[:, None, 1] + off[None, :, 1]).astype(np.float32)
        return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    tmpl = samp(prev_f, p0); gx = samp(gx_img, p0); gy = samp(gy_img, p0)
    w = samp(weight_img, p0) * g[None]
    h = np.stack([np.stack([(w * gx * gx).sum(1), (w * gx * gy).sum(1)], -1),
                  np.stack([(w * gx * gy).sum(1), (w * gy * gy).sum(1)], -1)], -2)
    det = h[:, 0, 0] * h[:, 1, 1] - h[:, 0, 1] ** 2
    ok = det > 1e-6 * np.maximum((h[:, 0, 0] + h[:, 1, 1]) ** 2, 1e-12)
    hinv = np.linalg.inv(np.where(ok[:, None, None], h, np.eye(2)))
    p = p1.astype(np.float64).copy()
    for _ in range(iterations):
        e = samp(cur_f, p.astype(np.float32)) - tmpl
        b = np.stack([(w * e * gx).sum(1), (w * e * gy).sum(1)], -1)
        d = np.einsum("nij,nj->ni", hinv, b)
        p[ok] -= d[ok]
        if np.abs(d[ok]).max(initial=0) < 1e-3:
            break
    return p.astype(np.float32)


def _anchor(ids, pts, t, every, tol, history, starts, grey, cur, win):
    key = ((t - 1) // every) * every
    anchor = np.maximum(starts, key)
    out = pts.copy()
    for a in np.unique(anchor):
        sel = np.nonzero(anchor == a)[0]
        hid, hpts = history[a]
        pos = np.searchsorted(hid, ids[sel])
        ref = hpts[pos]
        cor, st, _ = cv2.calcOpticalFlowPyrLK(grey(a), cur, ref[:, None], pts[sel][:, None].copy(), winSize=win,
                                              maxLevel=1, criteria=_LK_CRITERIA, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        cor = cor[:, 0]
        ok = (st[:, 0] == 1) & (np.linalg.norm(cor - pts[sel], axis=1) <= tol)
        out[sel[ok]] = cor[ok]
    return out


def track(frames: np.ndarray, masks: np.ndarray, *, spacing: int = 6, window: int = 21, levels: int = 3,
          fb_threshold: float = 1.0, reseed_every: int = 4, min_eigen: float = 2e-4,
          border: int = 2, mask_tolerance: int = 3, anchor_every: int = 8, anchor_tolerance: float = 1.0,
          progress: Callable[[int, int], None] | None = None) -> Tracks:
    """Track a grid of object points through a video with pyramidal Lucas–Kanade.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W, 3), uint8
        RGB video frames.
    masks : ndarray, shape (T, H, W), bool or integer
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
        OpenCV's normalised units) for a seed. 2e-4 is about ten times what
        sensor noise of 2 grey levels produces on a flat surface, and lies
        below the median of a natural image.
    border : int
        Seeds keep this many pixels away from the mask boundary, where the LK
        window sees mostly background.
    mask_tolerance : int
        A track dies when it leaves the mask dilated by this many pixels
        (masks are rarely exact at the boundary).
    progress : callable(done, total), optional
        Called after each frame step with ``total = T - 1``.

    Returns
    -------
    Tracks
        With ``M`` tracks; ``uv`` NaN where a track is not (yet, or any more) alive.
    """
    frames, masks = _check_video(frames, masks)
    for name, value, low in (("spacing", spacing, 1), ("window", window, 3), ("levels", levels, 0),
                             ("reseed_every", reseed_every, 1), ("border", border, 0),
                             ("mask_tolerance", mask_tolerance, 0)):
        if isinstance(value, bool) or int(value) != value or value < low:
            raise InputError(f"track: {name} must be an integer >= {low}, got {value!r}")
    if not (np.isfinite(fb_threshold) and fb_threshold > 0):
        raise InputError(f"track: fb_threshold must be a positive number, got {fb_threshold!r}")
    num_frames, h, w = masks.shape
    win = (int(window), int(window))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * mask_tolerance + 1,) * 2)
    seed_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * border + 1,) * 2)

    def seed_region(t: int) -> np.ndarray:
        return cv2.erode(masks[t].astype(np.uint8), seed_kernel).astype(bool)

    def grey(t: int) -> np.ndarray:
        g = cv2.cvtColor(frames[t], cv2.COLOR_RGB2GRAY)
        if BLUR > 0:
            g = cv2.GaussianBlur(g, (0, 0), BLUR)
        return _normalise(g) if NORM else g

    # Live state: track ids and their positions at the current frame.
    prev = grey(0)
    pts = _grid_seeds(_texture(prev), seed_region(0), spacing, min_eigen)
    ids = np.arange(len(pts))
    starts = [np.zeros(len(pts), np.int64)]
    history = [(ids, pts)]  # per frame: (ids, positions) of visible tracks
    lk = dict(winSize=win, maxLevel=levels, criteria=_LK_CRITERIA)

    def starts_of(i):
        return np.concatenate(starts)[i]
    for t in range(1, num_frames):
        cur = grey(t)
        if len(pts):
            fwd, st_f, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts[:, None], None, **lk)
            back, st_b, _ = cv2.calcOpticalFlowPyrLK(cur, prev, fwd, None, **lk)
            fwd, back = fwd[:, 0], back[:, 0]
            if MASKED:
                wprev = masks[t - 1].astype(np.float32)
                wcur = masks[t].astype(np.float32)
                fwd = _masked_refine(prev, cur, wprev, pts, fwd, window)
                back = _masked_refine(cur, prev, wcur, fwd, back, window)
            keep = (st_f[:, 0] == 1) & (st_b[:, 0] == 1)
            keep &= np.linalg.norm(back - pts, axis=1) <= fb_threshold
            keep &= _inside(fwd, cv2.dilate(masks[t].astype(np.uint8), kernel).astype(bool))
            ids, pts = ids[keep], fwd[keep]
            if anchor_every and len(pts):
                pts = _anchor(ids, pts, t, anchor_every, anchor_tolerance, history, starts_of(ids), grey, cur, win)
        if t % reseed_every == 0:
            allowed = seed_region(t) & _free_of_tracks(pts, (h, w), spacing)
            new = _grid_seeds(_texture(cur), allowed, spacing, min_eigen)
            next_id = sum(len(s) for s in starts)
            ids = np.concatenate([ids, np.arange(next_id, next_id + len(new))])
            pts = np.concatenate([pts, new])
            starts.append(np.full(len(new), t, np.int64))
        history.append((ids, pts))
        prev = cur
        if progress is not None:
            progress(t, num_frames - 1)

    start = np.concatenate(starts)
    uv = np.full((num_frames, len(start), 2), np.nan, np.float32)
    visible = np.zeros((num_frames, len(start)), bool)
    for t, (i, p) in enumerate(history):
        uv[t, i] = p
        visible[t, i] = True
    return Tracks(uv=uv, visible=visible, start=start)
