"""Evaluating a generation's commands: the interface between the run loop and the world(s).

Each rollout is seeded from the run seed and its attempt index, never from worker state, so results do not
depend on which worker ran what.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

from babblegen.fingerprint import fingerprint
from babblegen.scene import TaskSpec
from babblegen.seeded import Describe, Prepare, seeded_rollout, warm_up
from babblegen.world.rollout import Command, Rollout
from babblegen.world.world import World, WorldSettings


class Preparers:
    """The sinks' per-episode work, done where the rollout ran (a worker process, a Ray node) rather than in the
    one coordinator: ``steps`` maps a sink name to a picklable callable taking the executed rollout's frames;
    its result lands in ``rollout.prepared[name]``. The seconds spent go to ``rollout.timings["prepare"]``."""

    def __init__(self, steps: dict[str, Callable[[Any], Any]]):
        self.steps = steps

    def __call__(self, rollout: Rollout) -> None:
        if not rollout.feasible or rollout.frames is None:
            return
        t = time.perf_counter()
        for name, step in self.steps.items():
            rollout.prepared[name] = step(rollout.frames)
        rollout.timings["prepare"] = time.perf_counter() - t

    def warm_up(self) -> None:
        for step in self.steps.values():
            if hasattr(step, "warm_up"):
                step.warm_up()


def render_and_prepare_stepwise(world: World, rollout: Rollout, prepare: Prepare) -> Iterator[None]:
    """Finish a rollout made with ``defer_render`` (here or by another World): render its frames, pausing
    (``yield``) every few (the World may run other rollouts in the pauses: `World.render_frames_stepwise`), then
    prepare it. Its timings then count all the rendering in ``render``, and all this work in ``prepare`` (the
    seconds spent on this rollout, pauses left out)."""
    if rollout.frames is None:
        return
    rendering, t = 0.0, time.perf_counter()
    for _ in world.render_frames_stepwise(rollout.frames):
        rendering += time.perf_counter() - t
        yield
        t = time.perf_counter()
    rendering += time.perf_counter() - t
    prepare(rollout)
    rollout.timings["render"] = rollout.timings.get("render", 0.0) + rendering
    rollout.timings["prepare"] = rollout.timings.get("prepare", 0.0) + rendering


class Evaluator(ABC):
    """Runs batches of commands and returns their rollouts in the same order.

    `submit` then `collect` lets the caller work (write episodes, ask for more) while batches run: several may be
    submitted, and `collect` returns the oldest one not collected yet. `evaluate` does both for one batch.
    """

    failures: int = 0  # workers replaced after dying or timing out
    # this machine's fingerprint (babblegen.fingerprint), known once the evaluator is ready (`wait_ready`)
    fingerprint: str | None = None
    # the machines that ran rollouts and compute differently (fingerprints that differ from this machine's), by
    # name: empty unless a run allows mixed machines (`RunConfig.allow_mixed_machines`)
    other_machines: dict[str, str] = {}  # (never changed in place: an evaluator sets its own)

    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        if not hasattr(self, "_submitted"):
            self._submitted: deque[tuple[list[Command], list[int]]] = deque()
        self._submitted.append((list(commands), list(attempts)))

    def collect(self) -> list[Rollout]:
        if not getattr(self, "_submitted", None):
            raise RuntimeError("nothing submitted")
        return self.evaluate(*self._submitted.popleft())

    @abstractmethod
    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]: ...

    def wait_ready(self) -> None:  # noqa: B027  (optional hook)
        """Block until the evaluator can take commands. Evaluators whose workers start in the background (see
        `ProcessEvaluator`) let the caller do its own start-up meanwhile; `submit` waits here in any case."""

    def attach_prepared(self, rollout: Rollout, attempt: int, wait: bool) -> bool:
        """Whether ``rollout`` (of ``attempt``, collected from this evaluator) holds its preparation; an
        evaluator that prepares rollouts later than it returns them (see `ProcessEvaluator`) attaches it here,
        waiting for it with ``wait``. Rollouts prepared before they are returned are always ready."""
        return True

    def close(self) -> None:  # noqa: B027  (optional hook)
        pass


class LocalEvaluator(Evaluator):
    """One World in this process (rollouts run inside `collect`)."""

    def __init__(
        self,
        task: TaskSpec,
        settings: WorldSettings,
        run_seed: int,
        world: World | None = None,
        prepare: Prepare | None = None,
        describe: Describe | None = None,
    ):
        self.world = world or World(task, settings, seed=run_seed)
        self.run_seed, self.prepare, self.describe = run_seed, prepare, describe
        warm_up(self.world, prepare)
        self.fingerprint = fingerprint(self.world)

    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        return [
            seeded_rollout(self.world, c, self.run_seed, a, self.prepare, describe=self.describe)
            for c, a in zip(commands, attempts, strict=True)
        ]

    def close(self) -> None:
        self.world.close()
