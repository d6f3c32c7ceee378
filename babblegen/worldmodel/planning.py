"""Planning with a learned world model, scored in the real simulator.

A goal is an object's end position in a held-out executed episode (an object that moved at least ``min_move_cm``
and ended on the table), from that episode's start: known to be reachable. Goals are counted per stratum: pushed by
the arm (the arm touched the goal object), pushed by another object (the arm never touched it, and the episode's
recorded contact events hold it meeting another object), moved far (``far_cm`` or more). Objects pushed by another
object are rare (a few in a hundred moved objects), so up to ``object_share`` of the goals are drawn from them; the
rest are each episode's most-moved object.

Two planners (``planner``):

- **cem** (the default): the cross-entropy method over waypoint genomes with the model alone
  (`planning_cem.cem_plan`); only its choice is executed, once, in the simulator. The goal's own movement is never
  among its samples;
- **rank**: the model ranks K executed candidates (the goal episode's own genome, mutations of it, random genomes)
  and the one predicted nearest is taken (ties: their mean success).

Model-free baselines, executed once per test set and kept (``PlanningTask``): the goal's own movement replayed
(seeded as its attempt was: 1.0 unless the simulator is not deterministic); ``candidates`` uniform random waypoint
genomes per goal, as `random_waypoints` draws them, each executed: **one random genome** is their mean success, the
**best of them** whether any succeeds (a search in the true simulator with a small budget). A success is the goal
object ending within ``success_cm`` of the goal; an infeasible movement fails. Every rate has a 95 % bootstrap
interval over goals.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from babblegen.worldmodel.episodes import PROPERTIES, EpisodeSet, object_distance_moved
from babblegen.worldmodel.planning_sim import commander, execute

CANDIDATE_ATTEMPTS = 1_000_000_000  # attempt indices of the executed baselines: far from any run's own
PLAN_ATTEMPTS = 2_000_000_000  # attempt indices of the planners' executed choices
_STREAM = 0x91A4  # the goals' and candidates' own random stream
PLANNERS = ("cem", "rank")
GOAL_STRATA = {
    "arm": "pushed by the arm",
    "object": "pushed by another object",
    "far": "moved far",
}


@dataclass(frozen=True)
class PlanningSettings:
    planner: str = "cem"
    goals: int = 200
    candidates: int = 16  # random genomes per goal (baselines); rank: the candidates the model ranks
    success_cm: float = 3.0
    min_move_cm: float = 5.0  # a goal moves its object at least this far (so "leave it" is no success)
    far_cm: float = 15.0  # the "moved far" stratum
    object_share: float = 0.25  # at most this share of the goals drawn from objects pushed by another object
    sigma: float = 0.1  # rank: the goal genome's mutations
    seed: int = 0
    cem_samples: int = 64
    cem_iterations: int = 4
    cem_elites: int = 10
    cem_disagreement: float = 0.0  # metres of cost per cm of the ensemble's disagreement (`CemSettings`)
    ceiling_goals: int = 40  # goals the search is also run on with the true simulator as its model (0: none)

    def __post_init__(self) -> None:
        if self.planner not in PLANNERS:
            raise ValueError(f"unknown planner {self.planner!r}; choose one of {', '.join(PLANNERS)}")

    @property
    def mutations(self) -> int:
        """Executed mutations of the goal's genome per goal (the rank planner's; none for cem)."""
        return (self.candidates - 1) // 2 if self.planner == "rank" else 0

    def key(self, test: EpisodeSet) -> str:
        """What the executed goals and baselines depend on: the settings that choose them, and the test set."""
        parts = [self.planner == "rank", self.goals, self.candidates, self.min_move_cm, self.far_cm, self.sigma]
        parts += [self.seed, self.object_share, len(PROPERTIES)]  # the goals' stored object vectors' length
        parts += ["poses"]  # starts stored as whole poses (before: x, y, z, yaw)
        parts += ["toppled"]  # goal objects that ended on the table toppled as well (before: upright ones alone)
        raw = json.dumps([parts, sorted(set(test.source.tolist())), test.identity.tolist()]).encode()
        return hashlib.blake2b(raw, digest_size=12).hexdigest()


def bootstrap_ci(values: np.ndarray, level: float = 0.95, resamples: int = 10_000, seed: int = 0) -> list[float]:
    """Percentile bootstrap interval of the mean of ``values`` (one per goal): goals drawn with replacement."""
    v = np.asarray(values, dtype=np.float64)
    if not len(v):
        return [float("nan"), float("nan")]
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), (resamples, len(v)))].mean(axis=1)
    tail = (1 - level) / 2
    lo, hi = np.quantile(means, [tail, 1 - tail])
    return [float(lo), float(hi)]


def rate(values: np.ndarray) -> dict:
    """A success rate over goals and its 95 % interval."""
    v = np.asarray(values, dtype=np.float64)
    return {"rate": float(v.mean()) if len(v) else float("nan"), "ci95": bootstrap_ci(v), "goals": int(len(v))}


@dataclass
class PlanningTask:
    """Goals, where they start, and the outcomes of their executed baselines. Columns of the executed outcomes:
    the goal's own movement, ``mutations`` mutations of it (rank), then the random genomes."""

    source: np.ndarray  # (G,) str: the test dataset of the goal's episode
    start: list  # per goal its recorded start (layout or poses; None: the task's scene)
    goal_object: np.ndarray  # (G,) object index
    goal_xy: np.ndarray  # (G, 2) metres
    first: np.ndarray  # (G, K, 7) the start's object poses
    joints0: np.ndarray  # (G, 7) the arm's first joints
    strata: dict[str, np.ndarray]  # name -> (G,) bool
    mutations: int
    feasible: np.ndarray  # (G, C) bool
    actions: list[list[np.ndarray]]  # per goal, per column: (T, 7) commanded joints (empty when infeasible)
    final_xy: np.ndarray  # (G, C, 2) the goal object's true end position (nan when infeasible)
    specs: list | None = None  # per goal its start's objects as the sidecar records them (None: the task's)
    objects: np.ndarray | None = None  # (G, K, P) those objects' property vectors, the model's inputs

    def successes(self, success_cm: float) -> np.ndarray:
        """(G, C) whether each executed column reached its goal."""
        return reached(self.final_xy, self.goal_xy[:, None], success_cm)

    @property
    def random_columns(self) -> slice:
        return slice(1 + self.mutations, self.feasible.shape[1])

    def save(self, path: Path, key: str) -> None:
        lengths = np.array([len(a) for row in self.actions for a in row], dtype=np.int64)
        flat = [a for row in self.actions for a in row if len(a)]
        np.savez_compressed(
            path,
            key=key,
            source=self.source,
            start=json.dumps(self.start),
            goal_object=self.goal_object,
            goal_xy=self.goal_xy,
            first=self.first,
            joints0=self.joints0,
            strata=json.dumps({k: v.tolist() for k, v in self.strata.items()}),
            mutations=self.mutations,
            feasible=self.feasible,
            final_xy=self.final_xy,
            specs=json.dumps(self.specs),
            objects=np.zeros(0) if self.objects is None else self.objects,
            lengths=lengths,
            actions=np.concatenate(flat) if flat else np.zeros((0, 7)),
        )

    @classmethod
    def load(cls, path: Path, key: str) -> PlanningTask | None:
        """The task stored at ``path`` if it was made for ``key``, else None."""
        if not path.is_file():
            return None
        with np.load(path) as f:
            if "specs" not in f.files or str(f["key"]) != key:  # made before objects were stored: again
                return None
            data = {name: f[name] for name in f.files}
        g, c = data["feasible"].shape
        ends = np.cumsum(data["lengths"])
        flat = np.split(data["actions"], ends[:-1]) if len(ends) else []
        actions = [[flat[i * c + j] for j in range(c)] for i in range(g)]
        strata = {k: np.array(v, dtype=bool) for k, v in json.loads(str(data["strata"])).items()}
        return cls(
            data["source"], json.loads(str(data["start"])), data["goal_object"], data["goal_xy"], data["first"],
            data["joints0"], strata, int(data["mutations"]), data["feasible"], actions, data["final_xy"],
            json.loads(str(data["specs"])), data["objects"] if data["objects"].size else None,
        )  # fmt: skip


def reached(final_xy: np.ndarray, goal_xy: np.ndarray, success_cm: float) -> np.ndarray:
    """Whether each end position lies within ``success_cm`` of its goal (nan: an infeasible movement, never)."""
    d = np.linalg.norm(np.asarray(final_xy) - np.asarray(goal_xy), axis=-1)
    return np.nan_to_num(d, nan=np.inf) <= success_cm / 100


def contact_flags(test: EpisodeSet) -> tuple[np.ndarray, np.ndarray]:
    """(E, K) twice, from the sidecar: whether the arm touched each object in each episode (``touched``), and
    whether the object met another object in a contact that began during the episode (``object_contacts``; all
    False for a dataset recorded without them)."""
    from babblegen.contact_events import SEPARATOR, is_object_pair
    from babblegen.dataset.sidecar import read_attempts

    rows = {}
    for root in sorted(set(test.source.tolist())):
        for r in read_attempts(root):
            rows[(root, int(r["attempt"]))] = r
    names = test.scene.objects
    touched = np.zeros((len(test), len(names)), dtype=bool)
    met = np.zeros_like(touched)
    for e, key in enumerate(zip(test.source, test.attempt, strict=True)):
        row = rows.get((str(key[0]), int(key[1])), {})
        arm = row.get("touched") or {}
        touched[e] = [bool(arm.get(n, False)) for n in names]
        pairs = [pair for pair in row.get("object_contacts") or {} if is_object_pair(pair)]
        parties = {p for pair in pairs for p in pair.split(SEPARATOR)}
        met[e] = [n in parties for n in names]
    return touched, met


def choose_goals(
    test: EpisodeSet, settings: PlanningSettings, flags: tuple[np.ndarray, np.ndarray] | None = None
) -> list[tuple[int, int]]:
    """(episode, object) goals from executed episodes (waypoint episodes alone for rank, whose candidates mutate the
    goal's genome), drawn at random without repeating an episode: up to ``object_share`` of them objects pushed by
    another object (the most-moved such object of an episode), the rest each episode's most-moved object; every
    goal object moved at least ``min_move_cm`` and ended on the table. ``flags``: `contact_flags` of ``test``, when
    already read."""
    moved = object_distance_moved(test)
    final = test.final
    scene = test.scene
    x0, x1, y0, y1 = scene.table
    on_table = (final[..., 0] > x0) & (final[..., 0] < x1) & (final[..., 1] > y0) & (final[..., 1] < y1)
    on_table &= final[..., 2] > scene.top  # above the top, upright or toppled: a goal is a place (x, y) on it
    ok = (moved * 100 >= settings.min_move_cm) & on_table
    touched, met = flags if flags is not None else contact_flags(test)
    by_object = ok & ~touched & met
    pool, object_pool = [], []
    for e in range(len(test)):
        if settings.planner == "rank" and test.commands[e]["kind"] != "ee_waypoints":
            continue
        k = int(np.argmax(moved[e]))
        if ok[e, k]:
            pool.append((e, k))
        if by_object[e].any():
            object_pool.append((e, int(np.argmax(np.where(by_object[e], moved[e], -1.0)))))
    rng = np.random.default_rng([settings.seed, _STREAM])
    order = rng.permutation(len(pool))
    object_order = np.random.default_rng([settings.seed, _STREAM, 2]).permutation(len(object_pool))
    goals = [object_pool[i] for i in object_order[: int(settings.goals * settings.object_share)]]
    taken = {e for e, _ in goals}
    for i in order:
        if len(goals) >= settings.goals:
            break
        if pool[i][0] not in taken:
            goals.append(pool[i])
            taken.add(pool[i][0])
    return sorted(goals)


def random_genomes(n: int, rng: np.random.Generator, max_waypoints: int = 4) -> list[np.ndarray]:
    """``n`` genomes as `random_waypoints` draws them: 1 to ``max_waypoints`` waypoints uniform in the box."""
    return [rng.random((int(rng.integers(1, max_waypoints + 1)), 3)) for _ in range(n)]


def build_task(test: EpisodeSet, settings: PlanningSettings, workers: int, cache: Path | None, echo=print):
    """The goals of ``test`` and their baselines, executed (or read from ``cache`` when made for the same key)."""
    key = settings.key(test)
    if cache is not None and (task := PlanningTask.load(cache, key)) is not None:
        echo(f"planning: {len(task.goal_object)} goals read from {cache}")
        return task
    flags = contact_flags(test)
    goals = choose_goals(test, settings, flags)
    if not goals:
        return None
    rng = np.random.default_rng([settings.seed, _STREAM, 1])
    m, r = settings.mutations, settings.candidates - (1 if settings.planner == "rank" else 0) - settings.mutations
    c = 1 + m + r
    jobs = []
    for g, (e, _) in enumerate(goals):
        command = test.commands[e]
        own = np.asarray(command["genome"], dtype=np.float64)
        genomes = [own] + [own + rng.normal(0.0, settings.sigma, own.shape) for _ in range(m)]
        genomes += random_genomes(r, rng)
        for j, genome in enumerate(genomes):
            kind = command["kind"] if j == 0 else "ee_waypoints"
            attempt = int(test.attempt[e]) if j == 0 else CANDIDATE_ATTEMPTS + g * c + j
            jobs.append(
                (str(test.source[e]), attempt, kind, genome.tolist(), command["layout"], command.get("objects"))
            )
    echo(f"planning: executing {len(goals)} goals x {c} movements ({len(jobs)}): own, {m} mutations, {r} random")
    results = execute(jobs, workers)
    final_xy = np.full((len(goals), c, 2), np.nan)
    feasible = np.zeros((len(goals), c), dtype=bool)
    actions: list[list[np.ndarray]] = []
    for g, (_, k) in enumerate(goals):
        row = []
        for j in range(c):
            ok, action, final = results[g * c + j]
            feasible[g, j] = ok
            row.append(action if settings.planner == "rank" else np.zeros((0, 7)))  # rank alone needs them
            if ok:
                final_xy[g, j] = final[k, :2]
        actions.append(row)
    episodes = [e for e, _ in goals]
    objects = [k for _, k in goals]
    moved = object_distance_moved(test)[episodes, objects]
    touched, met = flags[0][episodes, objects], flags[1][episodes, objects]
    task = PlanningTask(
        source=test.source[episodes],
        start=[test.commands[e]["layout"] for e in episodes],
        goal_object=np.array(objects),
        goal_xy=np.stack([test.final[e, k, :2] for e, k in goals]),
        first=test.first[episodes],
        joints0=np.stack([test.states[e][0] for e in episodes]),
        strata={"arm": touched, "object": ~touched & met, "far": moved * 100 >= settings.far_cm},
        mutations=m,
        feasible=feasible,
        actions=actions,
        final_xy=final_xy,
        specs=[test.commands[e].get("objects") for e in episodes],
        objects=None if test.objects is None else test.objects[episodes],
    )
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        task.save(cache, key)
    return task


def by_stratum(task: PlanningTask, per_goal: np.ndarray) -> dict:
    """A per-goal success (G,) as a rate with its interval, overall and per goal stratum."""
    out = rate(per_goal)
    out["strata"] = {s: rate(per_goal[mask]) for s, mask in task.strata.items()}
    return out


def baseline_scores(task: PlanningTask, success_cm: float) -> dict:
    """The model-free baselines: one random genome, the best of the random genomes (executed), the goal's own
    movement replayed; each overall and per stratum."""
    success = task.successes(success_cm)
    random = success[:, task.random_columns]
    return {
        "random": by_stratum(task, random.mean(axis=1)),
        "best_of_random": by_stratum(task, random.any(axis=1).astype(float)),
        "replay": by_stratum(task, success[:, 0].astype(float)),
        "random_genomes": int(random.shape[1]),
    }


def rank_scores(model, task: PlanningTask, settings: PlanningSettings) -> dict:
    """The rank planner: the model picks, among the executed candidates (the goal's own genome, its mutations and
    the first random genomes: ``candidates`` in all), the one predicted nearest; per goal the success of its pick
    (of the picks predicted equally near: their mean)."""
    success = task.successes(settings.success_cm)
    cols = np.arange(min(settings.candidates, task.feasible.shape[1]))
    picks = np.zeros(len(task.goal_object))
    for g in range(len(task.goal_object)):
        live = cols[task.feasible[g, cols]]
        if not len(live):
            continue
        objects = {} if task.objects is None else {"objects": [task.objects[g]] * len(live)}
        pred = model.rollout(
            [task.first[g]] * len(live), [task.actions[g][j] for j in live], [task.joints0[g]] * len(live), **objects
        )
        miss = np.linalg.norm(pred[:, task.goal_object[g], :2] - task.goal_xy[g], axis=-1)
        tied = live[np.isclose(miss, miss.min(), rtol=0.0, atol=1e-9)]
        picks[g] = success[g, tied].mean()
    out = by_stratum(task, picks)
    out["model"] = out.pop("rate")
    oracle = float(success[:, cols].any(axis=1).mean())
    feasible = task.feasible[:, cols]
    chance = [success[g, cols][feasible[g]].mean() if feasible[g].any() else 0.0 for g in range(len(picks))]
    out.update(
        oracle=oracle,
        random=float(np.mean(chance)),  # a candidate chosen at random among the feasible ones
        share=out["model"] / oracle if oracle else float("nan"),
        goal_success=picks.tolist(),
    )
    return out


def cem_scores(model, task: PlanningTask, settings: PlanningSettings) -> dict:
    """The cem planner: search with the model alone per goal, execute the choice once; its success per goal and
    stratum, the search's wall time, and how the executed movement compares with the one the search scored."""
    from babblegen.worldmodel.planning_cem import CemSettings, cem_plan

    cem = CemSettings(
        samples=settings.cem_samples,
        iterations=settings.cem_iterations,
        elites=settings.cem_elites,
        disagreement=settings.cem_disagreement,
    )
    g_count = len(task.goal_object)
    genomes: list[np.ndarray | None] = [None] * g_count
    scored: list[np.ndarray | None] = [None] * g_count
    predicted = np.full(g_count, np.nan)
    search, search_cpu, rollouts = 0.0, 0.0, 0
    for root in sorted(set(task.source.tolist())):
        idx = np.flatnonzero(task.source == root)
        result = cem_plan(
            model, commander(root), task.first[idx], task.joints0[idx], task.goal_object[idx], task.goal_xy[idx],
            cem, settings.seed, None if task.objects is None else task.objects[idx],
        )  # fmt: skip
        search += result.seconds
        search_cpu += result.cpu_seconds
        rollouts += result.rollouts
        for j, g in enumerate(idx):
            genomes[g], scored[g] = result.genomes[j], result.actions[j]
            predicted[g] = result.predicted_miss[j] if result.genomes[j] is not None else np.nan
    t0 = time.perf_counter()
    run = [g for g in range(g_count) if genomes[g] is not None]
    specs = task.specs or [None] * g_count
    jobs = [
        (str(task.source[g]), PLAN_ATTEMPTS + g, "ee_waypoints", genomes[g].tolist(), task.start[g], specs[g])
        for g in run
    ]
    executed = dict(zip(run, execute(jobs, 1), strict=True))
    final_xy = np.full((g_count, 2), np.nan)
    differs, infeasible, gaps = np.zeros(g_count, bool), np.zeros(g_count, bool), []
    for g, (ok, action, final) in executed.items():
        if not ok:
            infeasible[g] = True
            continue
        final_xy[g] = final[task.goal_object[g], :2]
        n = min(len(action), len(scored[g]))
        gap = float(np.abs(action[:n] - scored[g][:n]).max())
        if gap > 1e-6 or len(action) < len(scored[g]):
            differs[g] = True
            gaps.append(gap)
    ran = max(len(run), 1)
    success = reached(final_xy, task.goal_xy, settings.success_cm).astype(float)
    out = by_stratum(task, success)
    out["model"] = out.pop("rate")
    miss = np.linalg.norm(final_xy - task.goal_xy, axis=1) * 100
    out.update(
        goal_success=success.tolist(),
        # per goal, cm from its goal: where the model predicted its choice leaves the goal object and where the
        # choice, executed, left it (NaN: no choice, or not executable)
        goal_predicted_miss_cm=(predicted * 100).tolist(),
        goal_miss_cm=miss.tolist(),
        search_seconds=search,
        search_cpu_seconds=search_cpu,
        rollouts=rollouts,
        execute_seconds=time.perf_counter() - t0,
        no_plan=float(1 - len(run) / g_count),
        executed={  # shares of the executed choices
            "differs": float(differs.sum() / ran),
            "infeasible": float(infeasible.sum() / ran),
            "median_joint_gap": float(np.median(gaps)) if gaps else 0.0,
        },
    )
    return out


def plan_scores(model, task: PlanningTask, settings: PlanningSettings) -> dict:
    """The planner's success with ``model`` (``model`` and ``ci95``, overall and per stratum)."""
    return cem_scores(model, task, settings) if settings.planner == "cem" else rank_scores(model, task, settings)
