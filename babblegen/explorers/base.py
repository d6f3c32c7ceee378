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
from babblegen.starts import NEW_START, Start, StartDraw, StartSampler

__all__ = [
    "NEW_START",
    "Batch",
    "Candidate",
    "Clone",
    "Evaluation",
    "Explorer",
    "ask_while_possible",
    "build_config",
    "check_descriptors",
    "genome_key",
]

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
    start: Start | None = None  # the varied start it runs from (None: the task's fixed scene)


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
    start: Start | None = None  # the varied start it (and its source) ran from


def genome_key(kind: str, genome: np.ndarray, start: Start | None = None) -> str:
    """Identity of a command: equal keys mean the same movement from the same start (the world is deterministic).
    A 128-bit digest of the exact float64 bytes, so the run state stays small however long genomes grow."""
    raw = np.ascontiguousarray(genome, dtype=np.float64).tobytes()
    if start is not None:
        raw += b"start" + start.key()
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


@dataclass
class Batch:
    """One generation's proposals as asked: the candidates to evaluate and the clones of tried genomes."""

    generation: int
    candidates: list[Candidate]
    clones: list[Clone]


class Explorer(ABC):
    """Generational ask/tell explorer whose generations may overlap by a fixed number.

    ``ask`` opens the next generation's batch and returns its candidates (possibly none, when every proposal
    repeats a genome already tried); ``can_ask`` says whether another batch may be opened before the oldest
    open one is told (NovEB's ``lag``). ``tell`` takes the oldest open batch's candidates in the same order with
    one descriptor each (``None`` when the candidate was infeasible); afterwards ``last_clones`` lists the
    proposals that reused earlier outcomes. ``open_batches`` re-issues the open batches (after a resume).
    ``ask(max_new=n)`` caps the batch at n candidates.

    The order of calls alone decides what is proposed: a caller that always asks while ``can_ask`` holds and
    tells batches in the order asked gets the same search whatever evaluates the candidates, and however fast.
    """

    name: str
    config: Any

    last_clones: list[Clone]

    @abstractmethod
    def ask(self, max_new: int | None = None) -> list[Candidate]: ...

    @abstractmethod
    def tell(self, candidates: list[Candidate], descriptors: list[np.ndarray | None]) -> list[Evaluation]: ...

    @property
    @abstractmethod
    def can_ask(self) -> bool:
        """Whether ``ask`` may open another batch now."""

    @abstractmethod
    def open_batches(self) -> list[list[Candidate]]:
        """The candidates of every batch asked and not told yet, oldest first."""

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
    @abstractmethod
    def attempts_asked(self) -> int:
        """Candidates handed out so far (attempt indices used), the open batches included."""

    @property
    def done(self) -> bool:
        """True once the configured number of generations has been told."""
        return self.generation >= int(getattr(self.config, "generations", 0))


def ask_while_possible(explorer: Explorer, max_attempts: int | None, generations: int) -> list[list[Candidate]]:
    """Open every batch the explorer allows now, short of ``max_attempts`` attempts and ``generations``
    generations (the run's: a resume may extend them): the one rule by which the run loop and the benchmarks
    interleave asks and tells, so that they explore alike."""
    asked: list[list[Candidate]] = []
    while explorer.can_ask:
        if explorer.generation + len(explorer.open_batches()) >= generations:
            break
        if max_attempts is not None and explorer.attempts_asked >= max_attempts:
            break
        left = None if max_attempts is None else max_attempts - explorer.attempts_asked
        asked.append(explorer.ask(max_new=left))
    return asked


class ArchiveExplorer(Explorer):
    """The state every generational explorer here shares: its RNG, novelty archive and archive policy,
    the generation and attempt counters, and the batches handed out by ``ask`` and not yet told.

    Subclasses set ``config_class``, implement ``_propose`` (the next batch's proposals), and add their own state
    through ``_extra_state`` / ``_load_extra_state``; ``max_open`` bounds the batches open at once.
    """

    config_class: type
    max_open = 1

    def __init__(self, config: Any, rng_seed: int, starts: StartSampler | None = None) -> None:
        self.config = build_config(self.config_class, config)
        self.starts = starts  # None: every attempt starts from the task's fixed scene
        self.rng = np.random.default_rng(rng_seed)
        self.archive = Archive()
        self.policy = self._make_policy()
        self._generation = 0
        self._next_index = 0
        self._open: list[Batch] = []  # asked, not told, oldest first
        # Every genome tried so far -> (its attempt index, its descriptor or None when infeasible) ...
        self._outcomes: dict[str, tuple[int, np.ndarray | None]] = {}
        self._in_flight: dict[str, int] = {}  # ... and those asked but not told yet -> their attempt index
        self.last_clones: list[Clone] = []  # the clones resolved by the last tell, for the sidecar

    @property
    def generation(self) -> int:
        return self._generation

    @property
    def archive_size(self) -> int:
        return len(self.archive)

    @property
    def batch_open(self) -> bool:
        """A batch was asked for and not told yet (after a resume: those in flight at the commit point)."""
        return bool(self._open)

    @property
    def attempts_asked(self) -> int:
        """Candidates handed out so far (attempt indices used), the open batches included."""
        return self._next_index

    @property
    def can_ask(self) -> bool:
        return len(self._open) < self.max_open

    def open_batches(self) -> list[list[Candidate]]:
        return [self._copies(b.candidates) for b in self._open]

    def ask(self, max_new: int | None = None) -> list[Candidate]:
        if not self.can_ask:
            raise RuntimeError(f"{len(self._open)} batches are open: tell the oldest before asking another")
        self._open_batch(self._propose(), max_new)
        return self._copies(self._open[-1].candidates)

    @abstractmethod
    def _propose(self) -> list[tuple[str, np.ndarray, int | None, Start | StartDraw | None]]:
        """The next batch's proposals as (kind, genome, parent attempt, start): with varied starts a start is a
        parent's `Start` or a `StartDraw`, drawn for the attempt the proposal becomes; None with fixed starts."""

    def _make_policy(self):
        name = getattr(self.config, "archive_policy", "most_novel")
        return make_archive_policy(name, per_generation=self.config.archive_per_generation)

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        pass

    def _open_batch(self, batch: list[tuple[str, np.ndarray, int | None, Any]], max_new: int | None) -> None:
        """Split proposed (kind, genome, parent, start) into candidates to evaluate and clones of tried genomes.

        A `StartDraw` is drawn for the attempt index the proposal gets, so it is never a clone. With
        ``reuse_clones`` (the default) a genome tried before from the same start, still in flight in an earlier
        open batch, or proposed twice in this batch, becomes a `Clone` of that attempt (resolved when its batch is
        told, which is never before the attempt it copies); otherwise every proposal is evaluated (the paper's
        literal re-simulation). ``max_new`` caps the candidates (the run's last generation); proposals past it are
        dropped.
        """
        reuse = bool(getattr(self.config, "reuse_clones", True))
        generation = self._generation + len(self._open)
        cands: list[Candidate] = []
        clones: list[Clone] = []
        for kind, genome, parent, start in batch:
            if isinstance(start, StartDraw):
                if max_new is not None and len(cands) >= max_new:
                    continue
                start = start.resolve(self.starts, self._next_index)
            key = genome_key(kind, genome, start)
            if reuse and key in self._outcomes:
                clones.append(Clone(generation, kind, genome, parent, self._outcomes[key][0], start=start))
            elif reuse and key in self._in_flight:
                clones.append(Clone(generation, kind, genome, parent, self._in_flight[key], start=start))
            elif max_new is None or len(cands) < max_new:
                self._in_flight.setdefault(key, self._next_index)
                cands.append(Candidate(self._next_index, generation, kind, genome, parent, start))
                self._next_index += 1
        self._open.append(Batch(generation, cands, clones))

    @staticmethod
    def _copies(candidates: list[Candidate]) -> list[Candidate]:
        return [dataclasses.replace(c, genome=c.genome.copy()) for c in candidates]

    @property
    def _pending(self) -> list[Candidate]:
        """The candidates of the oldest open batch (the one ``tell`` takes next)."""
        return self._open[0].candidates if self._open else []

    @property
    def _pending_clones(self) -> list[Clone]:
        return self._open[0].clones if self._open else []

    def _check_tell(self, candidates: list[Candidate], descriptors: list[np.ndarray | None]):
        return check_descriptors(self._pending, candidates, descriptors, bool(self._open))

    def _resolve(self, codes: list[np.ndarray | None]) -> list[np.ndarray | None]:
        """Record the oldest batch's told outcomes; return each of its clones' reused descriptor."""
        for c, code in zip(self._pending, codes, strict=True):
            key = genome_key(c.kind, c.genome, c.start)
            self._outcomes[key] = (c.index, code)
            if self._in_flight.get(key) == c.index:
                del self._in_flight[key]
        return [self._outcomes[genome_key(c.kind, c.genome, c.start)][1] for c in self._pending_clones]

    def _close_batch(self) -> None:
        self.last_clones = self._open.pop(0).clones
        self._generation += 1

    def state_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "config": dataclasses.asdict(self.config),
            "rng": self.rng.bit_generator.state,
            "generation": self._generation,
            "next_index": self._next_index,
            "open": [
                {
                    "generation": b.generation,
                    "candidates": [_stored(c) for c in b.candidates],
                    "clones": [_stored(c) for c in b.clones],
                }
                for b in self._open
            ],
            "outcomes": _pack_outcomes(self._outcomes),
            "archive": self.archive.state_dict(),
            **self._extra_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("name") != self.name:
            raise ValueError(f"state is for explorer {state.get('name')!r}, not {self.name!r}")
        self.config = build_config(self.config_class, self._stored_config(dict(state["config"])))
        self.policy = self._make_policy()
        self.rng.bit_generator.state = state["rng"]
        self._generation = int(state["generation"])
        self._next_index = int(state["next_index"])
        if "open" in state:
            batches = state["open"]
        else:  # stored before batches could overlap: at most one, open if asked
            batches = [
                {"generation": self._generation, "candidates": state["pending"], "clones": state["pending_clones"]}
            ][: int(bool(state["asked"]))]
        self._open = [
            Batch(
                int(b["generation"]),
                [Candidate(**_loaded(c)) for c in b["candidates"]],
                [Clone(**_loaded(c)) for c in b["clones"]],
            )
            for b in batches
        ]
        self._outcomes = _unpack_outcomes(state["outcomes"])
        self._in_flight = {}
        for b in self._open:
            for c in b.candidates:
                self._in_flight.setdefault(genome_key(c.kind, c.genome, c.start), c.index)
        self.archive = Archive()
        self.archive.load_state_dict(state["archive"])
        self._load_extra_state(state)

    @classmethod
    def _stored_config(cls, config: dict[str, Any]) -> dict[str, Any]:
        """A configuration as a checkpoint stored it, in this version's terms (subclasses upgrade old ones)."""
        return config


def _stored(item: Candidate | Clone) -> dict[str, Any]:
    """A candidate or clone as the checkpoint stores it (its start as plain values, none with fixed starts)."""
    out = dataclasses.asdict(item)
    out["start"] = None if item.start is None else item.start.to_dict()
    return out


def _loaded(stored: dict[str, Any]) -> dict[str, Any]:
    """`_stored`'s inverse, as keyword arguments (checkpoints stored before starts varied have none)."""
    return {**stored, "genome": np.array(stored["genome"]), "start": Start.from_dict(stored.get("start"))}


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
