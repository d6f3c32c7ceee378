"""Planning with the world model alone: the cross-entropy method (CEM) over waypoint genomes.

For each goal (an object's end position, from a start), CEM samples genomes as the explorers make them (1 to
``max_waypoints`` end-effector waypoints in the normalised workspace box), turns each into the commanded joint
trajectory the model consumes (`Commander`), lets the model predict where the goal object ends, and refits its
sampling distribution to the genomes predicted nearest the goal. Its first population is uniform, as
`random_waypoints` draws; each later one a Gaussian per waypoint coordinate around the elites (clipped to the box),
its number of waypoints drawn from the elites' counts. The genome predicted nearest over all iterations is the
choice. Nothing here runs the simulator: the choice is executed afterwards, once (`planning_sim.execute`).

Scoring a genome must be cheap, so `Commander` does not plan with OMPL: it solves IK for each waypoint with the
world's own `ArmPlanner.solve_iks` (its first stages batched over every genome at once) and joins the
configurations by straight joint-space segments, scheduled by the world's own code (`babblegen.world.schedule`,
which `World.rollout` executes). That is the path `ArmPlanner.plan_command` returns whenever every segment is
collision-free ("direct", most movements); when one is not, the executed path (RRTConnect) differs from the scored
one, which the evaluation measures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from babblegen.world.schedule import planned_actions

NEARER = 0.001  # metres: a choice must be predicted to bring the goal object at least this much nearer its goal


@dataclass(frozen=True)
class CemSettings:
    samples: int = 64  # genomes per goal and iteration
    iterations: int = 4
    elites: int = 10  # the nearest predicted genomes the next distribution is fitted to
    max_waypoints: int = 4
    min_std: float = 0.02  # normalised workspace units: the Gaussians never narrow below this
    spare: int = 4  # predicted-nearest genomes checked for colliding segments beyond the elites
    chunk: int = 512  # model rollouts per batch
    # metres of cost per centimetre of the ensemble's disagreement on the goal object (its members' spread, summed
    # over the frames; a model without members has none): a plan the members disagree on is trusted less
    disagreement: float = 0.0


class Commander:
    """Commanded joint trajectories of waypoint genomes, per recorded frame, as `World.rollout` sends them when
    every planned segment is direct (see the module docstring); built from a dataset's run configuration, without
    the simulator."""

    def __init__(self, config) -> None:
        from babblegen.tasks import get_robot, get_task
        from babblegen.world.planning import ArmPlanner

        task = get_task(config.task)
        robot = get_robot(task.robot_uid)
        self.task, self.settings = task, config.world
        self.home = np.asarray(robot.home_qpos, dtype=np.float64)
        self.planner = ArmPlanner(task, robot, self.home, config.world)
        self.kin = self.planner.kin

    def solve_ik(self, targets: np.ndarray, seeds: np.ndarray) -> list[np.ndarray | None]:
        """`ArmPlanner.solve_iks` of B (target, seed) pairs: the configurations `World.plan_command` finds (or
        None)."""
        return [q for q, _ in self.planner.solve_iks(targets, seeds)]

    # --- the trajectory --------------------------------------------------------------------------------------
    def actions(self, out_path: np.ndarray) -> np.ndarray | None:
        """(T, dof) the recorded ``action`` column of a movement along ``out_path`` (home -> targets), as
        `World.rollout` schedules it (`babblegen.world.schedule.planned_actions`: without the settling it adds while
        objects still move); None when the movement out is too long."""
        joint = self.planner.joint_planner
        action = planned_actions(
            out_path, self.home, self.settings, lambda a, b: joint.model.motion_free(a, b, joint.resolution)
        )
        return None if action is None else action.astype(np.float64)  # as the dataset stores it

    def joint_paths(self, genomes: list[np.ndarray]) -> list[np.ndarray | None]:
        """Per genome (n, 3) normalised waypoints: its joint path home -> each waypoint's IK configuration, or
        None where IK finds none."""
        paths: list[list[np.ndarray] | None] = [[self.home] for _ in genomes]
        targets = [self.task.workspace.to_world(np.atleast_2d(g)) for g in genomes]
        for w in range(max((len(g) for g in genomes), default=0)):
            idx = [i for i, g in enumerate(genomes) if paths[i] is not None and len(g) > w]
            if not idx:
                break
            solved = self.solve_ik(np.stack([targets[i][w] for i in idx]), np.stack([paths[i][-1] for i in idx]))
            for i, q in zip(idx, solved, strict=True):
                if q is None:
                    paths[i] = None
                else:
                    paths[i].append(q)
        return [None if p is None else np.stack(p) for p in paths]

    def trajectories(self, genomes: list[np.ndarray]) -> list[np.ndarray | None]:
        """Per genome: its commanded joints (T, dof), or None where IK finds no configuration, a straight segment
        between its configurations collides (the planner would detour) or the movement is too long."""
        paths = self.joint_paths(genomes)
        free = iter(self.direct([p for p in paths if p is not None]))
        return [None if p is None or not next(free) else self.actions(p) for p in paths]

    def direct(self, paths: list[np.ndarray]) -> list[bool]:
        """Whether every straight segment of each joint path is collision-free, as `JointPlanner.plan` checks it
        before planning (`SphereCollisionModel.motion_free`, all segments in one batch): then the planner returns
        that very path."""
        model, resolution = self.planner.joint_planner.model, self.planner.joint_planner.resolution
        configs, owner = [], []
        for i, path in enumerate(paths):
            for q0, q1 in zip(path[:-1], path[1:], strict=True):
                n = max(int(np.ceil(np.abs(q1 - q0).max() / resolution)), 1) + 1
                t = np.linspace(0.0, 1.0, n)[:, None]
                configs.append(q0 + t * (q1 - q0))
                owner.append(np.full(n, i))
        if not configs:
            return [True] * len(paths)
        hit = model.in_collision(np.concatenate(configs))
        bad = np.zeros(len(paths), dtype=bool)
        bad[np.concatenate(owner)[hit]] = True
        return (~bad).tolist()


def _sample(rng: np.random.Generator, n: int, dist: dict | None, cem: CemSettings) -> list[np.ndarray]:
    """``n`` genomes: uniform (``dist`` None, as `random_waypoints` draws) or from a fitted distribution: a
    number of waypoints drawn from its probabilities, then that length's Gaussian (clipped to the box)."""
    if dist is None:
        return [rng.random((int(rng.integers(1, cem.max_waypoints + 1)), 3)) for _ in range(n)]
    counts = rng.choice(np.arange(1, cem.max_waypoints + 1), size=n, p=dist["p"])
    out = []
    for c in counts:
        mean, std = dist["mean"][c - 1], dist["std"][c - 1]
        out.append(np.clip(mean + std * rng.standard_normal(mean.shape), 0.0, 1.0))
    return out


def _refit(dist: dict | None, elites: list[np.ndarray], cem: CemSettings) -> dict:
    """The distribution fitted to the elite genomes: the probability of each number of waypoints (the elites'
    counts, add-one smoothed) and, per number, a Gaussian per coordinate fitted to the elites of that length (the
    previous one, at first uniform's mean and std, where none has it)."""
    m = cem.max_waypoints
    if dist is None:
        dist = {"mean": [np.full((c, 3), 0.5) for c in range(1, m + 1)]}
        dist["std"] = [np.full((c, 3), np.sqrt(1 / 12)) for c in range(1, m + 1)]
    mean, std = list(dist["mean"]), list(dist["std"])
    counts = np.array([len(g) for g in elites])
    p = np.bincount(counts - 1, minlength=m)[:m] + 1.0
    for c in range(1, m + 1):
        have = np.array([g for g in elites if len(g) == c])
        if len(have):
            mean[c - 1] = have.mean(axis=0)
            std[c - 1] = np.maximum(have.std(axis=0), cem.min_std)
    return {"p": p / p.sum(), "mean": mean, "std": std}


def predict_ends(
    model,
    first: list[np.ndarray],
    actions: list[np.ndarray],
    joints0: list[np.ndarray],
    chunk: int,
    objects: list[np.ndarray] | None = None,
    spread: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """(E, K, 4) the model's predicted final object states, in batches of ``chunk`` rollouts (sorted by length,
    so a batch runs about as long as its episodes); ``objects``: each rollout's objects (property vectors; None: the
    task's). With ``spread``, also (E, K) its ensemble's disagreement (`LearnedSimulator.rollout`)."""
    order = np.argsort([len(a) for a in actions], kind="stable")
    out = np.zeros((len(actions), len(first[0]), 4))
    disagree = np.zeros((len(actions), len(first[0])))
    for at in range(0, len(order), chunk):
        idx = order[at : at + chunk]
        drawn = {} if objects is None else {"objects": [objects[i] for i in idx]}
        args = ([first[i] for i in idx], [actions[i] for i in idx], [joints0[i] for i in idx])
        if spread:
            out[idx], disagree[idx] = model.rollout(*args, **drawn, spread=True)
        else:
            out[idx] = model.rollout(*args, **drawn)
    return (out, disagree) if spread else out


@dataclass
class CemResult:
    genomes: list[np.ndarray | None]  # per goal, the chosen genome (None: none predicted to bring it nearer)
    actions: list[np.ndarray | None]  # its scored commanded joints (None: no sample was feasible)
    predicted_miss: np.ndarray  # (G,) metres: the predicted distance of the goal object to its goal
    seconds: float  # the search's wall time
    rollouts: int  # model rollouts made
    cpu_seconds: float = 0.0  # the search's CPU time in this process


def cem_plan(
    model,
    commander: Commander,
    first: np.ndarray,
    joints0: np.ndarray,
    goal_object: np.ndarray,
    goal_xy: np.ndarray,
    cem: CemSettings,
    seed: int,
    objects: np.ndarray | None = None,
) -> CemResult:
    """CEM for every goal at once (each goal its own distribution; the model's rollouts of all goals batched):
    ``first`` (G, K, 7) the starts' object poses, ``joints0`` (G, dof) the arm's first joints, ``objects`` (G, K,
    P) the starts' objects (property vectors; None: the task's)."""
    started, cpu = time.perf_counter(), time.process_time()
    g_count = len(goal_object)
    rng = np.random.default_rng([seed, 0xCE0])
    dists: list[dict | None] = [None] * g_count
    best_cost = np.full(g_count, np.inf)
    best_genome: list[np.ndarray] = [np.full((1, 3), 0.5)] * g_count
    best_actions: list[np.ndarray | None] = [None] * g_count
    rollouts = 0
    kept: list[list[tuple[float, np.ndarray]]] = [[] for _ in range(g_count)]  # each goal's elites so far
    for _ in range(cem.iterations):
        genomes = [_sample(rng, cem.samples, dists[g], cem) for g in range(g_count)]
        flat = [x for per in genomes for x in per]
        paths = commander.joint_paths(flat)
        actions = [None if p is None else commander.actions(p) for p in paths]
        live = [i for i, a in enumerate(actions) if a is not None]
        cost = np.full(len(flat), np.inf)
        if live:
            owner = np.array(live) // cem.samples
            drawn = None if objects is None else [objects[g] for g in owner]
            spread = cem.disagreement > 0 and getattr(model, "kind", "") == "graph"
            pred = predict_ends(
                model,
                [first[g] for g in owner],
                [actions[i] for i in live],
                [joints0[g] for g in owner],
                cem.chunk,
                drawn,
                spread,
            )
            if spread:
                pred, disagree = pred
            at_goal = pred[np.arange(len(live)), goal_object[owner], :2]
            cost[live] = np.linalg.norm(at_goal - goal_xy[owner], axis=-1)
            if spread:
                cost[live] += cem.disagreement * disagree[np.arange(len(live)), goal_object[owner]]
            rollouts += len(live)
        cost = cost.reshape(g_count, cem.samples)
        # the nearest predicted of each goal, checked for straight segments that collide (whose execution would
        # detour): the elites and the choice are among those that run as scored
        orders = [np.argsort(cost[g], kind="stable")[: cem.elites + cem.spare] for g in range(g_count)]
        check = [g * cem.samples + i for g in range(g_count) for i in orders[g] if np.isfinite(cost[g, i])]
        free = dict(zip(check, commander.direct([paths[i] for i in check]), strict=True))
        for g in range(g_count):
            ok = [i for i in orders[g] if free.get(g * cem.samples + i, False)][: cem.elites]
            if not ok:
                continue
            if cost[g, ok[0]] < best_cost[g]:
                best_cost[g] = cost[g, ok[0]]
                best_genome[g] = genomes[g][ok[0]]
                best_actions[g] = actions[g * cem.samples + ok[0]]
            # the elites: the nearest predicted of this population and the last (elitism)
            pool = sorted(kept[g] + [(float(cost[g, i]), genomes[g][i]) for i in ok], key=lambda pair: pair[0])
            kept[g] = pool[: cem.elites]
            dists[g] = _refit(dists[g], [genome for _, genome in kept[g]], cem)
    # a genome predicted to leave the goal object no nearer its goal than it starts is no plan: nothing is run
    start_miss = np.linalg.norm(first[np.arange(g_count), goal_object, :2] - goal_xy, axis=-1)
    chosen = [
        b if cost < start - NEARER else None for b, cost, start in zip(best_genome, best_cost, start_miss, strict=True)
    ]
    return CemResult(
        chosen, best_actions, best_cost, time.perf_counter() - started, rollouts, time.process_time() - cpu
    )
