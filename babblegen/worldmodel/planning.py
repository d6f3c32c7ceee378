"""Planning with a learned world model, scored in the real simulator.

A goal is an object's end position in a held-out executed episode, from that episode's start: known to be
reachable. For each goal, K candidate movements run from the same start: the goal episode's own genome, mutations
of it (every waypoint moved by a Gaussian of ``sigma`` in normalised workspace units) and uniform random waypoint
genomes (1 to 4 waypoints in the workspace box, as `random_waypoints` draws them). Every candidate is executed once
in the simulator (seeded like any attempt, so the goal's own genome reproduces the goal) and its outcome kept, so
that many models are scored against the same executions:

- **model**: the candidate whose predicted end position of the goal object is nearest the goal is chosen (among
  candidates predicted equally near, one at random: counted as their mean success); a success when that candidate's
  true end position lies within ``success_cm`` of the goal;
- **oracle**: a success when any candidate's does (the best of the same K, executed);
- **random**: the share of the feasible candidates that succeed (a candidate chosen at random);
- **share**: model / oracle.

Infeasible candidates (no plan) are known before anything runs and are never chosen.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from babblegen.worldmodel.episodes import EpisodeSet, object_distance_moved
from babblegen.worldmodel.model import WorldModel, object_state

CANDIDATE_ATTEMPTS = 1_000_000_000  # attempt indices of the candidates: far from any run's own
_STREAM = 0x91A4  # the goals' and candidates' own random stream


@dataclass(frozen=True)
class PlanningSettings:
    goals: int = 40
    candidates: int = 16
    success_cm: float = 3.0
    min_move_cm: float = 5.0  # a goal moves its object at least this far (so "leave it" is no success)
    sigma: float = 0.1
    seed: int = 0

    def key(self, test: EpisodeSet) -> str:
        """What the executed candidates depend on: these settings and the test episodes."""
        raw = json.dumps([asdict(self), sorted(set(test.source.tolist())), test.identity.tolist()]).encode()
        return hashlib.blake2b(raw, digest_size=12).hexdigest()


@dataclass
class PlanningTask:
    """Goals and the outcomes of their executed candidates."""

    goal_object: np.ndarray  # (G,) object index
    goal_xy: np.ndarray  # (G, 2) metres
    first: np.ndarray  # (G, K, 4) the start's object states
    joints0: np.ndarray  # (G, 7) the arm's first joints
    feasible: np.ndarray  # (G, C) bool
    actions: list[list[np.ndarray]]  # per goal, per candidate: (T, 7) commanded joints (empty when infeasible)
    final_xy: np.ndarray  # (G, C, 2) the goal object's true end position (nan when infeasible)
    objects: np.ndarray | None = None  # (G, K, P) the start's objects (`object_vector`s; None: the task's)

    def successes(self, success_cm: float) -> np.ndarray:
        """(G, C) whether each candidate reached its goal."""
        d = np.linalg.norm(self.final_xy - self.goal_xy[:, None], axis=-1)
        return np.nan_to_num(d, nan=np.inf) <= success_cm / 100

    def save(self, path: Path, key: str) -> None:
        lengths = np.array([len(a) for row in self.actions for a in row], dtype=np.int64)
        flat = [a for row in self.actions for a in row if len(a)]
        np.savez_compressed(
            path,
            key=key,
            goal_object=self.goal_object,
            goal_xy=self.goal_xy,
            first=self.first,
            joints0=self.joints0,
            feasible=self.feasible,
            final_xy=self.final_xy,
            lengths=lengths,
            actions=np.concatenate(flat) if flat else np.zeros((0, 7)),
            objects=np.zeros(0) if self.objects is None else self.objects,
        )

    @classmethod
    def load(cls, path: Path, key: str) -> PlanningTask | None:
        """The task stored at ``path`` if it was made for ``key``, else None."""
        if not path.is_file():
            return None
        with np.load(path) as f:
            if str(f["key"]) != key or "objects" not in f.files:  # made before objects were stored: again
                return None
            data = {name: f[name] for name in f.files}
        g, c = data["feasible"].shape
        ends = np.cumsum(data["lengths"])
        flat = np.split(data["actions"], ends[:-1]) if len(ends) else []
        actions = [[flat[i * c + j] for j in range(c)] for i in range(g)]
        return cls(
            data["goal_object"], data["goal_xy"], data["first"], data["joints0"], data["feasible"], actions,
            data["final_xy"], data["objects"] if data["objects"].size else None,
        )  # fmt: skip


def choose_goals(test: EpisodeSet, settings: PlanningSettings) -> list[tuple[int, int]]:
    """(episode, object) goals: waypoint episodes whose most-moved object moved at least ``min_move_cm`` and ended
    on the table, drawn at random without repeating an episode."""
    moved = object_distance_moved(test)
    final = test.final
    x0, x1, y0, y1 = test.scene.table
    on_table = (final[..., 0] > x0) & (final[..., 0] < x1) & (final[..., 1] > y0) & (final[..., 1] < y1)
    pool = []
    for e in range(len(test)):
        k = int(np.argmax(moved[e]))
        if test.commands[e]["kind"] == "ee_waypoints" and moved[e, k] * 100 >= settings.min_move_cm and on_table[e, k]:
            pool.append((e, k))
    rng = np.random.default_rng([settings.seed, _STREAM])
    order = rng.permutation(len(pool))[: settings.goals]
    return [pool[i] for i in sorted(order)]


def candidate_genomes(genome: np.ndarray, n: int, sigma: float, rng: np.random.Generator) -> list[np.ndarray]:
    """The goal's genome, then mutations of it, then uniform random waypoint genomes: ``n`` in all."""
    mutated = (n - 1) // 2
    out = [genome]
    out += [genome + rng.normal(0.0, sigma, genome.shape) for _ in range(mutated)]
    out += [rng.uniform(0.0, 1.0, (int(rng.integers(1, 5)), 3)) for _ in range(n - 1 - mutated)]
    return out


def build_task(test: EpisodeSet, settings: PlanningSettings, workers: int, cache: Path | None, echo=print):
    """The goals of ``test`` and their candidates, executed (or read from ``cache`` when made for the same key)."""
    key = settings.key(test)
    if cache is not None and (task := PlanningTask.load(cache, key)) is not None:
        echo(f"planning: {len(task.goal_object)} goals x {task.feasible.shape[1]} candidates read from {cache}")
        return task
    goals = choose_goals(test, settings)
    if not goals:
        return None
    rng = np.random.default_rng([settings.seed, _STREAM, 1])
    jobs = []
    for g, (e, _) in enumerate(goals):
        command = test.commands[e]
        genomes = candidate_genomes(
            np.asarray(command["genome"], dtype=np.float64), settings.candidates, settings.sigma, rng
        )
        for c, genome in enumerate(genomes):
            attempt = int(test.attempt[e]) if c == 0 else CANDIDATE_ATTEMPTS + g * settings.candidates + c
            jobs.append((str(test.source[e]), attempt, genome.tolist(), command["layout"], command.get("objects")))
    echo(f"planning: executing {len(goals)} goals x {settings.candidates} candidates ({len(jobs)} movements)")
    results = execute(jobs, workers)
    c = settings.candidates
    final_xy = np.full((len(goals), c, 2), np.nan)
    feasible = np.zeros((len(goals), c), dtype=bool)
    actions: list[list[np.ndarray]] = []
    for g, (_, k) in enumerate(goals):
        row = []
        for j in range(c):
            ok, action, final = results[g * c + j]
            feasible[g, j] = ok
            row.append(action)
            if ok:
                final_xy[g, j] = final[k, :2]
        actions.append(row)
    episodes = [e for e, _ in goals]
    task = PlanningTask(
        goal_object=np.array([k for _, k in goals]),
        goal_xy=np.stack([test.final[e, k, :2] for e, k in goals]),
        first=object_state(test.first[episodes]),
        joints0=np.stack([test.states[e][0] for e in episodes]),
        feasible=feasible,
        actions=actions,
        final_xy=final_xy,
        objects=test.objects[episodes],
    )
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        task.save(cache, key)
    return task


def plan_scores(model: WorldModel, task: PlanningTask, success_cm: float) -> dict[str, float]:
    """Success rates of the model's choice, the oracle's and a random choice, and the model's share of the oracle."""
    success = task.successes(success_cm)
    picks = []
    for g in range(len(task.goal_object)):
        live = np.flatnonzero(task.feasible[g])
        if not len(live):
            picks.append(False)
            continue
        objects = {} if task.objects is None else {"objects": [task.objects[g]] * len(live)}
        pred = model.rollout(
            [task.first[g]] * len(live), [task.actions[g][j] for j in live], [task.joints0[g]] * len(live), **objects
        )
        miss = np.linalg.norm(pred[:, task.goal_object[g], :2] - task.goal_xy[g], axis=-1)
        # candidates predicted equally near (none predicted to move, say): one of them at random, as expected value
        tied = live[np.isclose(miss, miss.min(), rtol=0.0, atol=1e-9)]
        picks.append(float(success[g, tied].mean()))
    oracle = float(success.any(axis=1).mean())
    rate = float(np.mean(picks))
    random_rate = float(np.mean([success[g, task.feasible[g]].mean() if task.feasible[g].any() else 0.0
                                 for g in range(len(success))]))  # fmt: skip
    return {"model": rate, "oracle": oracle, "random": random_rate, "share": rate / oracle if oracle else float("nan")}


# --- executing candidates in worker processes ------------------------------------------------------------------

_worlds: dict = {}


def _rollout(job: tuple[str, int, list, list | None, list | None]) -> tuple[bool, np.ndarray, np.ndarray | None]:
    """One candidate in this process's World for its dataset (built on first use), from the goal episode's start
    and objects (its sidecar row's; None: the task's)."""
    from babblegen.config import resumed_config
    from babblegen.evaluation import seeded_rollout, warm_up
    from babblegen.exporters.sidecar import read_run_info
    from babblegen.scene import ObjectSpec
    from babblegen.tasks import get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World

    root, attempt, genome, layout, objects = job
    if root not in _worlds:
        if not _worlds:  # leave without the interpreter's teardown, where OMPL's binding reports spurious leaks
            atexit.register(os._exit, 0)
        config = resumed_config(read_run_info(Path(root))["config"])
        world = World(get_task(config.task), config.world, seed=config.seed)
        warm_up(world, None)
        _worlds[root] = (world, config.seed)
    world, seed = _worlds[root]
    objects = None if objects is None else tuple(ObjectSpec.from_factors(o) for o in objects)
    command = Command("ee_waypoints", np.asarray(genome), None if layout is None else np.asarray(layout), objects)
    rollout = seeded_rollout(world, command, seed, attempt, defer_render=True)
    if not rollout.feasible:
        return False, np.zeros((0, 7)), None
    frames = rollout.frames
    action = np.asarray(frames.action, dtype=np.float32).astype(np.float64)  # as the dataset stores it
    return True, action, object_state(np.asarray(frames.object_poses[-1], dtype=np.float32).astype(np.float64))


def execute(jobs: list, workers: int) -> list:
    """Every job's (feasible, commanded joints, final object states), in order, on ``workers`` processes."""
    if workers <= 1:
        return [_rollout(job) for job in jobs]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        return list(pool.map(_rollout, jobs, chunksize=4))
