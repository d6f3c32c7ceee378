"""Rollouts on many workers: local processes or a Ray cluster, behind the `Evaluator` interface.

`scheduler` decides what runs when (every submitted batch's rollouts over free slots, results in attempt order,
the failure policy); `processes` and `ray_actors` are the transports; `worker` is a worker process's loop.
Rollouts are seeded from the run seed and the attempt index (`babblegen.evaluation.seeded_rollout`), so the
dataset does not depend on the number of workers or on which ran what.
"""

from __future__ import annotations

from babblegen.config import ConfigError, RunConfig
from babblegen.evaluation import Describe, Evaluator, Prepare
from babblegen.parallel.processes import ProcessEvaluator
from babblegen.parallel.scheduler import Failure, PoolEvaluator
from babblegen.scene import TaskSpec

__all__ = ["Failure", "PoolEvaluator", "ProcessEvaluator", "RayEvaluator", "make_parallel_evaluator"]


def __getattr__(name: str):
    if name == "RayEvaluator":  # Ray is optional: imported when asked for
        from babblegen.parallel.ray_actors import RayEvaluator

        return RayEvaluator
    raise AttributeError(name)


def make_parallel_evaluator(
    task: TaskSpec, config: RunConfig, prepare: Prepare | None = None, describe: Describe | None = None
) -> Evaluator:
    if config.ray:
        from babblegen.parallel.ray_actors import RayEvaluator

        n = config.workers if config.workers > 1 else None
        try:
            return RayEvaluator(
                task,
                config.world,
                config.seed,
                config.ray,
                n=n,
                prepare=prepare,
                describe=describe,
                allow_mixed=config.allow_mixed_machines,
            )
        except ImportError:
            raise ConfigError("--ray needs Ray: pip install 'babblegen[ray]'") from None
    return ProcessEvaluator(task, config.world, config.seed, config.workers, prepare=prepare, describe=describe)
