"""One rollout seeded from the run seed and its attempt index, never from worker state, and the warm-up a World
gets before its first: what the run loop's evaluators, the fingerprint, `babblegen verify` and planning share."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from babblegen.descriptors import describe_rollout
from babblegen.world.rollout import Command, Rollout
from babblegen.world.world import World

Prepare = Callable[[Rollout], None]  # work done on a rollout where it ran (see `Preparers`)
Describe = Callable[[np.ndarray], np.ndarray]  # the behaviour descriptor: after image -> packed bit code


def warm_up(world: World, prepare: Prepare | None) -> None:
    """Pay the one-time costs before the first attempt (the renderer's shaders, the preparers' imports), so
    that attempts' timings measure attempts; then leave everything alive so far out of garbage collection
    (`World.warm_up`)."""
    if hasattr(prepare, "warm_up"):
        prepare.warm_up()
    world.warm_up()


def seeded_rollout(
    world: World,
    command: Command,
    run_seed: int,
    attempt: int,
    prepare: Prepare | None = None,
    defer_render: bool = False,
    describe: Describe | None = None,
) -> Rollout:
    """One rollout whose randomness (IK restarts, planner) depends only on (run_seed, attempt), its behaviour
    code (``describe`` of the after image, in ``rollout.code``: the search needs it, so it is made with the
    movement), then ``prepare`` (both picklable: they travel to worker processes and Ray actors). With
    ``defer_render`` the frames between the first and last are not rendered yet and nothing is prepared:
    `render_and_prepare_stepwise` does both."""
    world.rng = np.random.default_rng([run_seed, attempt])
    rollout = world.rollout(command, defer_render=defer_render)
    if describe is not None and rollout.feasible:
        t = time.perf_counter()
        rollout.code = describe_rollout(describe, rollout)
        rollout.timings["descriptor"] = time.perf_counter() - t
    if prepare is not None and not defer_render:
        prepare(rollout)
    return rollout
