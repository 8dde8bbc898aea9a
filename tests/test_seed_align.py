"""Tracks re-aligned to their seed windows (marionette.source.seed_align), on a texture moved by known amounts."""

from __future__ import annotations

import cv2
import numpy as np

from marionette.source.seed_align import realign_to_seeds
from marionette.source.tracks import Tracks

FRAMES, SIZE = 12, 96


def _moving_texture(seed: int = 0):
    """Frames (T, H, W, 3) of a smooth random texture shifted by (0.4 t, 0.25 t) px, and that shift (T, 2)."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (SIZE, SIZE)).astype(np.float32), (0, 0), 2.0)
    texture = cv2.normalize(texture, None, 20, 235, cv2.NORM_MINMAX)
    shifts = np.stack([0.4 * np.arange(FRAMES), 0.25 * np.arange(FRAMES)], axis=1)
    frames = [cv2.warpAffine(texture, np.float32([[1, 0, dx], [0, 1, dy]]), (SIZE, SIZE), flags=cv2.INTER_CUBIC,
                             borderMode=cv2.BORDER_REFLECT) for dx, dy in shifts]
    frames = np.stack([np.repeat(np.clip(f, 0, 255).astype(np.uint8)[..., None], 3, axis=2) for f in frames])
    return frames, shifts


def _drifting_tracks(shifts: np.ndarray, drift: float) -> tuple[Tracks, np.ndarray]:
    """Tracks on a grid seeded at frame 0 that lag the true motion by ``drift`` px more each frame, and the true
    positions (T, M, 2)."""
    grid = np.stack(np.meshgrid(np.arange(30, 70, 8.0), np.arange(30, 70, 8.0)), axis=-1).reshape(-1, 2)
    truth = grid[None] + shifts[:, None]
    lag = drift * np.arange(FRAMES)[:, None, None] * np.array([1.0, 0.5])
    visible = np.ones((FRAMES, len(grid)), bool)
    tracks = Tracks(uv=(truth - lag).astype(np.float32), visible=visible, start=np.zeros(len(grid), np.int64))
    return tracks, truth


def test_realigned_tracks_carry_no_drift():
    """Tracks that drift by 0.05 px a frame (0.6 px by the end) come back to within 0.1 px of the truth (measured
    0.08: the frames' cubic resampling against the alignment's bilinear)."""
    frames, shifts = _moving_texture()
    tracks, truth = _drifting_tracks(shifts, 0.05)
    masks = np.ones(frames.shape[:3], bool)
    aligned = realign_to_seeds(tracks, frames, masks)
    assert aligned.visible.all()
    assert np.linalg.norm(tracks.uv[-1] - truth[-1], axis=1).min() > 0.5
    assert np.linalg.norm(aligned.uv - truth, axis=2).max() < 0.1


def test_an_observation_whose_window_no_longer_matches_is_dropped_or_kept_as_tracked():
    """Where the texture is replaced (the window now on another surface) the observation is dropped, or keeps
    the tracker's position when asked; the tracks not chosen are returned as they are."""
    frames, shifts = _moving_texture()
    frames[7] = _moving_texture(seed=1)[0][7]
    tracks, _ = _drifting_tracks(shifts, 0.05)
    masks = np.ones(frames.shape[:3], bool)
    subset = np.arange(tracks.num_tracks) % 2 == 0
    dropped = realign_to_seeds(tracks, frames, masks, subset=subset)
    assert not dropped.visible[7, subset].any() and dropped.visible[8, subset].all()
    assert np.array_equal(dropped.uv[:, ~subset], tracks.uv[:, ~subset])
    kept = realign_to_seeds(tracks, frames, masks, subset=subset, keep_unmatched=True)
    assert kept.visible.all() and np.array_equal(kept.uv[7], tracks.uv[7])
