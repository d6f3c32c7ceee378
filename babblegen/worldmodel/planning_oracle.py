"""The cem planner with the true simulator as its model: how far the search itself gets when every prediction is
right, the ceiling a learned model's planning is measured against.

`SimulatorModel` answers `WorldModel.rollout` by executing each scored candidate in the simulator from its goal's
start, seeded as the planner's executed choice is (attempt ``PLAN_ATTEMPTS`` + goal): so the end it predicts for
the chosen genome is, to the bit, where the executed choice ends. A model is handed commanded joint trajectories;
`GenomeRecorder`, wrapped around the search's `Commander`, remembers which genome and which goal each trajectory
came from (`cem_plan` scores its goals' samples in goal order, ``samples`` each).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from babblegen.worldmodel.planning import PLAN_ATTEMPTS, PlanningTask
from babblegen.worldmodel.planning_cem import CemSettings, cem_plan
from babblegen.worldmodel.planning_sim import commander, simulate


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
        ok, _, final = simulate(job)
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


def ceiling_goals(task: PlanningTask, count: int, seed: int = 0) -> list[int]:
    """The fixed subset of a task's goals the ceiling is measured on: ``count`` of them, drawn by the planning seed
    (all of them when there are fewer), in goal order."""
    n = len(task.goal_object)
    if count >= n:
        return list(range(n))
    return sorted(np.random.default_rng([seed, 0xCE11]).permutation(n)[:count].tolist())


def _search_one(job: tuple[PlanningTask, int, CemSettings, int]) -> dict:
    task, goal, cem, seed = job
    return simulator_search(task, [goal], cem, seed)


def ceiling(task: PlanningTask, goals: list[int], cem: CemSettings, success_cm: float, seed: int, workers: int) -> dict:
    """The search's ceiling: CEM with the true simulator as its model on ``goals``, each choice executed, goals
    spread over ``workers`` processes (each goal's search is its own). Per goal its success, the rate over them
    with its 95 % bootstrap interval, the simulator runs and the seconds."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from babblegen.worldmodel.planning import bootstrap_ci

    started = time.perf_counter()
    jobs = [(task, g, cem, seed) for g in goals]
    if workers <= 1:
        parts = [_search_one(job) for job in jobs]
    else:
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            parts = list(pool.map(_search_one, jobs))
    executed = np.array([p["executed_miss"][0] for p in parts], dtype=np.float64)
    success = (np.nan_to_num(executed, nan=np.inf) <= success_cm / 100).astype(float)
    return {
        "goals": list(goals),
        "goal_success": success.tolist(),
        "rate": float(success.mean()) if len(success) else float("nan"),
        "ci95": bootstrap_ci(success),
        "executed_miss": [None if np.isnan(v) else float(v) for v in executed],
        "runs": int(sum(p["runs"] for p in parts)),
        "seconds": time.perf_counter() - started,
    }


def measured_ceiling(task: PlanningTask, settings, count: int, workers: int, cache: Path | None, key: str, echo=print):
    """`ceiling` on `ceiling_goals`' ``count`` goals with the planner's search (``settings``: `PlanningSettings`),
    read from ``cache`` when it was measured for the same goals and search, else measured and kept there."""
    cem = CemSettings(samples=settings.cem_samples, iterations=settings.cem_iterations, elites=settings.cem_elites)
    goals = ceiling_goals(task, count, settings.seed)
    tag = json.dumps([key, goals, asdict(cem), settings.success_cm, settings.seed])
    if cache is not None and cache.is_file():
        stored = json.loads(cache.read_text())
        if stored.get("key") == tag:
            echo(f"planning ceiling: {len(goals)} goals read from {cache}")
            return stored["ceiling"]
    echo(f"planning ceiling: the search with the true simulator as its model on {len(goals)} goals ...")
    result = ceiling(task, goals, cem, settings.success_cm, settings.seed, workers)
    echo(f"planning ceiling: {result['rate']:.3f} of {len(goals)} goals ({result['seconds']:.0f} s)")
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps({"key": tag, "ceiling": result}))
    return result
