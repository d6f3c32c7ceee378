"""Building a run's parts from its configuration: the task, the evaluator, the descriptor and the explorer.

One place, so that ``babblegen generate`` and the benchmarks build exactly the same search.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from babblegen.config import RunConfig


def build_explorer(config: RunConfig, arm: dict[str, Any], overrides: dict[str, Any] | None = None):
    """The configured explorer, seeded with the run seed; ``arm`` is :func:`babblegen.evaluation.arm_info`'s
    answer and ``overrides`` changes explorer options (benchmarks only)."""
    from babblegen.explorers import make_explorer

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
    from babblegen.objects import slot_task
    from babblegen.tasks import get_task

    return slot_task(get_task(config.task), config.world.objects, config.world.num_objects)


def build_starts(config: RunConfig):
    """The run's start sampler (`babblegen.starts.run_starts`), drawing objects too when the run does; None with
    fixed starts."""
    from babblegen.starts import run_starts
    from babblegen.tasks import get_task

    return run_starts(get_task(config.task), config.world, config.seed)


def build_evaluator(task: Any, config: RunConfig, prepare=None, describe=None):
    """One world in this process, or a pool of worker processes or Ray actors (``workers``, ``ray``);
    ``describe`` (the behaviour descriptor) and ``prepare`` run on each rollout where it ran
    (:data:`babblegen.evaluation.Describe`, :data:`babblegen.evaluation.Prepare`)."""
    if config.workers > 1 or config.ray:
        from babblegen.parallel import make_parallel_evaluator

        return make_parallel_evaluator(task, config, prepare, describe)
    from babblegen.evaluation import LocalEvaluator

    return LocalEvaluator(task, config.world, config.seed, prepare=prepare, describe=describe)


def build_descriptor(config: RunConfig, overrides: dict[str, Any] | None = None):
    from babblegen.descriptors import make_descriptor

    return make_descriptor(**{**config.descriptor_config(), **(overrides or {})})
