"""Procedural textures: multi-scale value noise with colour variation and blobs.

Object faces need texture that Lucas–Kanade can track: structure at several
scales, corners, and nothing finer than a few pixels once rendered (so it
does not alias). Backgrounds get the same noise at low contrast.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Texels per world unit on object faces. An object face 4 units away spans
#: ~70 px per unit at 320x240, so a texel is ~0.5 px: the finest noise octave
#: (8 texels) lands at ~4 px, above the Nyquist limit.
TEXELS_PER_UNIT = 128


def value_noise(rng: np.random.Generator, shape: tuple[int, int], period: float) -> np.ndarray:
    """Smooth random field (H, W) float32, roughly in [0, 1], with features ``period`` texels apart."""
    h, w = shape
    step = max(int(round(period)), 1)
    grid = rng.random((h // step + 4, w // step + 4)).astype(np.float32)
    up = cv2.resize(grid, (grid.shape[1] * step, grid.shape[0] * step), interpolation=cv2.INTER_CUBIC)
    # Skip the first cell: cubic interpolation is least regular at the border.
    return up[step:step + h, step:step + w]


def fractal_noise(rng: np.random.Generator, shape: tuple[int, int],
                  periods: tuple[float, ...], weights: tuple[float, ...]) -> np.ndarray:
    """Weighted sum of value-noise octaves (H, W) float32, zero mean, unit std."""
    out = np.zeros(shape, np.float32)
    for period, weight in zip(periods, weights):
        out += weight * value_noise(rng, shape, period)
    out -= out.mean()
    return out / max(float(out.std()), 1e-6)


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Hue in turns, saturation and value in [0, 1], arrays (H, W) → RGB (H, W, 3) float32."""
    hsv = np.stack([(np.mod(h, 1.0) * 360.0), np.clip(s, 0, 1), np.clip(v, 0, 1)], axis=-1)
    return cv2.cvtColor(hsv.astype(np.float32), cv2.COLOR_HSV2RGB)


def face_texture(rng: np.random.Generator, shape: tuple[int, int], hue: float,
                 saturation: float = 0.55, value: float = 0.85, checker: bool = False) -> np.ndarray:
    """A trackable texture (Ht, Wt, 3) float32 in [0, 1] around one base hue.

    Brightness follows four noise octaves (64 to 8 texels) of similar weight,
    so there is contrast at every scale a tracker's window sees; hue and
    saturation drift slowly. On top, either a sprinkle of light and dark blobs
    (corners for the tracker) or, with ``checker``, 20-texel cells of varied
    hue and brightness (a different look, for target images).
    """
    lum = fractal_noise(rng, shape, (64, 32, 16, 8), (0.3, 0.3, 0.3, 0.25))
    drift = fractal_noise(rng, shape, (48, 24), (1.0, 0.5))
    sat_drift = fractal_noise(rng, shape, (40,), (1.0,))
    if checker:
        cell = 20
        cells = rng.random((shape[0] // cell + 1, shape[1] // cell + 1, 2)).astype(np.float32)
        cells = np.repeat(np.repeat(cells, cell, axis=0), cell, axis=1)[:shape[0], :shape[1]]
        cells = cv2.GaussianBlur(cells, (0, 0), 0.8)  # soft cell edges: no aliasing
        v = value * (0.72 + 0.05 * lum + 0.3 * cells[..., 0])
        drift = 0.5 * drift + 3.0 * (cells[..., 1] - 0.5)
    else:
        v = value * (0.7 + 0.17 * lum)
        # Discs of 1.5-5 texels, about one per 14x14 texels, blurred to stay band-limited.
        blobs = np.zeros(shape, np.float32)
        n = max(1, shape[0] * shape[1] // 200)
        centres = rng.random((n, 2)) * [shape[1], shape[0]]
        radii = rng.uniform(1.5, 5.0, n)
        signs = rng.choice([-1.0, 1.0], n)
        for (x, y), r, sign in zip(centres, radii, signs):
            cv2.circle(blobs, (int(x * 16), int(y * 16)), int(r * 16), float(sign), -1, cv2.LINE_AA, shift=4)
        v = v * (1.0 + 0.3 * cv2.GaussianBlur(blobs, (0, 0), 0.8))
    rgb = hsv_to_rgb(hue + 0.025 * drift, saturation * (1.0 + 0.3 * sat_drift), v)
    return np.clip(rgb, 0.0, 1.0)


def background_texture(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A static, low-contrast, near-neutral background (H, W, 3) float32 in [0, 1].

    Feature sizes are fractions of the image width, so the background looks
    the same at any resolution. Contrast is about ±8 %: enough texture that a
    tracker finds background corners too (so masks matter), not enough to
    compete with the object.
    """
    w = shape[1]
    lum = fractal_noise(rng, shape, (w / 6, w / 14, w / 30, w / 60), (0.45, 0.3, 0.2, 0.15))
    tint = fractal_noise(rng, shape, (w / 5,), (1.0,))
    hue = rng.random()
    base = rng.uniform(0.6, 0.72)
    return hsv_to_rgb(np.full(shape, hue, np.float32) + 0.05 * tint,
                      np.full(shape, 0.08, np.float32), base * (1.0 + 0.08 * lum))
