"""Planning with the world model alone: the cross-entropy method (CEM) over waypoint genomes.

For each goal (an object's end position, from a start), CEM samples genomes as the explorers make them (1 to
``max_waypoints`` end-effector waypoints in the normalised workspace box), turns each into the commanded joint
trajectory the model consumes (`Commander`), lets the model predict where the goal object ends, and refits its
sampling distribution to the genomes predicted nearest the goal. Its first population is uniform, as
`random_waypoints` draws; each later one a Gaussian per waypoint coordinate around the elites (clipped to the box),
its number of waypoints drawn from the elites' counts. The genome predicted nearest over all iterations is the
choice. Nothing here runs the simulator: the choice is executed afterwards, once (`planning.execute`).

Scoring a genome must be cheap, so `Commander` does not plan with OMPL: it solves IK for each waypoint exactly as
`ArmPlanner.solve_ik` does (the first stage batched over every genome at once, the rest by `solve_ik` itself) and
joins the configurations by straight joint-space segments, timed as `World._timed_path` times them. That is the
path `ArmPlanner.plan_command` returns whenever every segment is collision-free ("direct", most movements); when
one is not, the executed path (RRTConnect) differs from the scored one, which the evaluation measures.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from babblegen.world.exact import inv3, matmul, matvec, row_norm
from babblegen.world.settings import timed_path

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

    # --- IK: `ArmPlanner.solve_ik`, its first two stages batched ----------------------------------------------
    def _stage(self, targets: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`ArmKinematics.inverse_position` for B targets at once, each from its own M seeds ``seeds`` (B, M,
        dof): every target's seeds iterate until one of them converges, as the one-target call does. Returns
        (B, M, dof) configurations and (B, M) errors."""
        kin, s = self.kin, self.settings
        tol, damping, bias_gain = s.ik_tolerance * 0.5, 0.05, 0.05
        b, m = seeds.shape[:2]
        q = np.clip(seeds.reshape(b * m, -1), kin.lower, kin.upper)
        bias = q.copy()
        goal = np.repeat(targets, m, axis=0)
        err = np.full(b * m, np.inf)
        live = np.ones(b, dtype=bool)
        eye3, eye_n = np.eye(3), np.eye(kin.dof)
        for _ in range(100):
            rows = np.flatnonzero(np.repeat(live, m))
            if not len(rows):
                break
            jac, tool = kin.jacobian(q[rows])
            e = goal[rows] - tool
            err[rows] = row_norm(e)
            going = (err[rows] > tol).reshape(-1, m).all(axis=1)
            live[np.flatnonzero(live)[~going]] = False  # one of its seeds converged: that target stops here
            keep = np.repeat(going, m)
            rows, jac, e = rows[keep], jac[keep], e[keep]
            if not len(rows):
                break
            jac_t = jac.transpose(0, 2, 1)
            jpinv = matmul(jac_t, inv3(matmul(jac, jac_t) + damping**2 * eye3))
            step = matvec(jpinv, e)
            null = eye_n - matmul(jpinv, jac)
            step += bias_gain * matvec(null, bias[rows] - q[rows])
            norm = row_norm(step)[:, None]
            step *= np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))
            q[rows] = np.clip(q[rows] + step, kin.lower, kin.upper)
        rows = np.flatnonzero(np.repeat(live, m))
        if len(rows):  # ran out of iterations: the error where they ended
            err[rows] = row_norm(goal[rows] - kin.tool_position(q[rows]))
        return q.reshape(b, m, -1), err.reshape(b, m)

    def solve_ik(self, targets: np.ndarray, seeds: np.ndarray) -> list[np.ndarray | None]:
        """`ArmPlanner.solve_ik` of B (target, seed) pairs, the same configurations (or None): its first two
        stages (from the seed and home; from the bank configurations whose tool is nearest) batched over the
        targets, the random restarts after them left to `ArmPlanner.solve_ik` itself (rarely reached)."""
        p, s = self.planner, self.settings
        out: list[np.ndarray | None] = [None] * len(targets)
        pending = np.flatnonzero(p.shoulder_distance(targets) <= p.reach)
        for stage in range(2):
            if not len(pending):
                return out
            if stage == 0:
                starts = np.stack([seeds[pending], np.broadcast_to(self.home, (len(pending), len(self.home)))], 1)
            else:
                dist = row_norm(p.bank_tool[None] - targets[pending][:, None])
                near = np.argsort(dist, axis=1, kind="stable")[:, : max(s.ik_seeds - 2, 1)]
                starts = p.bank_q[near]
            q, err = self._stage(targets[pending], starts)
            ok = err < s.ik_tolerance
            free = np.zeros_like(ok)
            if ok.any():
                free[ok] = ~p.collision.in_collision(q[ok])
            left = []
            for j, i in enumerate(pending):
                cand = q[j][free[j]]
                if len(cand):
                    out[i] = cand[np.argmin(np.abs(cand - seeds[i]).sum(axis=1))]
                else:
                    left.append(i)
            pending = np.array(left, dtype=np.int64)
        for i in pending:  # the random restarts
            out[i] = p.solve_ik(targets[i], seeds[i])[0]
        return out

    # --- the trajectory --------------------------------------------------------------------------------------
    def _timed_path(self, path: np.ndarray) -> np.ndarray:
        """Joint targets at the control rate along a piecewise-linear path at max_joint_speed
        (`World._timed_path`)."""
        return timed_path(path, self.settings)

    def actions(self, out_path: np.ndarray) -> np.ndarray | None:
        """(T, dof) the recorded ``action`` column of a movement along ``out_path`` (home -> targets), as
        `World.rollout` schedules it (without the settling it adds while objects still move); None when the
        movement out is too long."""
        s = self.settings
        out = self._timed_path(out_path)
        if s.max_move_seconds:
            steps = float(len(out))
            if not s.count_approach:
                approach = np.abs(np.diff(out_path[:2], axis=0)).max(axis=1).sum() / s.max_joint_speed
                steps -= approach * s.control_freq
            if steps > s.max_move_seconds * s.control_freq + 1e-9:
                return None
        dwell = np.repeat(out[-1:], max(int(round(s.dwell_seconds * s.control_freq)), 0), axis=0)
        home_path = out_path[::-1]
        if s.return_home == "direct" and self.planner.joint_planner.model.motion_free(
            out_path[-1], self.home, self.planner.joint_planner.resolution
        ):
            home_path = np.stack([out_path[-1], self.home])
        back = self._timed_path(home_path)
        settle = np.repeat(self.home[None], max(int(round(s.settle_seconds * s.control_freq)), 1), axis=0)
        schedule = np.concatenate([out, dwell, back, settle])
        per_frame = s.control_freq // s.fps
        schedule = np.concatenate([schedule, np.repeat(self.home[None], -len(schedule) % per_frame, axis=0)])
        frames = len(schedule) // per_frame + 1
        picked = schedule[per_frame - 1 :: per_frame][: frames - 1]
        action = np.concatenate([picked, self.home[None]]).astype(np.float32)
        return action.astype(np.float64)  # as the dataset stores it

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
) -> np.ndarray:
    """(E, K, 4) the model's predicted final object states, in batches of ``chunk`` rollouts (sorted by length,
    so a batch runs about as long as its episodes); ``objects``: each rollout's objects (property vectors; None: the
    task's)."""
    order = np.argsort([len(a) for a in actions], kind="stable")
    out = np.zeros((len(actions), *first[0].shape))
    for at in range(0, len(order), chunk):
        idx = order[at : at + chunk]
        drawn = {} if objects is None else {"objects": [objects[i] for i in idx]}
        out[idx] = model.rollout([first[i] for i in idx], [actions[i] for i in idx], [joints0[i] for i in idx], **drawn)
    return out


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
    ``first`` (G, K, 4) the starts' object states, ``joints0`` (G, dof) the arm's first joints, ``objects`` (G, K,
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
            pred = predict_ends(
                model,
                [first[g] for g in owner],
                [actions[i] for i in live],
                [joints0[g] for g in owner],
                cem.chunk,
                drawn,
            )
            cost[live] = np.linalg.norm(pred[np.arange(len(live)), goal_object[owner], :2] - goal_xy[owner], axis=-1)
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
