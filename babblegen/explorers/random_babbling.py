"""Random motor babbling, the paper's control: uniform random joint targets for the arm.

Each ``ask`` returns ``population`` candidates of kind ``"joint_target"``, each drawn uniformly within the
joint limits (continuous joints are given as [-pi, pi]). The descriptors told back do not steer anything:
novelty is measured exactly as NovEB measures it (``k`` nearest among the batch and an archive that receives
the most novel new individual of each batch), so the two explorers' novelty columns can be compared.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from babblegen.explorers.base import (
    KIND_JOINTS,
    KIND_WAYPOINTS,
    NEW_START,
    ArchiveExplorer,
    Candidate,
    Evaluation,
)
from babblegen.novelty import ARCHIVE_POLICIES, novelty
from babblegen.starts import StartDraw, StartSampler

__all__ = ["RandomBabbling", "RandomBabblingConfig", "RandomWaypoints", "RandomWaypointsConfig"]


@dataclass
class RandomBabblingConfig:
    """Batch size, number of batches, and the novelty measurement (same meaning as in NovEB)."""

    population: int = 12
    generations: int = 2000
    k: int = 3
    archive_per_generation: int = 1
    archive_policy: str = "most_novel_unseen"

    def __post_init__(self) -> None:
        if int(self.population) != self.population or self.population < 1:
            raise ValueError(f"population must be an integer >= 1, got {self.population}")
        if int(self.generations) != self.generations or self.generations < 1:
            raise ValueError(f"generations must be an integer >= 1, got {self.generations}")
        if int(self.k) != self.k or self.k < 1:
            raise ValueError(f"k must be an integer >= 1, got {self.k}")
        if int(self.archive_per_generation) != self.archive_per_generation or self.archive_per_generation < 0:
            raise ValueError(f"archive_per_generation must be an integer >= 0, got {self.archive_per_generation}")
        if self.archive_policy not in ARCHIVE_POLICIES:
            raise ValueError(f"unknown archive_policy {self.archive_policy!r}; known: {sorted(ARCHIVE_POLICIES)}")


class RandomBabbling(ArchiveExplorer):
    """Uniform random joint targets; novelty is recorded for comparison only."""

    name = "random"
    config_class = RandomBabblingConfig
    # What is proposed depends on neither the outcomes nor their timing, so batches may be open at once freely:
    # 8 of the default 12 keep 96 movements available to run whatever evaluates them.
    max_open = 8

    def __init__(
        self,
        config: RandomBabblingConfig | dict[str, Any] | None = None,
        rng_seed: int = 0,
        *,
        joint_limits: np.ndarray,
        start_norm: np.ndarray | None = None,
        starts: StartSampler | None = None,
    ) -> None:
        super().__init__(config, rng_seed, starts)
        limits = np.asarray(joint_limits, dtype=np.float64)
        if limits.ndim != 2 or limits.shape[1] != 2 or not np.all(np.isfinite(limits)):
            raise ValueError(f"joint_limits must be a finite (n_joints, 2) array, got shape {limits.shape}")
        if np.any(limits[:, 0] > limits[:, 1]):
            raise ValueError("joint_limits must have lower <= upper for every joint")
        self.joint_limits = limits

    def _propose(self) -> list[tuple[str, np.ndarray, int | None, StartDraw | None]]:
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        targets = lo + (hi - lo) * self.rng.random((self.config.population, lo.shape[0]))
        return [(KIND_JOINTS, t, None, self._new_start) for t in targets]

    @property
    def _new_start(self) -> StartDraw | None:
        """Every attempt from a start of its own (drawn for its attempt index, as NovEB draws them), or None."""
        return NEW_START if self.starts is not None else None

    def tell(self, candidates: list[Candidate], descriptors: list[np.ndarray | None]) -> list[Evaluation]:
        codes = self._check_tell(candidates, descriptors)
        self._resolve(codes)
        evaluations = [Evaluation(None, False) for _ in codes]
        feasible = [i for i, d in enumerate(codes) if d is not None]
        if feasible:
            batch = np.stack([codes[i] for i in feasible])  # type: ignore[misc]
            nov = novelty(batch, batch, self.archive.descriptors, self.config.k)
            for j, i in enumerate(feasible):
                evaluations[i].novelty = float(nov[j])
            for j in self.policy.select(nov, batch, self.archive):
                c = self._pending[feasible[int(j)]]
                self.archive.add(batch[j], {"index": c.index, "generation": c.generation})
                evaluations[feasible[int(j)]].archived = True
        self._close_batch()
        return evaluations

    def _extra_state(self) -> dict[str, Any]:
        return {"joint_limits": self.joint_limits.copy()}

    def _load_extra_state(self, state: dict[str, Any]) -> None:
        self.joint_limits = np.asarray(state["joint_limits"], dtype=np.float64).copy()


@dataclass
class RandomWaypointsConfig(RandomBabblingConfig):
    """Random babbling's options, and the most waypoints a genome is drawn with."""

    max_waypoints: int = 4

    def __post_init__(self) -> None:
        super().__post_init__()
        if int(self.max_waypoints) != self.max_waypoints or self.max_waypoints < 1:
            raise ValueError(f"max_waypoints must be an integer >= 1, got {self.max_waypoints}")


class RandomWaypoints(RandomBabbling):
    """A control in NovEB's genome space: random waypoint lists (1 to ``max_waypoints`` points, each uniform in the
    normalised workspace box [0, 1]^3, the range of NovEB's first generation), with no novelty search and no
    selection. Against it, NovEB shows what its novelty search adds to aiming at the table."""

    name = "random_waypoints"
    config_class = RandomWaypointsConfig

    def _propose(self) -> list[tuple[str, np.ndarray, int | None, StartDraw | None]]:
        counts = self.rng.integers(1, self.config.max_waypoints + 1, size=self.config.population)
        return [(KIND_WAYPOINTS, self.rng.random((int(n), 3)), None, self._new_start) for n in counts]
