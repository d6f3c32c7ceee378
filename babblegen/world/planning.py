"""Planning, without the simulator: a command to a collision-free joint path, or the reason there is none.

`ArmPlanner` holds the arm's kinematic model, a sphere collision model of the static scene (the task's
obstacles and the robot's base), the OMPL joint planner, the home pose and a bank of IK seeds. It solves IK per
waypoint (from the arm's last configuration, then from bank configurations whose tool is near the target, then
random restarts) and plans a collision-free segment to each goal. `World` owns one and executes its paths.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from babblegen.robot import RobotSpec
from babblegen.scene import TaskSpec
from babblegen.shapes import Box
from babblegen.world.collision import SphereCollisionModel
from babblegen.world.exact import row_norm
from babblegen.world.kinematics import ArmKinematics, ReachShell, UrdfModel
from babblegen.world.planner import JointPlanner
from babblegen.world.rollout import Command
from babblegen.world.settings import WorldSettings


class Plan(NamedTuple):
    """A command's joint path home -> targets (not yet back), or the reason (a key of ``REASONS``) it has none.
    ``approach`` is the index of the path's knot at the first target: the way there from home."""

    path: np.ndarray | None
    reason: str
    targets: np.ndarray | None
    planner: str
    timings: dict
    approach: int = 0


class ArmPlanner:
    """Plans commands for one arm in one task's static scene. `kin` replaces the kinematic model loaded from the
    robot's URDF (a benchmark plugs other kinematics libraries in); it needs `urdf` for the base's boxes."""

    def __init__(
        self,
        task: TaskSpec,
        robot: RobotSpec,
        home: np.ndarray,
        settings: WorldSettings,
        kin: ArmKinematics | None = None,
    ):
        self.task, self.robot, self.settings, self.home = task, robot, settings, home
        self.kin = kin or ArmKinematics(UrdfModel.load(robot.urdf), robot.base_link, robot.tool_link)
        body = [
            Box(
                f"robot_body_{i}",
                tuple(sh.origin[:3, 3]),
                tuple(sh.size / 2),
                tuple(map(tuple, sh.origin[:3, :3])),
            )
            for i, sh in enumerate(self.kin.urdf.links[robot.base_link])
        ]
        self.collision = SphereCollisionModel(
            self.kin,
            task.planning_obstacles() + body,
            margin=settings.collision_margin,
            body_exempt_links=robot.body_exempt_links,
            self_exempt_pairs=robot.self_exempt_pairs,
        )
        self.joint_planner = JointPlanner(
            self.collision, max_iterations=settings.plan_iterations, time_limit=settings.plan_time_limit
        )
        self.shell = ReachShell.of(self.kin)
        self.reach = self.shell.reach
        self.bank_q, self.bank_tool = self._seed_bank(400)

    @property
    def start_norm(self) -> np.ndarray:
        """The home tool position in normalised workspace coordinates (the start of every trajectory)."""
        return self.task.workspace.to_norm(self.kin.tool_position(self.home)[0])

    def shoulder_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance from points (..., 3) to the nearest place the shoulder-lift joint can be (a circle
        around the pan axis): beyond `reach`, no configuration gets the tool there."""
        return self.shell.distance(points)

    def _seed_bank(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Collision-free configurations spread over the joint space (fixed seed) and their tool points:
        IK starts from the ones whose tool is nearest its target."""
        rng = np.random.default_rng(12345)
        q = rng.uniform(self.kin.lower, self.kin.upper, (8 * n, self.kin.dof))
        q = q[~self.collision.in_collision(q)][:n]
        return q, self.kin.tool_position(q)

    def solve_ik(self, target: np.ndarray, seed_q: np.ndarray) -> tuple[np.ndarray | None, str]:
        """A collision-free joint configuration reaching `target`, preferring one close to `seed_q`, or None and
        the reason there is none: `solve_iks` for one target."""
        return self.solve_iks(np.asarray(target, dtype=np.float64)[None], np.asarray(seed_q)[None])[0]

    def solve_iks(self, targets: np.ndarray, seeds: np.ndarray) -> list[tuple[np.ndarray | None, str]]:
        """Per target (B, 3), a collision-free joint configuration reaching it, preferring one close to its seed
        (B, dof), or None and the reason there is none. Stages: from the seed and home (smallest motion), then
        from stored configurations whose tool is near the target, then random restarts; IK stops at the first seed
        that converges, so order matters. The first two stages run for every target at once (each target's answer
        is what it would be alone), the restarts one target at a time.

        Deterministic: the same target and seed give the same answer (restarts draw from a generator seeded by
        the target), so a genome always produces the same movement.
        """
        s = self.settings
        targets = np.asarray(targets, dtype=np.float64)
        out: list[tuple[np.ndarray | None, str]] = [(None, "out_of_reach")] * len(targets)
        found_any = np.zeros(len(targets), dtype=bool)
        pending = np.flatnonzero(self.shoulder_distance(targets) <= self.reach)
        n_bank = max(s.ik_seeds - 2, 1)
        for stage in range(2):
            if not len(pending):
                return out
            if stage == 0:
                starts = np.stack([seeds[pending], np.broadcast_to(self.home, (len(pending), len(self.home)))], 1)
            else:
                dist = row_norm(self.bank_tool[None] - targets[pending][:, None])
                starts = self.bank_q[np.argsort(dist, axis=1, kind="stable")[:, :n_bank]]
            q, err = self.kin.inverse_positions(targets[pending], starts, tol=s.ik_tolerance * 0.5)
            converged = self._choose(q, err, seeds[pending], out, pending)
            found_any[pending[converged]] = True
            pending = np.array([i for i in pending if out[i][0] is None], dtype=np.int64)
        for i in pending:  # random restarts
            rng = np.random.default_rng(np.frombuffer(np.round(targets[i], 9).tobytes(), dtype=np.uint32))
            for starts in [rng.uniform(self.kin.lower, self.kin.upper, (s.ik_seeds, self.kin.dof)) for _ in range(2)]:
                q, err = self.kin.inverse_position(targets[i], starts, tol=s.ik_tolerance * 0.5)
                if self._choose(q[None], err[None], seeds[i][None], out, [i])[0]:
                    found_any[i] = True
                    if out[i][0] is not None:
                        break
            if out[i][0] is None:
                out[i] = (None, "target_in_collision" if found_any[i] else "no_ik")
        return out

    def _choose(
        self, q: np.ndarray, err: np.ndarray, seeds: np.ndarray, out: list, idx: np.ndarray | list[int]
    ) -> np.ndarray:
        """Among one stage's solutions (P, M, dof) of targets ``idx`` (P), each target's collision-free converged
        one nearest its seed goes to ``out[i]``; (P,) whether any of its solutions converged. The candidates of all
        targets are checked for collisions in one batch: each one's answer is what it would be alone."""
        ok = err < self.settings.ik_tolerance
        converged = ok.any(axis=1)
        owner = np.nonzero(ok)[0]
        cand = q[ok]
        if not len(cand):
            return converged
        free = ~self.collision.in_collision(cand)
        for j, i in enumerate(idx):
            mine = cand[(owner == j) & free]
            if len(mine):
                out[i] = (mine[np.argmin(np.abs(mine - seeds[j]).sum(axis=1))], "")
        return converged

    def plan_command(self, command: Command) -> Plan:
        """Joint path home -> targets (not yet back), or the reason it does not exist."""
        timings = {"ik": 0.0, "plan": 0.0}
        q_prev, path, planners = self.home, [self.home[None]], set()
        if command.kind == "ee_waypoints":
            targets = self.task.workspace.to_world(np.atleast_2d(command.values))
            goals = []
            for target in targets:
                t0 = time.perf_counter()
                q, reason = self.solve_ik(target, q_prev)
                timings["ik"] += time.perf_counter() - t0
                if q is None:
                    return Plan(None, reason, targets, "", timings)
                goals.append(q)
                q_prev = q
        elif command.kind == "joint_target":
            targets = None
            goal = np.asarray(command.values, dtype=np.float64)
            if np.any(goal < self.kin.lower - 1e-9) or np.any(goal > self.kin.upper + 1e-9):
                raise ValueError("joint target outside the joint limits")
            if self.collision.in_collision(goal[None])[0]:
                return Plan(None, "target_in_collision", None, "", timings)
            goals = [goal]
        else:
            raise ValueError(f"unknown command kind {command.kind!r}")
        q_prev = self.home
        for goal in goals:
            res = self.joint_planner.plan(q_prev, goal)
            timings["plan"] += res.seconds
            if res.path is None:
                return Plan(None, "no_plan", targets, "", timings)
            path.append(res.path[1:])
            planners.add(res.planner)
            q_prev = goal
        planner = "rrtconnect" if "rrtconnect" in planners else "direct"
        return Plan(np.concatenate(path), "", targets, planner, timings, approach=len(path[1]))
