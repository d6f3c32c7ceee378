"""Hamming distances, k-nearest-neighbour novelty and the novelty archive.

Behaviour codes are uint64 arrays of shape ``(n, n_words)`` (see :mod:`babblegen.descriptors`).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

__all__ = [
    "ARCHIVE_POLICIES",
    "Archive",
    "ArchivePolicy",
    "MostNovel",
    "MostNovelUnseen",
    "hamming",
    "k_smallest_distances",
    "make_archive_policy",
    "novelty",
]

# Elements of one (queries x chunk x words) XOR block; bounds temporary memory to a few MiB.
_BLOCK_ELEMENTS = 1 << 18


def _as_codes(x: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(x)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.dtype != np.uint64:
        raise ValueError(f"{name} must be a (n, n_words) uint64 array, got {a.shape} {a.dtype}")
    return a


def _chunk_rows(n_queries: int, n_words: int) -> int:
    return max(1, _BLOCK_ELEMENTS // max(1, n_queries * n_words))


def _block(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between all rows of ``a`` and ``b`` (both uint64, same width), small int dtype."""
    if a.shape[1] == 1:
        return np.bitwise_count(a[:, None, 0] ^ b[None, :, 0])
    return np.bitwise_count(a[:, None, :] ^ b[None, :, :]).sum(-1, dtype=np.int32)


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise Hamming distances, an ``(n, m)`` int32 array, between ``(n, w)`` and ``(m, w)`` uint64 codes.

    ``b`` is processed in chunks so that the temporary XOR array stays small whatever ``m``.
    """
    a, b = _as_codes(a, "a"), _as_codes(b, "b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"code widths differ: {a.shape[1]} vs {b.shape[1]} words")
    out = np.empty((a.shape[0], b.shape[0]), dtype=np.int32)
    step = _chunk_rows(a.shape[0], a.shape[1])
    for s in range(0, b.shape[0], step):
        out[:, s : s + step] = _block(a, b[s : s + step])
    return out


def k_smallest_distances(queries: np.ndarray, refs: np.ndarray, kk: int) -> np.ndarray:
    """The ``min(kk, m)`` smallest Hamming distances from each query to ``refs``, sorted, shape ``(n, .)``.

    Streams over ``refs`` in chunks, keeping the running ``kk`` best per query: memory stays bounded for
    archives of millions of codes, and a chunk only costs a selection for the queries whose running
    ``kk``-th best it can improve (rare once the archive is large), so the time is dominated by XOR and
    popcount.
    """
    queries, refs = _as_codes(queries, "queries"), _as_codes(refs, "refs")
    if queries.shape[1] != refs.shape[1] and refs.shape[0] > 0:
        raise ValueError(f"code widths differ: {queries.shape[1]} vs {refs.shape[1]} words")
    n, m = queries.shape[0], refs.shape[0]
    kk = min(int(kk), m)
    if kk <= 0 or n == 0:
        return np.zeros((n, 0), dtype=np.int32)
    n_words = queries.shape[1]
    step = max(_chunk_rows(n, 1), kk)
    width = min(step, m)
    xor = np.empty((n, width), dtype=np.uint64)  # buffers reused across chunks and words
    cnt = np.empty((n, width), dtype=np.uint8)
    acc = np.empty((n, width), dtype=np.uint16) if n_words > 1 else cnt
    best: np.ndarray | None = None
    for s in range(0, m, step):
        chunk = refs[s : s + step]
        c = chunk.shape[0]
        d = acc[:, :c]
        for j in range(n_words):
            np.bitwise_xor(queries[:, j : j + 1], chunk[None, :, j], out=xor[:, :c])
            np.bitwise_count(xor[:, :c], out=cnt[:, :c])
            if n_words > 1:
                if j == 0:
                    d[...] = cnt[:, :c]
                else:
                    d += cnt[:, :c]
        if best is None:
            best = np.sort(np.partition(d.astype(np.int32), kk - 1, axis=1)[:, :kk], axis=1)
            continue
        rows = np.flatnonzero(d.min(axis=1) < best[:, -1])
        if rows.size:
            merged = np.concatenate([best[rows], d[rows].astype(np.int32)], axis=1)
            best[rows] = np.sort(np.partition(merged, kk - 1, axis=1)[:, :kk], axis=1)
    assert best is not None
    return best


def novelty(
    queries: np.ndarray,
    population: np.ndarray,
    archive: np.ndarray | None,
    k: int,
    self_in_population: bool = True,
) -> np.ndarray:
    """Novelty of each query: mean Hamming distance to its ``k`` nearest codes in population ∪ archive.

    With ``self_in_population`` every query must be one of the rows of ``population`` and its own entry is
    excluded: one zero distance is dropped from its population distances, which removes exactly the value
    its own entry contributes (duplicates of it elsewhere still count as neighbours at distance 0). A
    ValueError is raised if a query has no zero-distance row in ``population``.
    When fewer than ``k`` neighbours exist the mean is taken over those that exist; with none at all the
    novelty is 0.0. Returns a float64 array of shape ``(len(queries),)``.
    """
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    q = _as_codes(queries, "queries")
    pop = _as_codes(population, "population")
    arc = np.zeros((0, q.shape[1]), np.uint64) if archive is None else _as_codes(archive, "archive")
    extra = 1 if self_in_population else 0
    dp = k_smallest_distances(q, pop, k + extra)
    if self_in_population:
        if dp.shape[1] == 0 or np.any(dp[:, 0] != 0):
            raise ValueError("with self_in_population=True every query must be a row of population")
        dp = dp[:, 1:]
    da = k_smallest_distances(q, arc, k)
    d = np.sort(np.concatenate([dp, da], axis=1), axis=1)[:, :k]
    if d.shape[1] == 0:
        return np.zeros(q.shape[0], dtype=np.float64)
    return d.mean(axis=1, dtype=np.float64)


class Archive:
    """Growable store of behaviour codes with one metadata dict per entry.

    Codes live in a uint64 buffer whose capacity doubles when full (amortised O(1) ``add``).
    """

    def __init__(self, n_words: int | None = None, capacity: int = 64) -> None:
        self._n_words = n_words
        self._buf = np.zeros((max(1, capacity), n_words or 1), dtype=np.uint64)
        self._n = 0
        self.meta: list[dict[str, Any]] = []

    def __len__(self) -> int:
        return self._n

    @property
    def n_words(self) -> int | None:
        """Code width in uint64 words (fixed by the first ``add`` when not given)."""
        return self._n_words

    @property
    def descriptors(self) -> np.ndarray:
        """Read-only view of the stored codes, shape ``(len(self), n_words)``."""
        v = self._buf[: self._n, : self._n_words or 1]
        v = v.view()
        v.flags.writeable = False
        return v

    def add(self, descriptor: np.ndarray, meta: dict[str, Any] | None = None) -> int:
        """Append one code (``(n_words,)`` uint64) and its metadata; returns its archive position."""
        d = np.asarray(descriptor)
        if d.dtype != np.uint64 or d.ndim != 1:
            raise ValueError(f"a descriptor must be a 1-D uint64 array, got {d.shape} {d.dtype}")
        if self._n_words is None:
            self._n_words = d.shape[0]
            self._buf = np.zeros((self._buf.shape[0], self._n_words), dtype=np.uint64)
        if d.shape[0] != self._n_words:
            raise ValueError(f"descriptor has {d.shape[0]} words, archive holds {self._n_words}")
        if self._n == self._buf.shape[0]:
            grown = np.zeros((2 * self._buf.shape[0], self._n_words), dtype=np.uint64)
            grown[: self._n] = self._buf[: self._n]
            self._buf = grown
        self._buf[self._n] = d
        self.meta.append(dict(meta or {}))
        self._n += 1
        return self._n - 1

    def state_dict(self) -> dict[str, Any]:
        """Picklable snapshot (codes copied)."""
        return {
            "n_words": self._n_words,
            "descriptors": np.array(self._buf[: self._n, : self._n_words or 1]),
            "meta": [dict(m) for m in self.meta],
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a snapshot written by :meth:`state_dict`."""
        codes = np.asarray(state["descriptors"], dtype=np.uint64)
        n_words = state["n_words"]
        self._n_words = n_words
        self._n = codes.shape[0]
        self._buf = np.zeros((max(64, 2 * self._n), n_words or 1), dtype=np.uint64)
        self._buf[: self._n] = codes
        self.meta = [dict(m) for m in state["meta"]]
        if len(self.meta) != self._n:
            raise ValueError("archive state has mismatched descriptors and meta")


class ArchivePolicy(Protocol):
    """Chooses which newly evaluated individuals enter the archive after a generation."""

    def select(self, novelty: np.ndarray, descriptors: np.ndarray, archive: Archive) -> np.ndarray:
        """Indices (into ``novelty``/``descriptors`` of the new individuals) to archive."""
        ...

    def config(self) -> dict[str, Any]: ...


class MostNovel:
    """The paper's policy: archive the ``per_generation`` most novel new individuals (ties: lowest index)."""

    name = "most_novel"

    def __init__(self, per_generation: int = 1) -> None:
        if per_generation < 0:
            raise ValueError(f"per_generation must be >= 0, got {per_generation}")
        self.per_generation = int(per_generation)

    def select(self, novelty: np.ndarray, descriptors: np.ndarray, archive: Archive) -> np.ndarray:
        nov = np.asarray(novelty, dtype=np.float64)
        order = np.argsort(-nov, kind="stable")
        return order[: self.per_generation]

    def config(self) -> dict[str, Any]:
        return {"name": self.name, "per_generation": self.per_generation}


class MostNovelUnseen(MostNovel):
    """The paper's policy, but an individual enters only if it adds novelty: the archive (and this
    generation's picks) do not already hold its exact descriptor. Without this, an archive fed one entry per
    generation fills with copies of the few most common outcomes (the untouched scene above all), which only
    pull everyone's novelty towards zero."""

    name = "most_novel_unseen"

    def select(self, novelty: np.ndarray, descriptors: np.ndarray, archive: Archive) -> np.ndarray:
        nov = np.asarray(novelty, dtype=np.float64)
        codes = _as_codes(descriptors, "descriptors") if len(nov) else np.zeros((0, 1), np.uint64)
        picked: list[int] = []
        for i in np.argsort(-nov, kind="stable"):
            if len(picked) == self.per_generation:
                break
            known = archive.descriptors if len(archive) else codes[:0]
            if len(known) and hamming(codes[i], known).min() == 0:
                continue
            if picked and hamming(codes[i], codes[picked]).min() == 0:
                continue
            picked.append(int(i))
        return np.asarray(picked, dtype=np.int64)


ARCHIVE_POLICIES: dict[str, type] = {"most_novel": MostNovel, "most_novel_unseen": MostNovelUnseen}


def make_archive_policy(name: str = "most_novel", **kwargs: Any) -> ArchivePolicy:
    """Build a registered archive policy by name."""
    try:
        cls = ARCHIVE_POLICIES[name]
    except KeyError:
        raise ValueError(f"unknown archive policy {name!r}; known: {sorted(ARCHIVE_POLICIES)}") from None
    return cls(**kwargs)
