"""Building a run's parts from its configuration: the task, the arm's description, the evaluator, the descriptor
and the explorer.

One place, so that ``babblegen generate`` and the benchmarks build exactly the same search. The evaluators' modules
load the simulator, so they are imported when one is built, not with this module.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from babblegen.config import RunConfig
from babblegen.descriptors import make_descriptor
from babblegen.explorers import make_explorer
from babblegen.objects import slot_task
from babblegen.scene import TaskSpec
from babblegen.starts import run_starts
from babblegen.tasks import get_robot, get_task
from babblegen.world.kinematics import ArmKinematics, ReachShell, UrdfModel


def arm_info(task: TaskSpec) -> dict:
    """What the explorers need to know about the arm, from its URDF alone (no simulator): joint names and
    limits, the home tool position in normalised workspace coordinates, and ``in_reach``, whether a normalised
    waypoint is within the arm's reach (`babblegen.world.kinematics.ReachShell`)."""
    robot = get_robot(task.robot_uid)
    kin = ArmKinematics(UrdfModel.load(robot.urdf), robot.base_link, robot.tool_link)
    home_tool = kin.tool_position(np.asarray(robot.home_qpos))[0]
    shell = ReachShell.of(kin)

    def in_reach(point: np.ndarray) -> bool:
        return bool(shell.contains(task.workspace.to_world(point)))

    return {
        "joints": kin.joint_names,
        "limits": kin.limits,
        "start_norm": task.workspace.to_norm(home_tool),
        "in_reach": in_reach,
    }


def build_explorer(config: RunConfig, arm: dict[str, Any], overrides: dict[str, Any] | None = None):
    """The configured explorer, seeded with the run seed; ``arm`` is :func:`arm_info`'s answer and ``overrides``
    changes explorer options (benchmarks only)."""
    options = {**config.explorer_config(), **(overrides or {})}
    if config.explorer != "noveb":
        options.pop("reuse_clones", None)
    starts = build_starts(config)
    return make_explorer(
        config.explorer,
        options,
        rng_seed=config.seed,
        joint_limits=np.asarray(arm["limits"]),
        start_norm=np.asarray(arm["start_norm"]),
        starts=starts,
        in_reach=arm.get("in_reach"),
    )


def build_task(config: RunConfig):
    """The run's task: the configured one, with its object slots when the run draws its objects
    (`babblegen.objects.slot_task`)."""
    return slot_task(get_task(config.task), config.world.objects, config.world.num_objects)


def build_starts(config: RunConfig):
    """The run's start sampler (`babblegen.starts.run_starts`), drawing objects too when the run does; None with
    fixed starts."""
    return run_starts(get_task(config.task), config.world, config.seed)


def build_evaluator(task: Any, config: RunConfig, prepare=None, describe=None):
    """One world in this process, or a pool of worker processes or Ray actors (``workers``, ``ray``);
    ``describe`` (the behaviour descriptor) and ``prepare`` run on each rollout where it ran
    (:data:`babblegen.evaluation.Describe`, :data:`babblegen.evaluation.Prepare`)."""
    if config.workers > 1 or config.ray:
        from babblegen.parallel import make_parallel_evaluator  # the simulator, like LocalEvaluator's module

        return make_parallel_evaluator(task, config, prepare, describe)
    from babblegen.evaluation import LocalEvaluator

    return LocalEvaluator(task, config.world, config.seed, prepare=prepare, describe=describe)


def build_descriptor(config: RunConfig, overrides: dict[str, Any] | None = None):
    return make_descriptor(**{**config.descriptor_config(), **(overrides or {})})
