"""The ask/tell interface shared by all explorers.

An explorer proposes candidates (``ask``), the caller evaluates them in the world and computes their
behaviour descriptors, and the explorer learns from the outcome (``tell``). Explorers only ever see
descriptors (packed bit codes), never the simulator's ground truth.
"""

from __future__ import annotations

import dataclasses
import hashlib
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from babblegen.novelty import Archive, make_archive_policy

__all__ = ["Candidate", "Clone", "Evaluation", "Explorer", "build_config", "check_descriptors", "genome_key"]

KIND_WAYPOINTS = "ee_waypoints"
KIND_JOINTS = "joint_target"


@dataclass
class Candidate:
    """One attempt proposed by an explorer."""

    index: int  # attempt index in the run (0, 1, 2, ... across generations, assigned by the explorer)
    generation: int
    kind: str  # "ee_waypoints" (genome = (n, 3) normalised waypoints) or "joint_target" (genome = (7,) rad)
    genome: np.ndarray
    parent: int | None  # attempt index of the parent, None for random ones


@dataclass
class Clone:
    """A child whose genome was already tried: it reuses that attempt's outcome instead of being simulated.

    It is not an attempt (no index of its own, no episode); the search still sees it, as in the paper.
    """

    generation: int
    kind: str
    genome: np.ndarray
    parent: int | None  # attempt index of the parent
    source: int  # attempt index whose outcome (descriptor, or infeasibility) it reuses
    novelty: float | None = None  # set by tell; None when the source was infeasible
    survived: bool = False  # set by tell: kept as a parent


def genome_key(kind: str, genome: np.ndarray) -> str:
    """Identity of a command: equal keys mean the same movement (the world is deterministic). A 128-bit digest
    of the exact float64 bytes, so the run state stays small however long genomes grow."""
    raw = np.ascontiguousarray(genome, dtype=np.float64).tobytes()
    return f"{kind}:{hashlib.blake2b(raw, digest_size=16).hexdigest()}"


def _pack_outcomes(outcomes: dict[str, tuple[int, np.ndarray | None]]) -> dict[str, Any]:
    """The genome -> (attempt, descriptor) memo as parallel arrays (infeasible: a zero row, feasible False)."""
    width = next((len(d) for _, d in outcomes.values() if d is not None), 0)
    codes = np.zeros((len(outcomes), width), dtype=np.uint64)
    for row, (_, d) in enumerate(outcomes.values()):
        if d is not None:
            codes[row] = d
    return {
        "keys": list(outcomes),
        "attempts": np.array([i for i, _ in outcomes.values()], dtype=np.int64),
        "feasible": np.array([d is not None for _, d in outcomes.values()], dtype=bool),
        "codes": codes,
    }


def _unpack_outcomes(packed: dict[str, Any]) -> dict[str, tuple[int, np.ndarray | None]]:
    codes = np.asarray(packed["codes"], dtype=np.uint64)
    return {
        key: (int(i), codes[row].copy() if ok else None)
        for row, (key, i, ok) in enumerate(zip(packed["keys"], packed["attempts"], packed["feasible"], strict=True))
    }


@dataclass
class Evaluation:
    """What the explorer made of one told candidate."""

    novelty: float | None  # None for infeasible candidates (no descriptor)
    archived: bool


class Explorer(ABC):
    """Generational ask/tell explorer.

    ``ask`` returns the current batch of candidates to evaluate (possibly empty when every proposal repeats a
    genome already tried); calling it again before ``tell`` returns the same batch (so a run restored from a
    checkpoint taken between the two re-issues it). ``ask(max_new=n)`` caps the batch at n candidates.
    ``tell`` takes the same candidates in the same order with one descriptor each (``None`` when the
    candidate was infeasible); afterwards ``last_clones`` lists the proposals that reused earlier outcomes.
    """

    name: str
    config: Any

    last_clones: list[Clone]

    @abstractmethod
    def ask(self, max_new: int | None = None) -> list[Candidate]: ...

    @abstractmethod
    def tell(self, candidates: list[Candidate], descriptors: list[np.ndarray | None]) -> list[Evaluation]: ...

    @abstractmethod
    def state_dict(self) -> dict[str, Any]: ...

    @abstractmethod
    def load_state_dict(self, state: dict[str, Any]) -> None: ...

    @property
    @abstractmethod
    def archive_size(self) -> int: ...

    @property
    @abstractmethod
    def generation(self) -> int:
        """Number of completed ask/tell rounds."""

    @property
    def done(self) -> bool:
        """True once the configured number of generations has been told."""
        return self.generation >= int(getattr(self.config, "generations", 0))


class ArchiveExplorer(Explorer):
    """The state every generational explorer here shares: its RNG, novelty archive and archive policy,
    the generation and attempt counters, and the batch handed out by ``ask`` and not yet told.

    Subclasses set ``config_class`` and add their own state through ``_extra_state`` / ``_load_extra_state``.
    """

    config_class: type

    def __init__(self, config: Any, rng_seed: int) -> None:
        self.config = build_config(self.config_class, config)
        self.rng = np.random.default_rng(rng_seed)
        self.archive = Archive()
        self.policy = self._make_policy()
        self._generation = 0
        self._next_index = 0
        self._pending: list[Candidate] = []
        self._pending_clones: list[Clone] = []
        self._asked = False  # a batch is out (ask called, tell not yet)
        # Every genome tried so far -> (its attempt index, its descriptor or None when infeasible).
        self._outcomes: dict[str, tuple[int, np.ndarray | None]] = {}
        self.last_clones: list[Clone] = []  # the clones resolved by the last tell, for the sidecar

    @property
    def generation(self) -> int:
        return self._generation

    @property
    def archive_size(self) -> int:
        return len(self.archive)

    @property
    def batch_open(self) -> bool:
        """A batch was asked for and not told yet (after a resume: the one in flight at the commit point)."""
        return self._asked

    @property
    def attempts_asked(self) -> int:
        """Candidates handed out so far (attempt indices used), the open batch included."""
        return self._next_index

    def _make_policy(self):
        name = getattr(self.config, "archive_policy", "most_novel")
        return make_archive_policy(name, per_generation=self.config.archive_per_generation)

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        pass

    def _open_batch(self, batch: list[tuple[str, np.ndarray, int | None]], max_new: int | None) -> None:
        """Split proposed (kind, genome, parent) into candidates to evaluate and clones of tried genomes.

        With ``reuse_clones`` (the default) a genome tried before, or proposed twice in this batch, becomes a
        `Clone` of that attempt; otherwise every proposal is evaluated (the paper's literal re-simulation).
        ``max_new`` caps the candidates (the run's last generation); proposals past it are dropped.
        """
        reuse = bool(getattr(self.config, "reuse_clones", True))
        seen: dict[str, int] = {}
        cands: list[Candidate] = []
        clones: list[Clone] = []
        for kind, genome, parent in batch:
            key = genome_key(kind, genome)
            if reuse and key in self._outcomes:
                clones.append(Clone(self._generation, kind, genome, parent, self._outcomes[key][0]))
            elif reuse and key in seen:
                clones.append(Clone(self._generation, kind, genome, parent, seen[key]))
            elif max_new is None or len(cands) < max_new:
                seen[key] = self._next_index
                cands.append(Candidate(self._next_index, self._generation, kind, genome, parent))
                self._next_index += 1
        self._pending, self._pending_clones, self._asked = cands, clones, True

    def _issued(self) -> list[Candidate]:
        return [dataclasses.replace(c, genome=c.genome.copy()) for c in self._pending]

    def _resolve(self, codes: list[np.ndarray | None]) -> list[np.ndarray | None]:
        """Record the told outcomes; return each pending clone's reused descriptor."""
        for c, code in zip(self._pending, codes, strict=True):
            self._outcomes[genome_key(c.kind, c.genome)] = (c.index, code)
        return [self._outcomes[genome_key(c.kind, c.genome)][1] for c in self._pending_clones]

    def _close_batch(self) -> None:
        self.last_clones = self._pending_clones
        self._pending, self._pending_clones, self._asked = [], [], False
        self._generation += 1

    def state_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "config": dataclasses.asdict(self.config),
            "rng": self.rng.bit_generator.state,
            "generation": self._generation,
            "next_index": self._next_index,
            "asked": self._asked,
            "pending": [dataclasses.asdict(c) for c in self._pending],
            "pending_clones": [dataclasses.asdict(c) for c in self._pending_clones],
            "outcomes": _pack_outcomes(self._outcomes),
            "archive": self.archive.state_dict(),
            **self._extra_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("name") != self.name:
            raise ValueError(f"state is for explorer {state.get('name')!r}, not {self.name!r}")
        self.config = build_config(self.config_class, dict(state["config"]))
        self.policy = self._make_policy()
        self.rng.bit_generator.state = state["rng"]
        self._generation = int(state["generation"])
        self._next_index = int(state["next_index"])
        self._pending = [Candidate(**{**c, "genome": np.array(c["genome"])}) for c in state["pending"]]
        self._pending_clones = [Clone(**{**c, "genome": np.array(c["genome"])}) for c in state["pending_clones"]]
        self._asked = bool(state["asked"])
        self._outcomes = _unpack_outcomes(state["outcomes"])
        self.archive = Archive()
        self.archive.load_state_dict(state["archive"])
        self._load_extra_state(state)


def build_config[C](cls: type[C], config: C | dict[str, Any] | None) -> C:
    """Turn ``None``, a dict or an instance into a validated config dataclass of type ``cls``."""
    if config is None:
        return cls()
    if isinstance(config, cls):
        return dataclasses.replace(config)  # re-run validation, detach from the caller
    if isinstance(config, dict):
        names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        unknown = sorted(set(config) - names)
        if unknown:
            raise ValueError(f"unknown {cls.__name__} options: {unknown}; known: {sorted(names)}")
        return cls(**config)
    raise TypeError(f"expected {cls.__name__}, dict or None, got {type(config).__name__}")


def check_descriptors(
    pending: list[Candidate], candidates: list[Candidate], descriptors: list[np.ndarray | None], asked: bool = True
) -> list[np.ndarray | None]:
    """Check a ``tell`` call against the outstanding batch; returns the descriptors as 1-D uint64 arrays."""
    if not asked:
        raise RuntimeError("tell() called without an outstanding ask()")
    if len(candidates) != len(descriptors):
        raise ValueError(f"{len(candidates)} candidates but {len(descriptors)} descriptors")
    if [c.index for c in candidates] != [c.index for c in pending]:
        raise ValueError("tell() must receive the candidates of the last ask(), in the same order")
    out: list[np.ndarray | None] = []
    width: int | None = None
    for d in descriptors:
        if d is None:
            out.append(None)
            continue
        a = np.asarray(d)
        if a.dtype != np.uint64 or a.ndim != 1:
            raise ValueError(f"a descriptor must be a 1-D uint64 array, got {a.shape} {a.dtype}")
        if width is not None and a.shape[0] != width:
            raise ValueError("descriptors of one batch must have the same width")
        width = a.shape[0]
        out.append(a)
    return out
