"""Scenes and robots: the tabletop tasks and the PR2-like arm, registered with babblegen here and with ManiSkill
when the simulator loads (`tasks.envs`)."""

from __future__ import annotations

from babblegen.robot import RobotSpec
from babblegen.scene import TaskSpec

from . import noveb_tabletop, pr2_arm, wall_tabletop  # noqa: F401  (register the robot and the scenes)
from .registry import ROBOTS, TASKS

DEFAULT_TASK = "noveb_tabletop"


def get_task(name: str) -> TaskSpec:
    """The registered task called `name`; a ValueError lists the valid names otherwise."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; choose one of: {', '.join(sorted(TASKS))}")
    return TASKS[name]


def get_robot(uid: str) -> RobotSpec:
    """The registered robot with this uid (a task's ``robot_uid``)."""
    if uid not in ROBOTS:
        raise ValueError(f"unknown robot {uid!r}; registered: {', '.join(sorted(ROBOTS))}")
    return ROBOTS[uid]


__all__ = ["DEFAULT_TASK", "ROBOTS", "TASKS", "get_robot", "get_task"]
