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

Joints (ours, ``RefineOptions.joints``): a part turning about its own centre
drifts away from the part it is attached to (a lid turning about its middle
leaves the box). With joints on, parts that touch (share k-nearest-neighbour
edges) form a tree rooted at the steadiest part; the root moves as above and
every other part turns about its joint with its parent, which moves with the
parent (the tree keeps the largest seams, see :func:`joint_tree`)::

    μ_{t+1} = R_t (μ_t − j_t) + j_{t+1},   j_{t+1} = parent's step applied to j_t

The joint is the least-squares fixed point of the two source parts' relative
motion, placed at the same offset from the child's centre (in units of its
size) on the target and snapped to the nearest Gaussian of the pair's
boundary band. The child's own translation is dropped: the joint fixes it.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import minimum_spanning_tree

from ..errors import InputError
from ..geometry import rotation_angle_deg
from ..prior import SpatPrior
from ..trajectory import Trajectory
from .refine import RefineOptions, Refiner

__all__ = ["integrate", "joint_tree", "part_radii", "velocity_step"]


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
    # Both are (R − I) μ + c, one product and one sum over the points.
    offset = translation if anchor_from is None else anchor_to - rotation @ anchor_from
    return means @ (rotation - np.eye(3)).T + offset


def _source_joint(prior: SpatPrior, k: int, j: int) -> np.ndarray:
    """(3,) point the source poses of parts k and j move alike: argmin_p Σ_t |T_k(t) p − T_j(t) p|².

    A small pull towards the midpoint of the two centres picks one point when
    the motion leaves a line (a hinge axis) or everything (no relative motion) free.
    """
    a = prior.poses[k, :, :3, :3] - prior.poses[j, :, :3, :3]  # (T, 3, 3)
    b = prior.poses[j, :, :3, 3] - prior.poses[k, :, :3, 3]
    mid = (prior.centroids[k, 0] + prior.centroids[j, 0]) / 2
    pull = 1e-3 * np.sqrt(prior.num_frames)
    lhs = np.concatenate([a.reshape(-1, 3), pull * np.eye(3)])
    rhs = np.concatenate([b.ravel(), pull * mid])
    return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def joint_tree(means: np.ndarray, labels: np.ndarray, prior: SpatPrior, near: np.ndarray,
               min_edges: int = 5) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Parts in tree order, each part's parent (P,) (-1 for a root) and joint rest position (P, 3).

    means : (N, 3) rest positions; labels : (N,) parts; near : (N, k) nearest
    neighbours of each Gaussian. Parts touch when at least ``min_edges``
    neighbour pairs join them. Rigid parts that move differently can hold
    only a tree of their seams, so the tree keeps the longest ones: the
    maximum spanning tree of the contact graph weighted by seam size (a seam
    left out, such as the short one closing a cycle of three parts, may
    open). Each tree is rooted at its part that moves least in the prior
    (rotation in radians plus centre travel in radii). A part the prior fits
    as a slider (``metadata["joints"]``) is nobody's child: a turn about a
    joint would drop the travel that is its motion; it moves by its own.
    """
    p = prior.num_parts
    a, b = np.repeat(labels, near.shape[1]), labels[near.ravel()]
    seam_size = np.bincount(a * p + b, minlength=p * p).reshape(p, p)
    seam_size = np.minimum(seam_size, seam_size.T)
    np.fill_diagonal(seam_size, 0)
    seam_size[seam_size < min_edges] = 0
    # Maximum spanning tree: a minimum one of weights that fall as seams grow (all positive, so none drops out).
    weights = np.where(seam_size > 0, seam_size.max() + 1.0 - seam_size, 0.0)
    tree = minimum_spanning_tree(weights).toarray() > 0
    held = tree | tree.T
    angles = np.radians([[rotation_angle_deg(r) for r in part] for part in prior.rotations]).sum(axis=1)
    travel = np.linalg.norm(np.diff(prior.centroids, axis=1), axis=2).sum(axis=1) / prior.radii
    motion = angles + travel
    cents, radii = part_radii(means, labels, p)
    parent, joints, order = np.full(p, -1), np.zeros((p, 3)), []
    sliding = {int(i) for i, note in (prior.metadata.get("joints") or {}).items() if note.get("model") == "slider"}
    for root in np.argsort(motion, kind="stable"):
        if root in order:
            continue
        order.append(int(root))
        walk = len(order) - 1
        while walk < len(order):  # breadth first: `order` grows while we walk it
            k = order[walk]
            walk += 1
            for j in np.nonzero(held[k])[0]:
                if j in order or j in sliding:
                    continue
                guess = cents[j] + (_source_joint(prior, k, j) - prior.centroids[j, 0]) * radii[j] / prior.radii[j]
                seam = (labels == k) & (labels[near] == j).any(axis=1) | (labels == j) & (labels[near] == k).any(axis=1)
                cand = np.nonzero(seam)[0]
                joints[j] = means[cand[np.argmin(np.linalg.norm(means[cand] - guess, axis=1))]]
                parent[j] = k
                order.append(int(j))
    return order, parent, joints


def integrate(means: np.ndarray, labels: np.ndarray, prior: SpatPrior, *, anchor: str = "centroid",
              translation_scale: np.ndarray | float | None = None,
              refine: RefineOptions | None = None) -> Trajectory:
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
    refine : RefineOptions, optional
        Refine each step's velocities (:mod:`~marionette.transfer.refine`) and,
        with ``joints`` and the centroid anchor, turn parts about their joints.
        Ignored for one part: there is nothing to refine.

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
    # Work with the Gaussians sorted by part, so that each part is a slice (no gathers in the loop).
    perm = np.argsort(labels, kind="stable")
    rest, sorted_labels = means[perm], labels[perm]
    bounds = np.searchsorted(sorted_labels, np.arange(p + 1))
    refiner = Refiner(rest, sorted_labels, refine) if refine is not None and p > 1 else None
    order, parent = list(range(p)), np.full(p, -1)
    if refiner is not None and refine.joints and anchor == "centroid":
        order, parent, joints = joint_tree(rest, sorted_labels, prior, refiner.near)

    out = np.empty((t_count, len(means), 3), dtype=np.float32)  # in part order until the end
    rots = np.empty((t_count, p, 3, 3))
    out[0], rots[0] = rest, np.eye(3)
    mu = rest.copy()
    pivot_from, pivot_to = np.zeros((p, 3)), np.zeros((p, 3))
    for t in range(t_count - 1):
        v = np.empty_like(mu)  # every Gaussian is in one part's slice
        for k in order:
            part, r, d = slice(bounds[k], bounds[k + 1]), prior.rotations[k, t], prior.translations[k, t]
            if anchor == "world":
                v[part] = velocity_step(mu[part], r, d)
            else:
                if parent[k] < 0:
                    g_next = cents[k] + scale[k] * (prior.centroids[k, t + 1] - prior.centroids[k, t])
                    pivot_from[k], pivot_to[k], cents[k] = cents[k], g_next, g_next
                else:  # the joint rides on the parent, which has already stepped
                    q = parent[k]
                    pivot_from[k] = joints[k]
                    pivot_to[k] = joints[k] = prior.rotations[q, t] @ (joints[k] - pivot_from[q]) + pivot_to[q]
                v[part] = velocity_step(mu[part], r, d, pivot_from[k], pivot_to[k])
            rots[t + 1, k] = r @ rots[t, k]
        if refiner is not None:
            mu = refiner.project(mu + refiner.velocity(v))
        else:
            mu = mu + v  # Euler step, paper Eq. 6
        out[t + 1] = mu
    if np.any(perm != np.arange(len(perm))):  # back to the Gaussians' own order
        unsorted = np.empty_like(out)
        unsorted[:, perm] = out
        out = unsorted
    return Trajectory(out, rots.astype(np.float32), labels.astype(np.int32))
