"""The cem planner with the true simulator as its model: how far the search itself gets when every prediction is
right, the ceiling a learned model's planning is measured against.

`SimulatorModel` answers `WorldModel.rollout` by executing each scored candidate in the simulator from its goal's
start, seeded as the planner's executed choice is (attempt ``PLAN_ATTEMPTS`` + goal): so the end it predicts for
the chosen genome is, to the bit, where the executed choice ends. A model is handed commanded joint trajectories;
`GenomeRecorder`, wrapped around the search's `Commander`, remembers which genome and which goal each trajectory
came from (`cem_plan` scores its goals' samples in goal order, ``samples`` each).
"""

from __future__ import annotations

import time

import numpy as np

from babblegen.worldmodel.planning import PLAN_ATTEMPTS, PlanningTask, _rollout, commander
from babblegen.worldmodel.planning_cem import CemSettings, cem_plan


class GenomeRecorder:
    """A `Commander` that remembers, per commanded trajectory it makes, its genome and its goal's position."""

    def __init__(self, inner, samples: int):
        self.inner, self.samples = inner, samples
        self.origin: dict[bytes, tuple[np.ndarray, int]] = {}
        self._paths: dict[int, tuple[np.ndarray, int]] = {}

    def joint_paths(self, genomes: list[np.ndarray]) -> list[np.ndarray | None]:
        paths = self.inner.joint_paths(genomes)
        self._paths = {id(p): (g, i // self.samples) for i, (g, p) in enumerate(zip(genomes, paths, strict=True))}
        return paths

    def actions(self, path: np.ndarray) -> np.ndarray | None:
        out = self.inner.actions(path)
        if out is not None:
            self.origin[out.tobytes()] = self._paths[id(path)]
        return out

    def direct(self, paths: list[np.ndarray]) -> list[bool]:
        return self.inner.direct(paths)


class SimulatorModel:
    """The true simulator in a world model's place, for the goals ``goals`` (indices into ``task``) of one test
    dataset ``root``, searched together."""

    def __init__(self, task: PlanningTask, root: str, goals: list[int], recorder: GenomeRecorder):
        self.task, self.root, self.goals, self.recorder = task, root, goals, recorder
        self.runs = 0

    def execute(self, goal: int, genome: np.ndarray) -> np.ndarray | None:
        """(K, 4) final object states of ``genome`` run from goal ``goal``'s start (None: infeasible)."""
        specs = self.task.specs[goal] if self.task.specs else None
        job = (self.root, PLAN_ATTEMPTS + goal, "ee_waypoints", genome.tolist(), self.task.start[goal], specs)
        ok, _, final = _rollout(job)
        self.runs += 1
        return final if ok else None

    def rollout(self, first, actions, joints0, objects=None) -> np.ndarray:
        out = []
        for f, a in zip(first, actions, strict=True):
            genome, at = self.recorder.origin[np.asarray(a).tobytes()]
            final = self.execute(self.goals[at], genome)
            out.append(np.full((len(f), 4), 1e3) if final is None else final)  # infeasible: nowhere near any goal
        return np.stack(out)


def simulator_search(task: PlanningTask, goals: list[int], cem: CemSettings, seed: int = 0) -> dict:
    """CEM with `SimulatorModel` on ``goals``; each choice then executed as the planner executes it. Per goal the
    predicted and the executed miss (metres; nan: no plan or infeasible), the simulator runs and the seconds."""
    started = time.perf_counter()
    predicted = np.full(len(task.goal_object), np.nan)
    executed = np.full(len(task.goal_object), np.nan)
    runs = 0
    for root in sorted({str(task.source[g]) for g in goals}):
        mine = [g for g in goals if str(task.source[g]) == root]
        recorder = GenomeRecorder(commander(root), cem.samples)
        model = SimulatorModel(task, root, mine, recorder)
        idx = np.array(mine)
        objects = None if task.objects is None else task.objects[idx]
        result = cem_plan(
            model, recorder, task.first[idx], task.joints0[idx], task.goal_object[idx], task.goal_xy[idx], cem, seed,
            objects,
        )  # fmt: skip
        for j, g in enumerate(mine):
            if result.genomes[j] is None:
                continue
            predicted[g] = result.predicted_miss[j]
            final = model.execute(g, result.genomes[j])
            if final is not None:
                executed[g] = np.linalg.norm(final[task.goal_object[g], :2] - task.goal_xy[g])
        runs += model.runs
    return {
        "goals": list(goals),
        "predicted_miss": predicted[goals],
        "executed_miss": executed[goals],
        "runs": runs,
        "seconds": time.perf_counter() - started,
    }
