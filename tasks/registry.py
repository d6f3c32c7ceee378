"""Registries: task name -> TaskSpec and robot uid -> RobotSpec. A scene module calls `register_task`, a robot
module `register_robot`, at import."""

from __future__ import annotations

from babblegen.robot import RobotSpec
from babblegen.scene import TaskSpec

TASKS: dict[str, TaskSpec] = {}
ROBOTS: dict[str, RobotSpec] = {}


def register_robot(spec: RobotSpec) -> RobotSpec:
    if spec.uid in ROBOTS:
        raise ValueError(f"robot {spec.uid!r} is already registered")
    ROBOTS[spec.uid] = spec
    return spec


def register_task(spec: TaskSpec) -> TaskSpec:
    if spec.name in TASKS:
        raise ValueError(f"task {spec.name!r} is already registered")
    TASKS[spec.name] = spec
    return spec
