"""Variation operators on NovEB genomes.

A genome is a float64 array of shape ``(n_waypoints, 3)``: end-effector waypoints in normalised workspace
coordinates, visited in order; the last row is the final point. The start pose, common to every trajectory,
is not stored in the genome: operators that need it receive its normalised coordinates as ``start``.
Operators never modify their inputs and never clip: values may leave [0, 1] as in the paper.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = [
    "as_genome",
    "crossover",
    "extend",
    "gaussian_mutation",
    "random_genome",
    "remove_waypoint",
    "waypoint_mutation",
]


def as_genome(genome: np.ndarray) -> np.ndarray:
    """Return ``genome`` as a float64 ``(n, 3)`` array with n >= 1, raising ValueError otherwise."""
    g = np.asarray(genome, dtype=np.float64)
    if g.ndim != 2 or g.shape[1] != 3 or g.shape[0] < 1:
        raise ValueError(f"a genome must have shape (n_waypoints >= 1, 3), got {g.shape}")
    return g


def random_genome(rng: np.random.Generator) -> np.ndarray:
    """A one-waypoint genome whose final point is uniform in [0, 1]^3."""
    return rng.random((1, 3))


def gaussian_mutation(genome: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Add independent N(0, sigma^2) noise to every coordinate of every waypoint (no clipping)."""
    g = as_genome(genome)
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma}")
    return g + rng.normal(0.0, sigma, size=g.shape)


def waypoint_mutation(
    genome: np.ndarray,
    sigma: float,
    rng: np.random.Generator,
    accept: Callable[[np.ndarray], bool] | None = None,
    redraws: int = 0,
) -> np.ndarray:
    """Add N(0, sigma^2) noise to the three coordinates of one waypoint drawn uniformly (no clipping).

    On a one-waypoint genome this is :func:`gaussian_mutation` (same draws); on longer ones the change, and the chance
    that it throws the trajectory out of reach, do not grow with the number of waypoints. With ``accept`` (a test of
    the moved waypoint) and ``redraws`` > 0, a rejected noise draw is drawn again, on the same waypoint, up to
    ``redraws`` times; the last draw stands if none is accepted. ``redraws = 0`` draws exactly as without them.
    """
    g = as_genome(genome)
    if sigma < 0:
        raise ValueError(f"sigma must be >= 0, got {sigma}")
    i = 0 if g.shape[0] == 1 else int(rng.integers(g.shape[0]))
    out = g.copy()
    for _ in range(1 + max(int(redraws), 0) if accept is not None else 1):
        out[i] = g[i] + rng.normal(0.0, sigma, size=3)
        if accept is None or accept(out[i]):
            break
    return out


def extend(genome: np.ndarray, start: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Insert one waypoint midway between two consecutive points of ``[start, w0, ..., w_last]``.

    The segment is drawn uniformly among the ``n`` segments of that sequence; segment ``i`` joins point
    ``i - 1`` (``start`` when ``i == 0``) to waypoint ``i``, and the new point becomes row ``i`` of the
    result, which has ``n + 1`` rows. The final point is unchanged.
    """
    g = as_genome(genome)
    s = np.asarray(start, dtype=np.float64).reshape(3)
    points = np.vstack([s[None, :], g])
    i = int(rng.integers(g.shape[0]))
    mid = 0.5 * (points[i] + points[i + 1])
    return np.insert(g, i, mid, axis=0)


def remove_waypoint(genome: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Delete one waypoint drawn uniformly; a one-waypoint genome is returned unchanged (as a copy).

    The inverse of :func:`extend`: with both, a genome's length can shrink as well as grow. Deleting the last row
    makes the waypoint before it the final point.
    """
    g = as_genome(genome)
    if g.shape[0] == 1:
        return g.copy()
    return np.delete(g, int(rng.integers(g.shape[0])), axis=0)


def crossover(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One-point crossover of two waypoint sequences at the same relative cut (optional, off by default).

    A fraction ``u ~ U[0, 1)`` is drawn; the child is the first ``floor(u * len(a))`` waypoints of ``a``
    followed by the waypoints of ``b`` from index ``floor(u * len(b))`` on. The child therefore always ends
    with ``b``'s final point, has at least one waypoint, and its length lies between the parents' lengths
    (up to rounding), so repeated crossover does not inflate genomes. Two one-waypoint parents give a copy
    of ``b``: crossover only acts once extension has produced intermediate waypoints.
    """
    ga, gb = as_genome(a), as_genome(b)
    u = float(rng.random())
    i = int(np.floor(u * ga.shape[0]))
    j = int(np.floor(u * gb.shape[0]))
    return np.vstack([ga[:i], gb[j:]])
