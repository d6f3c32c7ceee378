"""Evaluating a generation's commands: the interface between the run loop and the world(s).

Each rollout is seeded from the run seed and its attempt index, never from worker state, so results do not
depend on which worker ran what.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from babblegen.scene import TaskSpec
from babblegen.world.rollout import Command, Rollout
from babblegen.world.world import World, WorldSettings


def seeded_rollout(world: World, command: Command, run_seed: int, attempt: int) -> Rollout:
    """One rollout whose randomness (IK restarts, planner) depends only on (run_seed, attempt)."""
    world.rng = np.random.default_rng([run_seed, attempt])
    return world.rollout(command)


def arm_info(task: TaskSpec) -> dict:
    """What the explorers need to know about the arm, from its URDF alone (no simulator): joint names and
    limits, and the home tool position in normalised workspace coordinates."""
    from babblegen.tasks import get_robot
    from babblegen.world.kinematics import ArmKinematics, UrdfModel

    robot = get_robot(task.robot_uid)
    kin = ArmKinematics(UrdfModel.load(robot.urdf), robot.base_link, robot.tool_link)
    home_tool = kin.tool_position(np.asarray(robot.home_qpos))[0]
    return {"joints": kin.joint_names, "limits": kin.limits, "start_norm": task.workspace.to_norm(home_tool)}


class Evaluator(ABC):
    """Runs batches of commands and returns their rollouts in the same order.

    `submit` then `collect` lets the caller work (write episodes) while a batch runs; `evaluate` does both.
    """

    failures: int = 0  # workers replaced after dying or timing out

    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        self._batch = (commands, attempts)

    def collect(self) -> list[Rollout]:
        commands, attempts = self._batch
        self._batch = None
        return self.evaluate(commands, attempts)

    @abstractmethod
    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]: ...

    def close(self) -> None:  # noqa: B027  (optional hook)
        pass


class LocalEvaluator(Evaluator):
    """One World in this process (rollouts run inside `collect`)."""

    def __init__(self, task: TaskSpec, settings: WorldSettings, run_seed: int, world: World | None = None):
        self.world = world or World(task, settings, seed=run_seed)
        self.run_seed = run_seed

    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        return [seeded_rollout(self.world, c, self.run_seed, a) for c, a in zip(commands, attempts, strict=True)]

    def close(self) -> None:
        self.world.close()
