"""The paper's path when per-frame depth maps are given (``--depth DIR``).

Motion Marionette (Sec. 3) lifts each 2D track with its depth (Eq. 1,
``X = d K^-1 [u, v, 1]``) and fits every step's rigid transform with
Umeyama's method (Eq. 3-4). We do the same, with two changes for accuracy:

- each frame is fitted against a reference, not against the previous frame:
  a track's reference point is where it sat at frame 0, in frame-0
  coordinates; a track seeded later (re-seeded where the object turned new
  surface into view) gets its reference through the pose of the frame
  where it first appears. Tracks from frame 0 thus tie every frame to frame
  0 directly, and re-seeded ones bridge the frames no frame-0 track reaches,
  so errors do not add up over steps;
- the fit is robust (RANSAC on three-point samples, then least squares on
  the inliers): depth at occlusion edges mixes surfaces, and tracks there
  are dropped where the depth jumps between neighbouring pixels.

Poses are in the camera of each frame (remove camera motion afterwards) and
in the depth maps' unit.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..geometry import make_transform, transform_points, umeyama
from ..io.video import _natural_key, _scaled_size
from .tracks import Tracks

__all__ = ["DEPTH_SUFFIXES", "DepthMaps", "read_depths", "read_depth_map", "poses_from_depth"]

#: Depth map files: 16-bit PNG in millimetres, NumPy float maps.
DEPTH_SUFFIXES = (".png", ".npy", ".npz")
#: Inliers of the final fit lie within this many times the median residual
#: (3 sigma of a 3D Gaussian, whose residual norms have median ~1.5 sigma).
_SPREAD = 2.0


def _load_depth(file: Path) -> np.ndarray:
    """One depth map (H, W) float32: metres from a 16-bit PNG (0 → NaN), raw values from .npy/.npz."""
    suffix = file.suffix.lower()
    if suffix == ".png":
        image = cv2.imdecode(np.fromfile(file, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError(f"cannot read depth map {file} (corrupt or not a PNG file)")
        if image.dtype != np.uint16 or image.ndim != 2:
            raise InputError(f"depth map {file.name} must be a single-channel 16-bit PNG (millimetres), "
                             f"got {image.dtype} with {1 if image.ndim == 2 else image.shape[2]} channels")
        return np.where(image > 0, image.astype(np.float32) / 1000.0, np.nan)
    try:
        data = np.load(file, allow_pickle=False)
        if isinstance(data, np.lib.npyio.NpzFile):
            with data:
                keys = list(data.keys())
                if "depth" not in keys and len(keys) != 1:
                    raise InputError(f"depth map {file.name} must hold one array or one named 'depth', got {keys}")
                data = data["depth" if "depth" in keys else keys[0]]
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"cannot read depth map {file} ({exc})") from None
    if data.ndim != 2 or not (np.issubdtype(data.dtype, np.floating) or np.issubdtype(data.dtype, np.integer)):
        raise InputError(f"depth map {file.name} must be a 2D numeric array, got {data.dtype} {data.shape}")
    return data.astype(np.float32)


class DepthMaps:
    """Depth maps read from their files on demand: a read-only (T, H, W) float32 sequence.

    ``depths[t]`` reads and converts map t as :func:`read_depths` does (which
    checked every map once); ``np.asarray(depths)`` reads them all.
    """

    dtype = np.dtype(np.float32)
    ndim = 3

    def __init__(self, files: list[Path], size: tuple[int, int]) -> None:
        self._files, self._size = files, size
        self.shape = (len(files), size[1], size[0])

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, t: int) -> np.ndarray:
        return read_depth_map(self._files[t], self._size)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        depths = np.stack([self[t] for t in range(len(self))])
        return depths if dtype is None else depths.astype(dtype)


def read_depth_map(file: str | Path, size: tuple[int, int]) -> np.ndarray:
    """One checked depth map (H, W) float32 of ``size`` (W, H), NaN where unknown.

    Formats and rules as for :func:`read_depths`; a map at the original
    resolution of downscaled frames is resized (nearest neighbour).
    """
    file = Path(file)
    if not file.is_file():
        raise InputError(f"depth map {file} does not exist")
    width, height = size
    depth = _load_depth(file)
    if np.isinf(depth).any():
        raise InputError(f"depth map {file.name} contains infinite values")
    h0, w0 = depth.shape
    if (w0, h0) != (width, height):
        if _scaled_size(w0, h0, max(width, height)) != (width, height):
            raise InputError(f"depth map {file.name} is {w0}x{h0} but the frames are {width}x{height}")
        depth = cv2.resize(depth, (width, height), interpolation=cv2.INTER_NEAREST)
    with np.errstate(invalid="ignore"):
        depth = np.where(depth > 0, depth, np.nan).astype(np.float32, copy=False)
    if np.isnan(depth).all():
        raise InputError(f"depth map {file.name} has no valid (positive) depth")
    return depth


def read_depths(folder: str | Path, *, count: int, size: tuple[int, int],
                indices: list[int] | None = None, lazy: bool = False) -> np.ndarray | DepthMaps:
    """Read ``count`` per-frame depth maps of ``size`` (W, H) → (T, H, W) float32.

    One file per frame in natural name order: 16-bit single-channel PNGs in
    millimetres (returned in metres; 0 = unknown), or ``.npy`` / ``.npz``
    float maps in any unit (an ``.npz`` holds one array, or one named
    ``depth``). Depth is the z coordinate in the camera, not the distance
    along the ray. Unknown depth (0, negative or NaN) comes back as NaN;
    infinite values are an error. Maps at the original resolution of a
    downscaled video are resized (nearest neighbour, so that depths of
    different surfaces never mix). ``indices`` (the video's frame numbers
    when read with a frame range) selects maps from a folder holding one per
    source frame, as :func:`~marionette.io.video.read_masks` does. ``lazy``:
    check every map, keep none, and return :class:`DepthMaps` that read them
    again when asked.

    Raises
    ------
    InputError
        Missing folder, wrong count or size, unreadable files, infinite
        values, or a map without any valid depth.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"depth folder {folder} does not exist" if not folder.exists()
                         else f"depth must be a folder of depth maps, got the file {folder}")
    files = sorted((f for f in folder.iterdir()
                    if f.suffix.lower() in DEPTH_SUFFIXES and not f.name.startswith(".") and f.is_file()),
                   key=lambda f: (_natural_key(f.name), f.name))
    if indices is not None and len(files) != count and len(files) > max(indices):
        files = [files[i] for i in indices]
    if len(files) != count:
        raise InputError(f"{folder} holds {len(files)} depth maps ({', '.join(DEPTH_SUFFIXES)}) "
                         f"but the video has {count} frames")
    if lazy:
        for file in files:
            read_depth_map(file, size)
        return DepthMaps(files, size)
    depths = np.empty((count, size[1], size[0]), np.float32)
    for t, file in enumerate(files):
        depths[t] = read_depth_map(file, size)
    return depths


def _sample_depth(depth: np.ndarray, uv: np.ndarray, edge: float) -> np.ndarray:
    """Depth (N,) at sub-pixel positions (N, 2); NaN where unknown or across a depth edge.

    Interpolates inverse depth bilinearly (it is linear in the image over a
    plane). A sample needs its four neighbouring pixels valid and within a
    factor ``1 + edge`` of each other: a larger jump means an occlusion edge.
    """
    h, w = depth.shape
    x0, y0 = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    inside = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0 = np.where(inside, x0, 0), np.where(inside, y0, 0)
    near = np.stack([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]]).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = inside & np.all(np.isfinite(near) & (near > 0), axis=0)
        ok &= near.max(axis=0) <= (1 + edge) * near.min(axis=0)
        ax, ay = uv[:, 0] - x0, uv[:, 1] - y0
        inverse = ((1 - ay) * ((1 - ax) / near[0] + ax / near[1]) + ay * ((1 - ax) / near[2] + ax / near[3]))
        return np.where(ok, 1.0 / inverse, np.nan)


def _ransac_rigid(src: np.ndarray, dst: np.ndarray, threshold: float, iterations: int,
                  rng: np.random.Generator) -> np.ndarray:
    """Robust rigid ``dst ≈ R src + t`` (4, 4) for points (N, 3): RANSAC on triples, then Umeyama on inliers.

    ``threshold`` bounds the RANSAC consensus; the final inliers are also
    within ``_SPREAD`` times the median residual of the consensus fit.
    """
    best, best_count = np.ones(len(src), bool), -1
    for _ in range(iterations):
        sample = rng.choice(len(src), 3, replace=False)
        r, t, _ = umeyama(src[sample], dst[sample])
        inliers = np.linalg.norm(src @ r.T + t - dst, axis=1) < threshold
        if inliers.sum() > best_count:
            best, best_count = inliers, inliers.sum()
    inliers = best
    for _ in range(4):  # refit on the consensus, then keep what fits within a robust spread of it
        r, t, _ = umeyama(src[inliers], dst[inliers])
        residual = np.linalg.norm(src @ r.T + t - dst, axis=1)
        refreshed = residual < min(threshold, _SPREAD * np.median(residual[inliers]))
        if refreshed.sum() < 3:
            break
        inliers = refreshed
    return make_transform(r, t)


def poses_from_depth(tracks: Tracks, depths: np.ndarray, K: np.ndarray, *, threshold: float = 0.01,
                     edge: float = 0.05, iterations: int = 100, min_points: int = 6, seed: int = 0) -> np.ndarray:
    """Object poses from 2D tracks lifted with per-frame depth (paper Eq. 1, 3-4).

    Parameters
    ----------
    tracks : Tracks
        Object tracks over T frames (one rigid part).
    depths : (T, H, W) float, or DepthMaps
        z-depth per pixel; non-finite or non-positive = unknown. Read once
        per frame, in order.
    K : (3, 3) float64
        Camera intrinsics.
    threshold : float
        RANSAC inlier distance, as a fraction of the tracks' median depth in
        the frame (0.01: 4 cm at 4 m).
    edge : float
        Relative depth jump between neighbouring pixels taken as an
        occlusion edge (tracks there are not lifted).
    iterations : int
        RANSAC samples per frame.
    min_points : int
        Fewest lifted tracks to fit a frame; with fewer, the previous
        frame's pose is kept (with a warning).
    seed : int
        RANSAC random seed (results are deterministic).

    Returns
    -------
    poses : (T, 4, 4) float64
        Frame-0 points to frame t, in each frame's camera coordinates and
        the depth maps' unit; ``poses[0]`` is identity.
    """
    depths = depths if isinstance(depths, DepthMaps) else np.asarray(depths)
    k = np.asarray(K, dtype=np.float64)
    if depths.ndim != 3 or len(depths) != tracks.num_frames:
        raise InputError(f"depths must be (T, H, W) with T = {tracks.num_frames} frames, got {depths.shape}")
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise InputError(f"K must be a 3x3 intrinsics matrix with positive focal lengths, got {k.tolist()}")
    num_frames, num_tracks = tracks.visible.shape

    def lift(t: int) -> np.ndarray:
        """(M, 3) tracks of frame t lifted with its depth, NaN where unknown."""
        points = np.full((num_tracks, 3), np.nan)
        vis = np.nonzero(tracks.visible[t])[0]
        uv = tracks.uv[t, vis].astype(np.float64)
        rays = np.concatenate([uv, np.ones((len(vis), 1))], axis=1) @ np.linalg.inv(k).T
        points[vis] = _sample_depth(depths[t], uv, edge)[:, None] * rays  # Eq. 1: X = d K^-1 [u, v, 1]
        return points

    reference = lift(0)  # (M, 3) each track's point at frame 0, in frame-0 coordinates
    poses = np.tile(np.eye(4), (num_frames, 1, 1))
    rng = np.random.default_rng(seed)
    held = []
    for t in range(1, num_frames):
        points = lift(t)
        lifted = np.isfinite(points[:, 0])
        usable = lifted & np.isfinite(reference[:, 0])
        if usable.sum() >= max(min_points, 3):
            scale = threshold * np.median(points[usable, 2])
            poses[t] = _ransac_rigid(reference[usable], points[usable], scale, iterations, rng)
        else:
            poses[t] = poses[t - 1]
            held.append(t)
        fresh = lifted & ~np.isfinite(reference[:, 0])
        reference[fresh] = transform_points(np.linalg.inv(poses[t]), points[fresh])
    if held:
        warnings.warn(f"too few tracks with depth at {len(held)} frames (first {held[0]}): "
                      "their pose repeats the previous frame's", stacklevel=2)
    return poses
