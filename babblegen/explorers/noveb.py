"""Novelty-driven Evolutionary Babbling (Maestre et al.): novelty search with NSGA-II survival.

Generation 0 asks ``population`` random genomes (one final point uniform in [0, 1]^3). Every later generation proposes
``children`` children of the current parents (those selected after the generation ``lag + 1`` before it, so that ``lag +
1`` generations can be evaluated at once): binary tournament on (rank, crowding), optional crossover, Gaussian mutation
with probability ``mutation_prob`` (of one waypoint, or of all with ``mutation_scope = "genome"``), and waypoint
extension with probability ``extend_prob`` (at most ``max_waypoints``) or removal with probability ``remove_prob`` (of
a genome longer than ``remove_above``). A child that is neither mutated nor extended nor shortened is a copy of its
parent. The simulation is deterministic, so such a clone (any genome tried before, or still being tried) reuses that
outcome instead of being simulated again (``reuse_clones``; off, it is evaluated again as in the paper's noisy
simulator). ``tell`` recomputes the novelty of
parents ∪ feasible children (clones included) against that union plus the archive, archives the most novel newly
evaluated child (by default only if the archive does not already hold its descriptor), and keeps ``population``
survivors by NSGA-II on the single objective novelty, i.e. elitist truncation, with ties broken by ``tie_break`` (by
default fewer waypoints first: parsimony pressure against genomes that grow without adding novelty).

With varied starts (`babblegen.starts`) each candidate also carries the start it runs from: the first generation
draws one per attempt; a child keeps its parent's, unless its genome is new and a start mutation
(``start_mutation_prob``) draws it another (with ``start_from_end``, the scene its parent's movement left); a clone is
the same genome from the same start.

Infeasible candidates (no IK solution or no collision-free plan: descriptor ``None``) have no behaviour, so
they get no novelty, are never archived and never survive selection; they still consume an attempt index.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from babblegen.explorers.base import (
    KIND_WAYPOINTS,
    NEW_START,
    ArchiveExplorer,
    Candidate,
    Evaluation,
)
from babblegen.genome import (
    crossover,
    extend,
    gaussian_mutation,
    random_genome,
    remove_waypoint,
    waypoint_mutation,
)
from babblegen.novelty import ARCHIVE_POLICIES, novelty
from babblegen.selection import binary_tournament, crowding_distance, non_dominated_sort, nsga2_select
from babblegen.starts import Start, StartDraw, StartSampler

__all__ = ["NovEB", "NovEBConfig", "upgrade_stored_config"]


@dataclass
class NovEBConfig:
    """NovEB parameters; the numbers are those of the paper's appendix. Where babblegen departs from the
    paper's procedure (docs/departures.md), the option restoring it is named.

    ``population`` parents breed ``children`` children per generation, and the ``population`` best of parents ∪
    children survive (the paper: 12 and 12, "50 % kept"; babblegen: 12 and 128, which explores more widely per
    attempt and gives about 40 new movements per generation to run at once). ``lag`` lets generations overlap:
    generation g is bred from the parents selected after generation g - 1 - lag, so up to ``lag + 1`` generations'
    movements can run at once (the paper: 0, each generation waits for the one before). Both are settings of the
    run, never of the hardware: the same seed gives the same search on one worker or a cluster. ``mutation_prob``
    and ``extend_prob`` are per individual; ``sigma`` is in normalised workspace units. Crossover is an option the
    paper does not use (``crossover_prob = 0``); see :func:`babblegen.genome.crossover`.
    """

    population: int = 12
    children: int = 128  # the paper: 12 (docs/departures.md: more children of the same parents)
    lag: int = 0
    generations: int = 2000
    k: int = 3
    mutation_prob: float = 0.3
    sigma: float = 0.3
    extend_prob: float = 0.05
    remove_prob: float = 0.05  # remove-waypoint probability (0: the paper, whose genomes only grow)
    # only a genome of more waypoints than this may lose one (1: any of 2 or more): removal bounds what long genomes
    # cost, and leaves short ones, which rarely reach an object, to grow (docs/departures.md)
    remove_above: int = 4
    crossover_prob: float = 0.0
    archive_per_generation: int = 1
    archive_policy: str = field(default="most_novel_unseen")
    tie_break: str = "shortest"  # among equal novelty: fewer waypoints, then newest ("oldest": the paper)
    mutation_scope: str = "waypoint"  # noise on one waypoint drawn at random ("genome": on all, the paper)
    reuse_clones: bool = True
    # extension stops at this many waypoints (None or 0: unbounded, the paper); with removal, a run's cost per
    # episode stays flat (docs/departures.md)
    max_waypoints: int | None = 8
    # a mutated waypoint beyond the arm's reach (known from its URDF alone) is drawn again, up to this many times
    # (0: never, the paper: the attempt is spent on a movement that cannot run); "waypoint" mutation scope only
    reach_redraws: int = 0
    # with varied starts: a child runs from its parent's start, or, with this probability, from a new one; which
    # children may draw one: "new_genomes" (those whose genome differs from their parent's: a copy of a parent
    # stays a clone, free) or "all_children" (copies too: the same movement from a new start); what it draws:
    # "new_layout" (every object drawn anew) or "move_one" (the parent's layout with one object placed anew).
    # Chosen by docs/start_states.md's measurements.
    start_mutation_prob: float = 0.5
    start_mutation_of: str = "new_genomes"
    start_mutation: str = "new_layout"
    # the share of start mutations that start from the scene the parent's own movement left instead (Go-Explore's
    # return to a found state: pushed, toppled and touching objects that placement rarely makes); a scene with an
    # object off the table top is not used (a new layout is drawn). 0: never, as before
    start_from_end: float = 0.0
    # the share of each generation's children drawn independently of the parents instead, as `random_waypoints`
    # draws (1 to 4 waypoints uniform in the workspace box; with varied starts, from a new start): the random
    # emitter of quality-diversity libraries (0: every child is bred, the paper)
    independent_share: float = 0.0

    def __post_init__(self) -> None:
        if int(self.population) != self.population or self.population < 2:
            raise ValueError(f"population must be an integer >= 2, got {self.population}")
        if int(self.children) != self.children or self.children < 1:
            raise ValueError(f"children must be an integer >= 1, got {self.children}")
        if int(self.lag) != self.lag or self.lag < 0:
            raise ValueError(f"lag must be an integer >= 0, got {self.lag}")
        if int(self.generations) != self.generations or self.generations < 1:
            raise ValueError(f"generations must be an integer >= 1, got {self.generations}")
        if int(self.k) != self.k or self.k < 1:
            raise ValueError(f"k must be an integer >= 1, got {self.k}")
        probabilities = ("mutation_prob", "extend_prob", "remove_prob", "crossover_prob", "start_mutation_prob")
        for name in (*probabilities, "independent_share", "start_from_end"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {p}")
        if self.extend_prob + self.remove_prob > 1.0:
            raise ValueError(f"extend_prob + remove_prob must be <= 1, got {self.extend_prob + self.remove_prob}")
        if int(self.remove_above) != self.remove_above or self.remove_above < 1:
            raise ValueError(f"remove_above must be an integer >= 1, got {self.remove_above}")
        if self.max_waypoints == 0:  # a settings file or flag's way to say "no bound"
            self.max_waypoints = None
        if self.max_waypoints is not None and (int(self.max_waypoints) != self.max_waypoints or self.max_waypoints < 1):
            raise ValueError(f"max_waypoints must be an integer >= 1 (0: no bound), got {self.max_waypoints}")
        if int(self.reach_redraws) != self.reach_redraws or self.reach_redraws < 0:
            raise ValueError(f"reach_redraws must be an integer >= 0, got {self.reach_redraws}")
        if not self.sigma >= 0.0:
            raise ValueError(f"sigma must be >= 0, got {self.sigma}")
        if int(self.archive_per_generation) != self.archive_per_generation or self.archive_per_generation < 0:
            raise ValueError(f"archive_per_generation must be an integer >= 0, got {self.archive_per_generation}")
        if self.archive_policy not in ARCHIVE_POLICIES:
            raise ValueError(f"unknown archive_policy {self.archive_policy!r}; known: {sorted(ARCHIVE_POLICIES)}")
        if self.mutation_scope not in MUTATION_SCOPES:
            raise ValueError(f"unknown mutation_scope {self.mutation_scope!r}; known: {list(MUTATION_SCOPES)}")
        if self.start_mutation not in START_MUTATIONS:
            raise ValueError(f"unknown start_mutation {self.start_mutation!r}; known: {list(START_MUTATIONS)}")
        if self.start_mutation_of not in START_MUTATION_OF:
            raise ValueError(f"unknown start_mutation_of {self.start_mutation_of!r}; known: {list(START_MUTATION_OF)}")
        if self.tie_break not in TIE_BREAKS:
            raise ValueError(f"unknown tie_break {self.tie_break!r}; known: {list(TIE_BREAKS)}")


def upgrade_stored_config(config: dict[str, Any]) -> dict[str, Any]:
    """A NovEB section stored by an earlier version, in this version's terms, meaning the same search: the
    number of children was ``population * (1 / keep_fraction - 1)``, generations did not overlap, and genomes grew
    without bound and never shrank, and mutations out of the arm's reach were not drawn again."""
    config = dict(config)
    config.setdefault("remove_prob", 0.0)  # stored before removal existed: genomes only grew ...
    config.setdefault("max_waypoints", None)  # ... without bound
    config.setdefault("remove_above", 1)  # stored before the setting: any genome of 2 or more could lose one
    config.setdefault("reach_redraws", 0)  # stored before the setting: a waypoint out of reach was run as drawn
    config.setdefault("independent_share", 0.0)  # stored before the setting: every child was bred
    config.setdefault("start_from_end", 0.0)  # ... and started from a placed layout
    if "keep_fraction" in config:
        kept = float(config.pop("keep_fraction"))
        config.setdefault("children", int(round(int(config.get("population", 12)) * (1.0 / kept - 1.0))))
    config.setdefault("lag", 0)
    return config


INDEPENDENT_WAYPOINTS = 4  # an independent child has 1 to this many waypoints, as `random_waypoints` draws
TIE_BREAKS = ("newest", "oldest", "random", "shortest")
START_MUTATION_OF = ("new_genomes", "all_children")
START_MUTATIONS = ("move_one", "new_layout")
MUTATION_SCOPES = ("genome", "waypoint")


class NovEB(ArchiveExplorer):
    """Novelty search over end-effector waypoint lists (see the module docstring for the generation flow)."""

    name = "noveb"
    config_class = NovEBConfig

    @classmethod
    def _stored_config(cls, config: dict[str, Any]) -> dict[str, Any]:
        return upgrade_stored_config(config)

    def __init__(
        self,
        config: NovEBConfig | dict[str, Any] | None = None,
        rng_seed: int = 0,
        *,
        start_norm: np.ndarray,
        joint_limits: np.ndarray | None = None,
        starts: StartSampler | None = None,
        in_reach: Callable[[np.ndarray], bool] | None = None,
    ) -> None:
        super().__init__(config, rng_seed, starts)
        start = np.asarray(start_norm, dtype=np.float64)
        if start.shape != (3,) or not np.all(np.isfinite(start)):
            raise ValueError(f"start_norm must be a finite (3,) array, got {start}")
        self.start_norm = start
        if self.config.reach_redraws and in_reach is None:
            raise ValueError("reach_redraws needs in_reach, the arm's reach as a test of a normalised waypoint")
        self.in_reach = in_reach
        # Current parents: genomes, descriptors (p, w), attempt indices, novelty at their last evaluation.
        self._parents: list[np.ndarray] = []
        self._parent_codes = np.zeros((0, 1), dtype=np.uint64)
        self._parent_index = np.zeros(0, dtype=np.int64)
        self._parent_novelty = np.zeros(0, dtype=np.float64)
        self._parent_starts: list[Start | None] = []  # the start each parent ran from (None: fixed starts)

    # ------------------------------------------------------------------ properties
    @property
    def parents(self) -> list[int]:
        """Attempt indices of the current parents (the survivors of the last selection)."""
        return [int(i) for i in self._parent_index]

    # ------------------------------------------------------------------ ask / tell
    @property
    def can_ask(self) -> bool:
        """A generation is bred from the parents selected after the one ``lag + 1`` before it: up to ``lag + 1``
        generations are open at once. The first waits for nothing; the second waits for the first to be told
        (there are no parents before)."""
        if not self._open:
            return True
        return bool(self._parents) and len(self._open) <= self.config.lag

    def _propose(self) -> list[tuple[str, np.ndarray, int | None, Start | StartDraw | None]]:
        if not self._parents:
            new = NEW_START if self.starts is not None else None
            proposals = [(random_genome(self.rng), None, new) for _ in range(self.config.population)]
        else:
            proposals = self._make_children()
        return [(KIND_WAYPOINTS, g, p, start) for g, p, start in proposals]

    def _make_children(self) -> list[tuple[np.ndarray, int | None, Start | StartDraw | None]]:
        """Children of the current parents. A crossover child runs from the start of the parent whose first
        waypoints it keeps (the tournament's first winner), as any other child does, unless a start mutation
        draws it a new one."""
        cfg = self.config
        n = cfg.children
        objectives = self._parent_novelty[:, None]
        rank = non_dominated_sort(objectives)
        crowd = crowding_distance(objectives, rank)
        first = binary_tournament(rank, crowd, n, self.rng)
        mates = binary_tournament(rank, crowd, n, self.rng)
        varied = self.starts is not None
        # crossover, mutation, extension decisions (and with varied starts, start mutation: fixed starts draw what
        # they always drew)
        draws = self.rng.random((n, 4 if varied else 3))
        children = []
        for i in range(n):
            p = int(first[i])
            g = self._parents[p]
            if draws[i, 0] < cfg.crossover_prob:
                g = crossover(g, self._parents[int(mates[i])], self.rng)
            if draws[i, 1] < cfg.mutation_prob:
                if cfg.mutation_scope == "waypoint":
                    g = waypoint_mutation(g, cfg.sigma, self.rng, self.in_reach, cfg.reach_redraws)
                else:
                    g = gaussian_mutation(g, cfg.sigma, self.rng)
            # one draw decides extension or removal (with removal off, the paper's draws exactly)
            if draws[i, 2] < cfg.extend_prob:
                if cfg.max_waypoints is None or len(g) < cfg.max_waypoints:
                    g = extend(g, self.start_norm, self.rng)
            elif draws[i, 2] < cfg.extend_prob + cfg.remove_prob and len(g) > cfg.remove_above:
                g = remove_waypoint(g, self.rng)
            start = self._parent_starts[p]
            may_move = cfg.start_mutation_of == "all_children" or not np.array_equal(g, self._parents[p])
            if varied and may_move and draws[i, 3] < cfg.start_mutation_prob * cfg.start_from_end:
                start = StartDraw(made_from=int(self._parent_index[p]))
            elif varied and may_move and draws[i, 3] < cfg.start_mutation_prob:
                start = StartDraw(start if cfg.start_mutation == "move_one" else None)
            children.append((np.array(g, dtype=np.float64), int(self._parent_index[p]), start))
        if cfg.independent_share > 0:  # drawn after the bred children, so that a share of 0 draws as before
            independent = np.flatnonzero(self.rng.random(n) < cfg.independent_share)
            counts = self.rng.integers(1, INDEPENDENT_WAYPOINTS + 1, size=len(independent))
            for i, count in zip(independent, counts, strict=True):
                children[i] = (self.rng.random((int(count), 3)), None, NEW_START if varied else None)
        return children

    def tell(self, candidates: list[Candidate], descriptors: list[np.ndarray | None]) -> list[Evaluation]:
        codes = self._check_tell(candidates, descriptors)
        pending, clones = self._pending, self._pending_clones
        clone_codes = self._resolve(codes)
        evaluations = [Evaluation(None, False) for _ in pending]
        # New individuals: feasible evaluated candidates, then clones of feasible genomes.
        fresh = [i for i, d in enumerate(codes) if d is not None]
        reused = [i for i, d in enumerate(clone_codes) if d is not None]
        new_codes_list = [codes[i] for i in fresh] + [clone_codes[i] for i in reused]
        if new_codes_list:
            n_par = len(self._parents)
            new_codes = np.stack(new_codes_list)  # type: ignore[arg-type]
            if n_par and self._parent_codes.shape[1] != new_codes.shape[1]:
                raise ValueError("descriptor width changed during the run")
            pool_codes = np.concatenate([self._parent_codes, new_codes]) if n_par else new_codes
            nov = novelty(pool_codes, pool_codes, self.archive.descriptors, self.config.k)
            new_nov = nov[n_par:]
            for j, i in enumerate(fresh):
                evaluations[i].novelty = float(new_nov[j])
            for j, i in enumerate(reused):
                clones[i].novelty = float(new_nov[len(fresh) + j])
            # Only evaluated individuals enter the archive: a clone's descriptor has been seen.
            for j in self.policy.select(new_nov[: len(fresh)], new_codes[: len(fresh)], self.archive):
                c = pending[fresh[int(j)]]
                self.archive.add(new_codes[j], {"index": c.index, "generation": c.generation})
                evaluations[fresh[int(j)]].archived = True
            pool_genomes = self._parents + [pending[i].genome for i in fresh] + [clones[i].genome for i in reused]
            pool_starts = self._parent_starts + [pending[i].start for i in fresh] + [clones[i].start for i in reused]
            pool_index = np.concatenate(
                [self._parent_index, [pending[i].index for i in fresh], [clones[i].source for i in reused]]
            )
            lengths = np.array([len(g) for g in pool_genomes])
            keep = nsga2_select(nov[:, None], min(self.config.population, len(pool_genomes)), self._tie_order(lengths))
            for k in keep:
                if k >= n_par + len(fresh):
                    clones[reused[int(k) - n_par - len(fresh)]].survived = True
            self._parents = [pool_genomes[i] for i in keep]
            self._parent_starts = [pool_starts[i] for i in keep]
            self._parent_codes = pool_codes[keep]
            self._parent_index = pool_index[keep].astype(np.int64)
            self._parent_novelty = nov[keep]
        self._close_batch()
        return evaluations

    def _tie_order(self, lengths: np.ndarray) -> np.ndarray:
        """Rank among equally novel individuals of the pool (parents first, then this generation's), given
        their numbers of waypoints. "shortest" is lexicographic parsimony pressure (Luke and Panait, 2002):
        fewer waypoints first, then the newest."""
        n = len(lengths)
        if self.config.tie_break == "oldest":
            return np.arange(n)
        if self.config.tie_break == "newest":
            return np.arange(n)[::-1].copy()
        if self.config.tie_break == "shortest":
            order = np.lexsort((np.arange(n)[::-1], lengths))
            ranks = np.empty(n, dtype=np.int64)
            ranks[order] = np.arange(n)
            return ranks
        return self.rng.permutation(n)

    # ------------------------------------------------------------------ checkpointing
    def _extra_state(self) -> dict[str, Any]:
        return {
            "start_norm": self.start_norm.copy(),
            "parents": [g.copy() for g in self._parents],
            "parent_codes": self._parent_codes.copy(),
            "parent_index": self._parent_index.copy(),
            "parent_novelty": self._parent_novelty.copy(),
            "parent_starts": [None if st is None else st.to_dict() for st in self._parent_starts],
        }

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        self.start_norm = np.asarray(state["start_norm"], dtype=np.float64).copy()
        self._parents = [np.array(g, dtype=np.float64) for g in state["parents"]]
        self._parent_codes = np.array(state["parent_codes"], dtype=np.uint64)
        self._parent_index = np.array(state["parent_index"], dtype=np.int64)
        self._parent_novelty = np.array(state["parent_novelty"], dtype=np.float64)
        # stored before starts varied: every parent ran from the fixed scene
        self._parent_starts = [Start.from_dict(st) for st in state.get("parent_starts", [None] * len(self._parents))]
