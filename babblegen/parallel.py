"""Rollouts on worker processes (local) or Ray actors (a cluster), behind the `Evaluator` interface.

Each worker builds one World and keeps its simulator and renderer warm. Work is handed out one rollout at a
time to whichever worker is free; results come back in submission order. Rollouts are seeded from the run
seed and the attempt index (see `seeded_rollout`), so the dataset does not depend on the number of workers.
A worker that dies or exceeds the per-rollout timeout is replaced and the rollout retried; each such event is
counted (`failures`) and reported with the attempt.

`submit` returns at once and hands the batch to a dispatch thread, which keeps every worker busy while the run
loop writes the previous generation's episodes; `collect` waits for that thread. Without the thread, work would
only be handed out inside `collect`, and the workers would sit idle for most of the writing.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import threading
import time
from abc import abstractmethod
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import wait

from babblegen.config import ConfigError, RunConfig
from babblegen.evaluation import Evaluator
from babblegen.scene import TaskSpec
from babblegen.world.rollout import Command, Rollout
from babblegen.world.settings import WorldSettings

log = logging.getLogger(__name__)


def _worker_main(conn, task_name: str, settings: WorldSettings, run_seed: int) -> None:
    """Worker loop: build a World once, then answer (attempt, command) requests until told to stop."""
    os.environ.setdefault("LP_NUM_THREADS", "1")  # one rendering thread per worker process
    import torch

    torch.set_num_threads(1)  # one core per worker: idle torch threads would spin against the other processes
    from babblegen.evaluation import seeded_rollout
    from babblegen.tasks import get_task
    from babblegen.world.world import World

    world = World(get_task(task_name), settings, seed=run_seed)
    conn.send(("ready", None))
    while True:
        msg = conn.recv()
        if msg is None:
            break
        attempt, command = msg
        conn.send((attempt, seeded_rollout(world, command, run_seed, attempt)))
    world.close()


class _BatchThread(Evaluator):
    """`submit` runs `_run_batch` on a thread; `collect` waits for it and returns its rollouts (or raises)."""

    _thread: threading.Thread | None = None
    _closing = False

    @abstractmethod
    def _run_batch(self, commands: list[Command], attempts: list[int]) -> list[Rollout]: ...

    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        if self._thread is not None:
            raise RuntimeError("collect the previous batch first")
        self._outcome: tuple[str, object] | None = None

        def run() -> None:
            try:
                self._outcome = ("ok", self._run_batch(list(commands), list(attempts)))
            except BaseException as e:  # handed to collect() in the calling thread
                self._outcome = ("error", e)

        self._thread = threading.Thread(target=run, name="rollout-dispatch", daemon=True)
        self._thread.start()

    def collect(self) -> list[Rollout]:
        if self._thread is None:
            raise RuntimeError("nothing submitted")
        while self._thread.is_alive():
            self._thread.join(0.2)  # short waits: the main thread stays responsive to Ctrl-C
        self._thread = None
        status, value = self._outcome
        if status == "error":
            raise value
        return value

    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        self.submit(commands, attempts)
        return self.collect()

    def _stop_dispatch(self) -> None:
        """Make a running batch give up (on close, e.g. after an interruption) and wait for its thread."""
        self._closing = True
        if self._thread is not None:
            self._thread.join(10)
            self._thread = None


class _Cancelled(Exception):
    pass


@dataclass
class _Worker:
    process: mp.Process
    conn: object
    job: tuple[int, Command] | None = None
    started: float = 0.0


@dataclass
class _Batch:
    commands: list[Command]
    attempts: list[int]
    results: dict[int, Rollout] = field(default_factory=dict)
    retries: dict[int, int] = field(default_factory=dict)


class ProcessEvaluator(_BatchThread):
    """`n` local worker processes."""

    def __init__(
        self, task: TaskSpec, settings: WorldSettings, run_seed: int, n: int, timeout: float = 300.0, retries: int = 2
    ):
        self.task, self.settings, self.run_seed = task, settings, run_seed
        self.timeout, self.max_retries = timeout, retries
        self.ctx = mp.get_context("spawn")
        self.workers = [self._spawn() for _ in range(n)]
        for w in self.workers:
            self._await_ready(w)
        self.failures = 0

    def _spawn(self) -> _Worker:
        parent, child = self.ctx.Pipe()
        p = self.ctx.Process(
            target=_worker_main, args=(child, self.task.name, self.settings, self.run_seed), daemon=True
        )
        p.start()
        child.close()
        return _Worker(p, parent)

    def _await_ready(self, w: _Worker, timeout: float = 600.0) -> None:
        if not w.conn.poll(timeout):
            raise RuntimeError("a rollout worker did not start")
        tag, _ = w.conn.recv()
        assert tag == "ready"

    def _replace(self, w: _Worker) -> None:
        w.process.kill()
        w.process.join(5)
        fresh = self._spawn()
        self._await_ready(fresh)
        w.process, w.conn, w.job = fresh.process, fresh.conn, None

    def _dispatch(self, b: _Batch, queue: deque) -> None:
        for w in self.workers:
            if w.job is None and queue:
                i = queue.popleft()
                w.job = (i, b.commands[i])
                w.started = time.monotonic()
                w.conn.send((b.attempts[i], b.commands[i]))

    def _run_batch(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        b = _Batch(commands, attempts)
        queue = deque(range(len(commands)))
        self._dispatch(b, queue)
        while len(b.results) < len(b.commands):
            if self._closing:
                raise _Cancelled
            busy = [w for w in self.workers if w.job is not None]
            ready = wait([w.conn for w in busy] + [w.process.sentinel for w in busy], timeout=1.0)
            now = time.monotonic()
            for w in busy:
                died = w.process.sentinel in ready or not w.process.is_alive()
                if w.conn in ready and not died:
                    try:
                        attempt, rollout = w.conn.recv()
                    except (EOFError, OSError):
                        died = True
                    else:
                        i = w.job[0]
                        b.results[i] = rollout
                        w.job = None
                        continue
                if died or now - w.started > self.timeout:
                    i = w.job[0]
                    self.failures += 1
                    b.retries[i] = b.retries.get(i, 0) + 1
                    log.warning(
                        "rollout worker %s for attempt %d (%s); replacing it",
                        "died" if died else "timed out",
                        b.attempts[i],
                        "retrying" if b.retries[i] <= self.max_retries else "giving up",
                    )
                    if b.retries[i] > self.max_retries:
                        raise RuntimeError(f"attempt {b.attempts[i]} failed on {b.retries[i]} workers")
                    self._replace(w)
                    queue.appendleft(i)
            self._dispatch(b, queue)
        out = [b.results[i] for i in range(len(b.commands))]
        for i, r in enumerate(out):
            r.timings["worker_failures"] = float(b.retries.get(i, 0))
        return out

    def close(self) -> None:
        self._stop_dispatch()
        for w in self.workers:
            with contextlib.suppress(BrokenPipeError, OSError):
                w.conn.send(None)
        for w in self.workers:
            w.process.join(10)
            if w.process.is_alive():
                w.process.kill()


class RayEvaluator(_BatchThread):
    """One Ray actor per worker, each with its own World; same semantics as ProcessEvaluator."""

    def __init__(
        self,
        task: TaskSpec,
        settings: WorldSettings,
        run_seed: int,
        address: str,
        n: int | None = None,
        timeout: float = 300.0,
        retries: int = 2,
    ):
        import ray

        self.ray = ray
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            options = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
            try:
                ray.init(address=None if address == "local" else address, **options)
            except ConnectionError:
                if address != "auto":
                    raise ConfigError(f"--ray {address}: no Ray cluster there") from None
                log.info("no running Ray cluster; starting a local one")
                ray.init(address=None, **options)
        n = n or max(int(ray.cluster_resources().get("CPU", 1)), 1)

        @ray.remote(num_cpus=1, max_restarts=0)
        class RolloutActor:
            def __init__(self, task_name: str, settings: WorldSettings, run_seed: int):
                os.environ.setdefault("LP_NUM_THREADS", "1")
                import torch

                torch.set_num_threads(1)
                from babblegen.tasks import get_task
                from babblegen.world.world import World

                self.world = World(get_task(task_name), settings, seed=run_seed)
                self.run_seed = run_seed

            def ping(self) -> bool:
                return True

            def rollout(self, attempt: int, command: Command) -> Rollout:
                from babblegen.evaluation import seeded_rollout

                return seeded_rollout(self.world, command, self.run_seed, attempt)

        self._actor_cls = RolloutActor
        self._args = (task.name, settings, run_seed)
        self.actors = [self._actor_cls.remote(*self._args) for _ in range(n)]
        ray.get([a.ping.remote() for a in self.actors])
        self.timeout, self.max_retries = timeout, retries
        self.failures = 0

    def _run_batch(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        ray = self.ray
        results: dict[int, Rollout] = {}
        retries: dict[int, int] = {}
        queue = deque(range(len(commands)))
        running: dict = {}  # object ref -> (index, actor, start)
        idle = list(self.actors)
        while len(results) < len(commands):
            if self._closing:
                raise _Cancelled
            while idle and queue:
                i, actor = queue.popleft(), idle.pop()
                running[actor.rollout.remote(attempts[i], commands[i])] = (i, actor, time.monotonic())
            done, _ = ray.wait(list(running), num_returns=1, timeout=1.0)
            now = time.monotonic()
            for ref in list(running):
                i, actor, start = running[ref]
                if ref in done:
                    del running[ref]
                    try:
                        results[i] = ray.get(ref)
                        idle.append(actor)
                        continue
                    except ray.exceptions.RayActorError:
                        pass
                elif now - start <= self.timeout:
                    continue
                else:
                    del running[ref]
                self.failures += 1
                retries[i] = retries.get(i, 0) + 1
                log.warning("Ray rollout actor failed on attempt %d; replacing it", attempts[i])
                if retries[i] > self.max_retries:
                    raise RuntimeError(f"attempt {attempts[i]} failed on {retries[i]} actors")
                ray.kill(actor)
                fresh = self._actor_cls.remote(*self._args)
                self.actors[self.actors.index(actor)] = fresh
                idle.append(fresh)
                queue.appendleft(i)
        out = [results[i] for i in range(len(commands))]
        for i, r in enumerate(out):
            r.timings["worker_failures"] = float(retries.get(i, 0))
        return out

    def close(self) -> None:
        self._stop_dispatch()
        for a in self.actors:
            self.ray.kill(a)
        if self._owns_ray:
            self.ray.shutdown()


def make_parallel_evaluator(task: TaskSpec, config: RunConfig) -> Evaluator:
    if config.ray:
        try:
            return RayEvaluator(
                task, config.world, config.seed, config.ray, n=config.workers if config.workers > 1 else None
            )
        except ImportError:
            raise ConfigError("--ray needs Ray: pip install 'babblegen[ray]'") from None
    return ProcessEvaluator(task, config.world, config.seed, config.workers)
