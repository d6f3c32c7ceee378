"""The true simulator behind planning: each test dataset's World and the planner's arm, built once per process.

`simulate` runs one movement from a recorded start; `execute` runs many, in order, on worker processes.
"""

from __future__ import annotations

import atexit
import os
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context, parent_process
from pathlib import Path

import numpy as np

from babblegen.worldmodel.poses import object_state


def goal_command(kind: str, values, start, objects: list | None = None):
    """The Command that runs ``values`` from a goal episode's recorded start (``start``: its drawn layout or a
    made start's poses, as the sidecar's row records it; None: the task's scene) with its objects (the row's factors,
    `ObjectSpec.factors`; None: the task's). The one place a recorded start becomes something the world runs."""
    from babblegen.shapes import ObjectSpec
    from babblegen.world.rollout import Command

    placement = None if start is None else np.asarray(start, float)
    drawn = None if objects is None else tuple(ObjectSpec.from_factors(o) for o in objects)
    return Command(kind, np.asarray(values, dtype=np.float64), placement, drawn)


_worlds: dict = {}
_commanders: dict = {}


def dataset_config(root: str):
    from babblegen.config import resumed_config
    from babblegen.dataset.sidecar import read_run_info

    return resumed_config(read_run_info(Path(root))["config"])


def commander(root: str):
    """The `planning_cem.Commander` of a dataset's task and world settings (built on first use)."""
    from babblegen.worldmodel.planning_cem import Commander

    if root not in _commanders:
        _commanders[root] = Commander(dataset_config(root))
    return _commanders[root]


def simulate(job: tuple[str, int, str, list, list | None, list | None]) -> tuple[bool, np.ndarray, np.ndarray | None]:
    """One movement in this process's World for its dataset (built on first use): (feasible, the recorded
    commanded joints, the final object states)."""
    from babblegen.evaluation import seeded_rollout, warm_up
    from babblegen.tasks import get_task
    from babblegen.world.world import World

    root, attempt, kind, genome, start, objects = job
    if root not in _worlds:
        if not _worlds and parent_process() is not None:
            # a worker leaves without the interpreter's teardown, where OMPL's binding reports spurious leaks (not
            # the main process: its exit status, a test run's say, must stand)
            atexit.register(os._exit, 0)
        config = dataset_config(root)
        world = World(get_task(config.task), config.world, seed=config.seed)
        warm_up(world, None)
        _worlds[root] = (world, config.seed)
    world, seed = _worlds[root]
    rollout = seeded_rollout(world, goal_command(kind, genome, start, objects), seed, attempt, defer_render=True)
    if not rollout.feasible:
        return False, np.zeros((0, 7)), None
    frames = rollout.frames
    action = np.asarray(frames.action, dtype=np.float32).astype(np.float64)  # as the dataset stores it
    return True, action, object_state(np.asarray(frames.object_poses[-1], dtype=np.float32).astype(np.float64))


def execute(jobs: list, workers: int) -> list:
    """Every job's (feasible, commanded joints, final object states), in order, on ``workers`` processes."""
    if workers <= 1:
        return [simulate(job) for job in jobs]
    with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
        return list(pool.map(simulate, jobs, chunksize=4))
