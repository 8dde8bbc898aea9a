"""Refinement of the transfer's velocity field, one Euler step at a time (Motion Marionette Sec. 4.2).

At step ``t`` every Gaussian ``i`` has its part's rigid velocity ``u_i``
(:func:`~marionette.transfer.velocity.velocity_step`); the refined velocity
is ``v_i = u_i + r_i``, where the residual ``r`` minimises, by ``sweeps``
Jacobi sweeps warm-started from the previous step's residual ``q``::

    L = λ_data Σ_i |r_i|²                                              (data term, ours)
      + λ_kin  Σ_i 1/|N(i)| Σ_{j∈N(i)} |r_i − r_j|² + |(r_i − q_i) − (r_j − q_j)|²   (kinematic, Eq. 7)
      + λ_topo Σ_{i∈B} |v_i − 1/|N'(i)| Σ_{j∈N'(i)} v_j|²                  (topological, Eq. 8)

``N(i)`` are the ``neighbours`` nearest Gaussians in i's own part (its patch),
``N'(i)`` the nearest in any part and ``B`` the boundary band (Gaussians with
a neighbour in another part). Setting the gradient to zero gives the sweep::

    r_i ← [λ_kin (2 r̄_i + q_i − q̄_i) + λ_topo b_i (m_i − u_i)] / (λ_data + 2 λ_kin + λ_topo b_i)

with ``r̄, q̄`` patch means, ``m_i`` the mean of ``v`` over ``N'(i)`` and
``b_i = 1`` in the band. Where we depart from the paper: its kinematic loss
penalises ``|v_i − v_j|``, which is not zero inside a turning rigid part, so
smoothing the full velocities bends every part (docs/benchmarks/transfer.md);
we smooth the residual from the part's rigid motion, and
the data term keeps the velocity near it. As rigid fields have no residual,
only the band and the Gaussians within ``sweeps`` graph hops of it (the
*active* set) are ever touched, which keeps the cost small.

Motion propagation (paper): a static Gaussian (``|v_i| < ε`` object radii
per frame) whose neighbours are mostly dynamic takes their mean velocity.

Shape matching (position-based dynamics, Müller et al. 2005; beyond the
paper): after the Euler step each active patch ``P`` (a Gaussian and its
patch neighbours) is matched to its rest shape by the best rotation
``R_P`` (Kabsch's optimum, found by Müller et al. 2016's warm-started
iteration) and each active Gaussian moves to its goal, averaged over the
patches ``P ∋ i``::

    g_i = mean_{P∋i} R_P (x⁰_i − c⁰_P) + c_P

Gaussians outside the active set follow their part rigidly and anchor it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from ..errors import InputError
from ..parallel import chunks, parallel_for

__all__ = ["RefineOptions", "Refiner"]

#: Patches per item of the shape-matching loop shared among threads.
_MATCH_CHUNK = 64


@dataclass(frozen=True)
class RefineOptions:
    """Which refinement steps run and their weights (paper defaults: 5 sweeps, λ_kin = λ_topo = 1, ε = 1e-5).

    ``lambda_data`` (ours) is 4: on the synthetic hinge, 1 let the band bend
    (1.4 % rigidity error), 4 keeps it to 0.5 % with the seam still closed.

    ``joints`` (ours) turns each part that touches a steadier part about their
    joint instead of its own centre (see :func:`~marionette.transfer.velocity.integrate`).
    ``epsilon`` is in object radii per frame. ``match_iterations`` caps the
    shape-matching rotation updates per step; warm-started from the previous
    step, they converge over the steps as PBD solvers do.
    """

    kinematic: bool = True
    topological: bool = True
    propagation: bool = True
    shape_matching: bool = True
    joints: bool = True
    sweeps: int = 5
    lambda_kin: float = 1.0
    lambda_topo: float = 1.0
    lambda_data: float = 4.0
    epsilon: float = 1e-5
    neighbours: int = 8
    match_iterations: int = 3

    def __post_init__(self) -> None:
        if self.sweeps < 0 or self.neighbours < 1 or self.match_iterations < 1:
            raise InputError("refinement needs sweeps >= 0, neighbours >= 1 and match_iterations >= 1")
        if min(self.lambda_kin, self.lambda_topo, self.lambda_data, self.epsilon) < 0:
            raise InputError("refinement weights and epsilon must be non-negative")


def _match_patches(rest, mu, patch, rot, tol, max_iter):
    """Goal positions (M, k, 3) of patches (M, k) and their rotations ``rot`` (M, 3, 3), updated in place.

    The rotation maximising ``tr(Rᵀ A)``, ``A = Σ (x − c)(x⁰ − c⁰)ᵀ``, by
    Müller et al. 2016 ("A robust method to extract the rotational part of
    deformations"), warm-started from ``rot``: ``ω = Σ_c r_c × a_c / |Σ_c r_c · a_c|``,
    ``R ← exp(ω) R`` until ``|ω| < tol``. Same optimum as Kabsch (SVD), much cheaper
    per patch when warm (a step or two per Euler step).
    """
    goal = np.empty((patch.shape[0], patch.shape[1], 3))
    parallel_for(_match_chunks, chunks(patch.shape[0], _MATCH_CHUNK), rest, mu, patch, rot, tol, max_iter, goal)
    return goal


@numba.njit(nogil=True, cache=True)
def _match_chunks(first, step, nchunks, rest, mu, patch, rot, tol, max_iter, goal):  # pragma: no cover - compiled
    """Chunks ``first, first + step, ...`` of ``_MATCH_CHUNK`` patches of ``_match_patches`` (one thread's share)."""
    m, k = patch.shape
    for chunk in range(first, nchunks, step):
        for p in range(chunk * _MATCH_CHUNK, min(m, (chunk + 1) * _MATCH_CHUNK)):
            c0 = np.zeros(3)
            c = np.zeros(3)
            for s in range(k):
                for d in range(3):
                    c0[d] += rest[patch[p, s], d] / k
                    c[d] += mu[patch[p, s], d] / k
            a = np.zeros((3, 3))
            e = np.empty((3, 3))
            for s in range(k):
                for i in range(3):
                    for j in range(3):
                        a[i, j] += (mu[patch[p, s], i] - c[i]) * (rest[patch[p, s], j] - c0[j])
            r = rot[p]  # a view: updated in place
            for _ in range(max_iter):
                w0 = w1 = w2 = dot = 0.0
                for col in range(3):
                    rc0, rc1, rc2 = r[0, col], r[1, col], r[2, col]
                    ac0, ac1, ac2 = a[0, col], a[1, col], a[2, col]
                    w0 += rc1 * ac2 - rc2 * ac1
                    w1 += rc2 * ac0 - rc0 * ac2
                    w2 += rc0 * ac1 - rc1 * ac0
                    dot += rc0 * ac0 + rc1 * ac1 + rc2 * ac2
                scale = 1.0 / (abs(dot) + 1e-300)
                w0, w1, w2 = w0 * scale, w1 * scale, w2 * scale
                angle = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
                if angle < tol:
                    break
                x, y, z = w0 / angle, w1 / angle, w2 / angle
                cs, sn = np.cos(angle), np.sin(angle)
                e[0, 0], e[0, 1], e[0, 2] = cs + x * x * (1 - cs), x * y * (1 - cs) - z * sn, x * z * (1 - cs) + y * sn
                e[1, 0], e[1, 1], e[1, 2] = y * x * (1 - cs) + z * sn, cs + y * y * (1 - cs), y * z * (1 - cs) - x * sn
                e[2, 0], e[2, 1], e[2, 2] = z * x * (1 - cs) - y * sn, z * y * (1 - cs) + x * sn, cs + z * z * (1 - cs)
                for col in range(3):
                    t0, t1, t2 = r[0, col], r[1, col], r[2, col]
                    for i in range(3):
                        r[i, col] = e[i, 0] * t0 + e[i, 1] * t1 + e[i, 2] * t2
            for s in range(k):
                for i in range(3):
                    g = c[i]
                    for j in range(3):
                        g += r[i, j] * (rest[patch[p, s], j] - c0[j])
                    goal[p, s, i] = g


class Refiner:
    """Refinement state for one target: neighbourhoods, band and active set, built once from rest positions.

    Stateful: call :meth:`velocity`, then :meth:`project` on the stepped
    positions, once per Euler step and in order (the previous step's
    residual and patch rotations carry over).

    Parameters
    ----------
    rest : (N, 3) float
        Rest positions of the Gaussians.
    labels : (N,) int
        Part of each Gaussian.
    options : RefineOptions
    """

    def __init__(self, rest: np.ndarray, labels: np.ndarray, options: RefineOptions) -> None:
        self.options = options
        rest = np.asarray(rest, dtype=np.float64)
        labels = np.asarray(labels)
        n, k = len(rest), min(options.neighbours, len(rest) - 1)
        self.radius = float(np.sqrt(((rest - rest.mean(axis=0)) ** 2).sum(axis=1).mean())) or 1.0
        # N'(i): nearest in any part; the band has a neighbour in another part.
        _, near = cKDTree(rest).query(rest, k=k + 1, workers=-1)
        self.near = near[:, 1:]
        self.adjacency = csr_matrix((np.ones(n * k), (np.repeat(np.arange(n), k), self.near.ravel())), shape=(n, n))
        self.band = (labels[self.near] != labels[:, None]).any(axis=1)
        # Active set: the band grown by `sweeps` hops (+1 so patches of its edge see anchored neighbours).
        active = self.band.copy()
        for _ in range(options.sweeps + 1):
            grown = active.copy()
            grown[self.near[active].ravel()] = True
            active = grown
        self.active = np.nonzero(active)[0]
        # N(i): the patch of i within its own part.
        patch = np.empty((len(self.active), k + 1), np.int64)
        for part in np.unique(labels[self.active]):
            members = np.nonzero(labels == part)[0]
            rows = np.nonzero(labels[self.active] == part)[0]
            kk = min(k + 1, len(members))
            _, idx = cKDTree(rest[members]).query(rest[self.active[rows]], k=kk)
            idx = members[np.asarray(idx).reshape(len(rows), kk)]
            patch[rows] = np.pad(idx, ((0, 0), (0, k + 1 - kk)), mode="edge")
        self.patch = patch  # (A, k+1), first column the Gaussian itself
        self.rest = rest
        # Residuals live on the active set only; a patch mean counts neighbours outside it as zero.
        pos = np.full(n, -1)
        pos[self.active] = np.arange(len(self.active))
        a = len(self.active)
        cols = pos[patch[:, 1:]]
        pr, pc = np.nonzero(cols >= 0)
        self.patch_mean = csr_matrix((np.full(len(pr), 1.0 / k), (pr, cols[pr, pc])), shape=(a, a))
        near_a = self.near[self.active]
        self.near_mean = csr_matrix((np.full(a * k, 1.0 / k), (np.repeat(np.arange(a), k), near_a.ravel())),
                                    shape=(a, n))
        self.band_a = self.band[self.active].astype(np.float64)[:, None]
        self.residual = np.zeros((a, 3))
        self.rotations = np.tile(np.eye(3), (a, 1, 1))  # warm start of each patch's shape matching

    def velocity(self, u: np.ndarray) -> np.ndarray:
        """Refined velocities (N, 3) from the parts' rigid velocities ``u`` (N, 3) at this step."""
        o = self.options
        v = u.copy()
        lam_kin = o.lambda_kin if o.kinematic else 0.0
        lam_topo = o.lambda_topo if o.topological else 0.0
        if (lam_kin or lam_topo) and len(self.active):
            q = self.residual
            q_term = q - self.patch_mean @ q
            # m_i − u_i = mean_j (u_j + r_j) − u_i; the u part is fixed during the sweeps.
            u_gap = self.near_mean @ u - u[self.active]
            b = lam_topo * self.band_a
            denom = o.lambda_data + 2 * lam_kin + b
            r = q.copy()
            full = np.zeros_like(u)
            for _ in range(o.sweeps):
                full[self.active] = r
                topo = self.near_mean @ full + u_gap
                r = (lam_kin * (2 * (self.patch_mean @ r) + q_term) + b * topo) / denom
            self.residual = r
            v[self.active] += r
        if o.propagation:
            v = self._propagate(v)
        return v

    def _propagate(self, v: np.ndarray) -> np.ndarray:
        """Static Gaussians whose neighbours are mostly dynamic take the neighbours' mean dynamic velocity."""
        dynamic = (np.einsum("ij,ij->i", v, v) >= (self.options.epsilon * self.radius) ** 2).astype(np.float64)
        count = self.adjacency @ dynamic
        idx = np.nonzero((dynamic == 0) & (2 * count > self.near.shape[1]))[0]
        if not len(idx):
            return v
        out = v.copy()
        out[idx] = (self.adjacency[idx] @ (v * dynamic[:, None])) / count[idx, None]
        return out

    def project(self, mu: np.ndarray) -> np.ndarray:
        """Positions (N, 3) after the shape-matching projection of the active patches (no-op when switched off)."""
        if not self.options.shape_matching or not len(self.active):
            return mu
        # (A, k+1, 3) goals; self.rotations carry over to warm-start the next step.
        goal = _match_patches(self.rest, mu, self.patch, self.rotations, 1e-10, self.options.match_iterations)
        flat = self.patch.ravel()
        count = np.bincount(flat, minlength=len(mu))
        out = mu.copy()
        sums = np.stack([np.bincount(flat, goal[..., d].ravel(), minlength=len(mu)) for d in range(3)], axis=1)
        # Only active Gaussians move; the rest follow their part rigidly and anchor the patches.
        act = self.active
        out[act] = sums[act] / count[act, None]
        return out
