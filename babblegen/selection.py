"""NSGA-II survival and mating selection (Deb et al. 2002), for maximised objectives.

Hand-written with numpy rather than taken from a library: it adds no dependency and the populations are tiny
(about 24 individuals), so the O(m n^2) dominance matrix costs microseconds.
"""

from __future__ import annotations

import numpy as np

__all__ = ["binary_tournament", "crowding_distance", "non_dominated_sort", "nsga2_select"]


def _as_objectives(objectives: np.ndarray) -> np.ndarray:
    f = np.asarray(objectives, dtype=np.float64)
    if f.ndim == 1:
        f = f[:, None]
    if f.ndim != 2:
        raise ValueError(f"objectives must have shape (n, m), got {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError("objectives must be finite")
    return f


def non_dominated_sort(objectives: np.ndarray) -> np.ndarray:
    """Pareto front index (0 = non-dominated) of each row of an ``(n, m)`` array of maximised objectives."""
    f = _as_objectives(objectives)
    n = f.shape[0]
    ge = np.all(f[:, None, :] >= f[None, :, :], axis=-1)
    gt = np.any(f[:, None, :] > f[None, :, :], axis=-1)
    dominates = ge & gt  # dominates[i, j]: i dominates j
    rank = np.full(n, -1, dtype=np.int64)
    remaining = np.ones(n, dtype=bool)
    front = 0
    while remaining.any():
        n_dominators = dominates[remaining][:, remaining].sum(axis=0)
        idx = np.flatnonzero(remaining)[n_dominators == 0]
        rank[idx] = front
        remaining[idx] = False
        front += 1
    return rank


def crowding_distance(objectives: np.ndarray, rank: np.ndarray) -> np.ndarray:
    """Crowding distance of each individual within its front.

    Per objective, the two extreme individuals of a front get ``inf`` and the others the normalised gap
    between their neighbours. An objective that is constant over a front contributes 0 to all of its members
    (no extremes), so tied individuals are left to the index tie-break.
    """
    f = _as_objectives(objectives)
    rank = np.asarray(rank)
    crowd = np.zeros(f.shape[0], dtype=np.float64)
    for r in np.unique(rank):
        members = np.flatnonzero(rank == r)
        if members.size <= 2:
            crowd[members] = np.inf
            continue
        for j in range(f.shape[1]):
            v = f[members, j]
            span = v.max() - v.min()
            if span == 0.0:
                continue
            order = members[np.argsort(v, kind="stable")]
            sv = f[order, j]
            crowd[order[0]] = np.inf
            crowd[order[-1]] = np.inf
            crowd[order[1:-1]] += (sv[2:] - sv[:-2]) / span
    return crowd


def nsga2_select(objectives: np.ndarray, n_keep: int, tie_order: np.ndarray | None = None) -> np.ndarray:
    """Indices of the ``n_keep`` survivors: best fronts first, then larger crowding, then lower ``tie_order``
    (by default the index).

    With a single objective this is elitist truncation: the ``n_keep`` largest values, ties to lower
    ``tie_order``. The result is ordered by that same key.
    """
    f = _as_objectives(objectives)
    n = f.shape[0]
    if not 0 <= n_keep <= n:
        raise ValueError(f"n_keep must be in [0, {n}], got {n_keep}")
    rank = non_dominated_sort(f)
    crowd = crowding_distance(f, rank)  # one objective: a front is a set of ties, equal crowding
    ties = np.arange(n) if tie_order is None else np.asarray(tie_order)
    if ties.shape != (n,):
        raise ValueError(f"tie_order must have shape ({n},), got {ties.shape}")
    order = np.lexsort((ties, -crowd, rank))
    return order[:n_keep]


def binary_tournament(rank: np.ndarray, crowding: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` winners of binary tournaments between two distinct random individuals (crowded comparison).

    The lower rank wins, then the larger crowding distance; a full tie goes to the first contestant drawn.
    With a single individual it always wins.
    """
    rank = np.asarray(rank)
    crowding = np.asarray(crowding, dtype=np.float64)
    size = rank.shape[0]
    if size < 1:
        raise ValueError("binary_tournament needs at least one individual")
    a = rng.integers(size, size=n)
    if size == 1:
        return a
    b = (a + rng.integers(1, size, size=n)) % size
    b_wins = (rank[b] < rank[a]) | ((rank[b] == rank[a]) & (crowding[b] > crowding[a]))
    return np.where(b_wins, b, a)
