"""Prior → velocity field → Euler steps (Motion Marionette Sec. 4.2).

For part k and step t the prior holds ``R_t, δ_t`` with
``μ_{t+1} = R_t μ_t + δ_t`` (paper Eq. 5). The velocity of a target Gaussian
is ``v_t = μ_{t+1} − μ_t`` and positions advance by Euler steps
``μ_{t+1} = μ_t + v_t`` (paper Eq. 6).

Where we depart from the paper (``anchor="centroid"``, the default): applying
``R_t, δ_t`` about the source world origin makes a target that sits elsewhere
orbit the origin. We instead turn each target part about its own centre
``g_t`` and move that centre as the source part's centre moved, scaled by
target size over source size ``s``::

    g_{t+1} = g_t + s (c_{t+1} − c_t)
    μ_{t+1} = R_t (μ_t − g_t) + g_{t+1}

which is the same rigid step when the target is the source (``s = 1``,
``g = c``). ``anchor="world"`` keeps the paper's literal Eq. 5.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..prior import SpatPrior
from ..trajectory import Trajectory

__all__ = ["velocity_step", "integrate", "part_radii"]


def part_radii(means: np.ndarray, labels: np.ndarray, num_parts: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (P, 3) and RMS radii (P,) of each part of points (N, 3) labelled (N,).

    A part with no points gets the whole set's centroid and radius.
    """
    means = means.astype(np.float64)
    whole_c = means.mean(axis=0)
    whole_r = float(np.sqrt(((means - whole_c) ** 2).sum(axis=1).mean()))
    cents = np.tile(whole_c, (num_parts, 1))
    radii = np.full(num_parts, whole_r)
    for k in range(num_parts):
        pts = means[labels == k]
        if len(pts):
            cents[k] = pts.mean(axis=0)
            radii[k] = max(float(np.sqrt(((pts - cents[k]) ** 2).sum(axis=1).mean())), 1e-9)
    return cents, radii


def velocity_step(means: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                  anchor_from: np.ndarray | None = None, anchor_to: np.ndarray | None = None) -> np.ndarray:
    """Velocities (M, 3) of points ``means`` (M, 3) under one rigid step.

    With anchors: ``v = R (μ − anchor_from) + anchor_to − μ``; without, the
    paper's ``v = R μ + δ − μ``.
    """
    if anchor_from is None:
        return means @ rotation.T + translation - means
    return (means - anchor_from) @ rotation.T + anchor_to - means


def integrate(means: np.ndarray, labels: np.ndarray, prior: SpatPrior, *, anchor: str = "centroid",
              translation_scale: np.ndarray | float | None = None) -> Trajectory:
    """Euler-integrate the prior's velocity field from rest positions.

    Parameters
    ----------
    means : (N, 3) float
        Rest positions of the target Gaussians (frame 0).
    labels : (N,) int
        Part of each Gaussian, indices into the prior's parts.
    prior : SpatPrior with P parts and T frames.
    anchor : "centroid" (each part about its own centre, translations scaled by
        size) or "world" (the paper's literal Eq. 5).
    translation_scale : (P,) or float, optional
        Override of the target-over-source size ratio ``s``.

    Returns
    -------
    Trajectory with means (T, N, 3) and part rotations (T, P, 3, 3).
    """
    if anchor not in ("centroid", "world"):
        raise InputError(f"anchor must be 'centroid' or 'world', got {anchor!r}")
    means = np.asarray(means, dtype=np.float64)
    labels = np.asarray(labels)
    p, t_count = prior.num_parts, prior.num_frames
    if labels.shape != (len(means),) or (len(labels) and (labels.min() < 0 or labels.max() >= p)):
        raise InputError(f"part labels must be ({len(means)},) integers in 0..{p - 1}")
    cents, radii = part_radii(means, labels, p)
    scale = radii / prior.radii if translation_scale is None else np.broadcast_to(translation_scale, (p,))
    members = [np.nonzero(labels == k)[0] for k in range(p)]

    out = np.empty((t_count, len(means), 3), dtype=np.float32)
    rots = np.empty((t_count, p, 3, 3))
    out[0], rots[0] = means, np.eye(3)
    mu = means.copy()
    for t in range(t_count - 1):
        v = np.zeros_like(mu)
        for k, idx in enumerate(members):
            r, d = prior.rotations[k, t], prior.translations[k, t]
            if anchor == "world":
                v[idx] = velocity_step(mu[idx], r, d)
            else:
                g_next = cents[k] + scale[k] * (prior.centroids[k, t + 1] - prior.centroids[k, t])
                v[idx] = velocity_step(mu[idx], r, d, cents[k], g_next)
                cents[k] = g_next
            rots[t + 1, k] = r @ rots[t, k]
        mu = mu + v  # Euler step, paper Eq. 6
        out[t + 1] = mu
    return Trajectory(out, rots.astype(np.float32), labels.astype(np.int32))
