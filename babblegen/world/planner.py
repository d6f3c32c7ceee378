"""Collision-free joint-space paths with OMPL (RRTConnect), checked against the sphere model.

Each edge OMPL considers is checked in one batched call (a Python MotionValidator), not state by state.
A straight joint-space motion that is already free is returned without calling the planner: it is the
shortest path RRTConnect plus simplification would converge to, at a fraction of the cost.

Planning is deterministic and independent of machine load and of what was planned before: each query seeds
OMPL from the motion itself, uses a fresh planner, and stops after a number of iterations (a wall-clock limit
stays only as a safety net); the path is then shortened greedily, without randomness.
"""

from __future__ import annotations

import time
import zlib
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from babblegen.world.collision import SphereCollisionModel

# OMPL reports re-seeding after first use as an error; here it is deliberate (see plan()).
ou.setLogLevel(ou.LogLevel.LOG_NONE)


@dataclass
class PlanResult:
    path: np.ndarray | None  # (n, dof) joint waypoints, start and goal included; None if no plan
    planner: str  # "direct", "rrtconnect" or "none"
    seconds: float


class _BatchMotionValidator(ob.MotionValidator):
    def __init__(self, si: ob.SpaceInformation, model: SphereCollisionModel, dof: int, resolution: float):
        super().__init__(si)
        self.model, self.dof, self.resolution = model, dof, resolution

    def checkMotion(self, s1, s2, *_):  # noqa: N802 (OMPL's name)
        a = np.fromiter((s1[i] for i in range(self.dof)), float, self.dof)
        b = np.fromiter((s2[i] for i in range(self.dof)), float, self.dof)
        return self.model.motion_free(a, b, self.resolution)


class JointPlanner:
    """Plans between joint configurations; obstacles are whatever the collision model holds."""

    def __init__(
        self,
        model: SphereCollisionModel,
        max_iterations: int = 20_000,
        time_limit: float = 30.0,
        resolution: float = 0.03,
    ):
        self.model = model
        self.max_iterations = max_iterations
        self.time_limit = time_limit
        self.resolution = resolution
        kin = model.kin
        self.dof = kin.dof
        self.space = ob.RealVectorStateSpace(self.dof)
        bounds = ob.RealVectorBounds(self.dof)
        for i in range(self.dof):
            bounds.setLow(i, float(kin.lower[i]))
            bounds.setHigh(i, float(kin.upper[i]))
        self.space.setBounds(bounds)
        self.setup = og.SimpleSetup(self.space)
        self.setup.setStateValidityChecker(self._state_valid)
        si = self.setup.getSpaceInformation()
        self._validator = _BatchMotionValidator(si, model, self.dof, resolution)
        si.setMotionValidator(self._validator)
        self.si = si
        self._warmed = False

    def _state_valid(self, state) -> bool:
        q = np.fromiter((state[i] for i in range(self.dof)), float, self.dof)
        return not self.model.in_collision(q[None])[0]

    def _state(self, q: np.ndarray):
        s = self.space.allocState()
        for i, v in enumerate(q):
            s[i] = float(v)
        return s

    def plan(self, start: np.ndarray, goal: np.ndarray) -> PlanResult:
        """A collision-free path from start to goal (both assumed valid), or path=None."""
        t0 = time.perf_counter()
        if self.model.motion_free(start, goal, self.resolution):
            return PlanResult(np.stack([start, goal]), "direct", time.perf_counter() - t0)
        if not self._warmed:
            # The first solve on a SimpleSetup draws random numbers during one-time set-up, so the first RRT
            # query a planner answers would differ from the same query later. An empty solve absorbs that.
            self._solve(start, goal, 0, t0)
            self._warmed = True
        if not self._solve(start, goal, self.max_iterations, t0):
            return PlanResult(None, "none", time.perf_counter() - t0)
        p = self.setup.getSolutionPath()
        path = np.array([[p.getState(i)[j] for j in range(self.dof)] for i in range(p.getStateCount())])
        return PlanResult(self.shortcut(path), "rrtconnect", time.perf_counter() - t0)

    def _solve(self, start: np.ndarray, goal: np.ndarray, max_iterations: int, t0: float) -> bool:
        """One RRTConnect query, seeded from the motion; True if it found an exact solution."""
        seed = zlib.crc32(np.round(np.concatenate([start, goal]), 9).tobytes()) | 1
        ou.RNG.setSeed(seed)
        self.setup.clear()
        self.setup.setPlanner(og.RRTConnect(self.si))
        self.setup.setStartAndGoalStates(self._state(start), self._state(goal))
        iterations = [0]
        deadline = t0 + self.time_limit

        def stop() -> bool:
            iterations[0] += 1
            return iterations[0] > max_iterations or time.perf_counter() > deadline

        self.setup.solve(ob.PlannerTerminationCondition(stop))
        return bool(self.setup.haveExactSolutionPath())

    def shortcut(self, path: np.ndarray) -> np.ndarray:
        """Greedy, deterministic shortening: from each kept waypoint, jump to the farthest one reachable by a
        free straight motion."""
        out, i = [path[0]], 0
        while i < len(path) - 1:
            j = len(path) - 1
            while j > i + 1 and not self.model.motion_free(path[i], path[j], self.resolution):
                j -= 1
            out.append(path[j])
            i = j
        return np.array(out)
