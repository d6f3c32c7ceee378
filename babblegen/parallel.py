"""Rollouts on worker processes (local) or Ray actors (a cluster), behind the `Evaluator` interface.

Each worker builds one World and keeps its simulator and renderer warm. Work is handed out one rollout at a
time to whichever worker is free; results come back in submission order. Rollouts are seeded from the run
seed and the attempt index (see `seeded_rollout`), so the dataset does not depend on the number of workers.
One scheduling-and-retry loop (`PoolEvaluator`) serves both backends: a worker that dies, raises or exceeds the
per-rollout timeout is replaced and the rollout retried; each such event is counted (`failures`) and reported
with the attempt.

`submit` returns at once and hands the batch to a dispatch thread, which keeps every worker busy while the run
loop writes the previous generation's episodes; `collect` waits for that thread. Without the thread, work would
only be handed out inside `collect`, and the workers would sit idle for most of the writing.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import signal
import threading
import time
import traceback
from abc import abstractmethod
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import wait

from babblegen.config import ConfigError, RunConfig
from babblegen.evaluation import Evaluator, Prepare
from babblegen.scene import TaskSpec
from babblegen.world.rollout import Command, Rollout
from babblegen.world.settings import WorldSettings

log = logging.getLogger(__name__)

# How long a worker with episodes to prepare waits for its next rollout when the batch has more to hand out,
# before it prepares one (the coordinator answers a returned rollout with the next request in milliseconds).
NEXT_REQUEST_GRACE_S = 0.05
_DONE = object()


def _worker_main(conn, task_name: str, settings: WorldSettings, run_seed: int, prepare: Prepare | None) -> None:
    """Worker loop: build a World once, then answer requests until told to stop (``None``):

    - ``("run", attempt, command, more)``: simulate; the rollout goes back at once (a Python error is sent back
      instead: the coordinator replaces this worker and retries, as for a crash);
    - ``("prepare", attempt, rollout)``: prepare a rollout another worker simulated;
    - ``("forget", attempt)``: another worker prepares this one.

    With ``prepare`` (encoding the episode), a rollout goes back with only its first and last frames rendered
    (`World.rollout`'s ``defer_render``); rendering the others and preparing the episode wait until no request
    is pending, pause every few frames for one that arrives, and go back as a ``"prepared"`` message. The
    movements, which the next generation waits for, come first; rendering and encoding fill the time a worker
    would otherwise wait for the others at the end of a generation. ``more`` says whether the batch has
    rollouts left to hand out, so whether the next request is about to arrive."""
    # Ctrl-C in a terminal reaches the whole process group: the coordinator stops the run and then the workers
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # (already so when spawned from the main thread: `_spawn`)
    os.environ.setdefault("LP_NUM_THREADS", "1")  # one rendering thread per worker process
    import torch

    torch.set_num_threads(1)  # one core per worker: idle torch threads would spin against the other processes
    from babblegen.evaluation import render_and_prepare_stepwise, seeded_rollout, warm_up
    from babblegen.tasks import get_task
    from babblegen.world.world import World

    world = World(get_task(task_name), settings, seed=run_seed)
    warm_up(world, prepare)
    conn.send(("ready", None))
    pending: dict[int, Rollout] = {}  # to render and prepare here (simulated here or handed over), in order
    work: tuple[int, Rollout, Iterator[None]] | None = None  # the preparation under way, and its steps
    more = False
    while True:
        if (work or pending) and not conn.poll(NEXT_REQUEST_GRACE_S if more else 0.0):
            more = False  # (no request came: the batch's last rollouts went to other workers)
            if work is None:
                attempt = next(iter(pending))
                rollout = pending.pop(attempt)
                work = (attempt, rollout, render_and_prepare_stepwise(world, rollout, prepare))
            attempt, rollout, steps = work
            if next(steps, _DONE) is _DONE:
                timings = {k: rollout.timings[k] for k in ("render", "prepare") if k in rollout.timings}
                conn.send(("prepared", (attempt, rollout.prepared, timings)))
                work = None
            continue
        msg = conn.recv()
        if msg is None:
            break
        kind, attempt, *rest = msg
        if kind == "forget":
            pending.pop(attempt, None)
            if work is not None and work[0] == attempt:
                work = None
            continue
        if kind == "prepare":
            pending[attempt] = rest[0]
            continue
        command, more = rest
        try:
            rollout = seeded_rollout(world, command, run_seed, attempt, defer_render=prepare is not None)
        except Exception:
            conn.send(("error", traceback.format_exc(limit=-3)))
            continue
        conn.send(("ok", rollout))
        if prepare is not None and rollout.feasible:
            pending[attempt] = rollout
    world.close()


@contextlib.contextmanager
def _ctrl_c_ignored():
    """Ignore SIGINT in this process meanwhile (from the main thread only, where Python allows it): a process
    spawned then starts with it ignored, and Python installs no KeyboardInterrupt handler in it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


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
class Failure:
    """A rollout that did not come back: its worker died, raised, or was lost."""

    reason: str


class PoolEvaluator(_BatchThread):
    """One scheduling-and-retry loop over ``n`` worker slots of a backend (processes or Ray actors).

    Work goes one rollout at a time to whichever slot is free, the genomes with the most waypoints first. The
    one failure policy: a rollout whose worker
    dies, raises a Python error or exceeds ``timeout`` seconds is counted (``failures``, and the attempt's
    ``worker_failures``), its worker is replaced by a fresh one, and it is retried, at most ``retries`` times;
    then the run stops with an error naming the attempt. Subclasses implement the four slot operations.
    """

    kind = "worker"

    def __init__(self, n: int, timeout: float = 300.0, retries: int = 2):
        self.n, self.timeout, self.max_retries = n, timeout, retries
        self.failures = 0

    @abstractmethod
    def _send(self, slot: int, attempt: int, command: Command, more: bool) -> None:
        """Start one rollout on a free slot (``more``: the batch has rollouts left to hand out)."""

    @abstractmethod
    def _wait(self, busy: list[int], timeout: float) -> list[tuple[int, Rollout | Failure]]:
        """Outcomes of the busy slots that finished within ``timeout`` seconds (possibly none)."""

    @abstractmethod
    def _replace(self, slot: int) -> None:
        """Put a fresh worker in the slot."""

    def _started(self, slot: int, job: tuple[int, Command] | None) -> None:  # noqa: B027  (optional hook)
        """Called when a slot takes (``job``) or leaves (``None``) a rollout."""

    def _share_work(self, busy: set[int]) -> None:  # noqa: B027  (optional hook)
        """Called while the batch has no rollout left to hand out and only the ``busy`` slots run one."""

    def _run_batch(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        results: dict[int, Rollout] = {}
        retries: dict[int, int] = {}
        # longest first (more waypoints, longer movements): the batch's last rollout, which the other workers wait
        # for, is then a short one; results still come back in submission order
        queue = deque(sorted(range(len(commands)), key=lambda i: -len(commands[i].values)))
        jobs: dict[int, tuple[int, float]] = {}  # slot -> (index in the batch, start time)

        def failed(slot: int, i: int, reason: str) -> None:
            self.failures += 1
            retries[i] = retries.get(i, 0) + 1
            giving_up = retries[i] > self.max_retries
            log.warning(
                "rollout %s for attempt %d %s; replacing it, %s",
                self.kind,
                attempts[i],
                reason,
                "giving up" if giving_up else "retrying",
            )
            if giving_up:
                raise RuntimeError(f"attempt {attempts[i]} failed on {retries[i]} {self.kind}s: {reason}")
            self._replace(slot)
            queue.appendleft(i)

        while len(results) < len(commands):
            if self._closing:
                raise _Cancelled
            for slot in range(self.n):
                if slot not in jobs and queue:
                    i = queue.popleft()
                    jobs[slot] = (i, time.monotonic())
                    self._started(slot, (i, commands[i]))
                    self._send(slot, attempts[i], commands[i], bool(queue))
            if not queue:
                self._share_work(set(jobs))
            for slot, outcome in self._wait(list(jobs), timeout=1.0):
                i, _ = jobs.pop(slot)
                self._started(slot, None)
                if isinstance(outcome, Failure):
                    failed(slot, i, outcome.reason)
                else:
                    results[i] = outcome
            now = time.monotonic()
            for slot, (i, start) in list(jobs.items()):
                if now - start > self.timeout:
                    del jobs[slot]
                    self._started(slot, None)
                    failed(slot, i, f"timed out after {self.timeout:.0f} s")
        out = [results[i] for i in range(len(commands))]
        for i, r in enumerate(out):
            r.timings["worker_failures"] = float(retries.get(i, 0))
        return out


@dataclass
class _Worker:
    process: mp.Process
    conn: object
    job: tuple[int, Command] | None = None
    attempt: int | None = None  # of the rollout last handed to it
    owed: dict[int, None] = field(default_factory=dict)  # attempts whose preparation it is to send, in its order


class ProcessEvaluator(PoolEvaluator):
    """``n`` local worker processes. Each returns a rollout as soon as it is simulated, and renders and prepares
    the episode when it has no rollout to run (`_worker_main`); a worker left with nothing to do at the end of a
    batch takes over preparations from a busy one (`_share_work`). `attach_prepared` hands each preparation to
    its rollout. The preparations a worker owed when it died go to its replacement (this process has no
    renderer), at most ``retries`` times per attempt."""

    kind = "worker process"

    def __init__(
        self,
        task: TaskSpec,
        settings: WorldSettings,
        run_seed: int,
        n: int,
        timeout: float = 300.0,
        retries: int = 2,
        prepare: Prepare | None = None,
    ):
        super().__init__(n, timeout, retries)
        self.task, self.settings, self.run_seed, self.prepare = task, settings, run_seed, prepare
        self._prepared: dict[int, tuple[dict, dict]] = {}  # attempt -> (preparation, its render/prepare seconds)
        self._unprepared: dict[int, Rollout] = {}  # returned rollouts whose preparation has not arrived
        self._handed_over: dict[int, int] = {}  # attempt -> times its preparation went to a replacement worker
        self._arrived = threading.Condition()
        self.ctx = mp.get_context("spawn")
        self.workers = [self._spawn() for _ in range(n)]  # they start in the background: see `wait_ready`
        self._starting = list(self.workers)

    def wait_ready(self) -> None:
        while self._starting:
            self._await_ready(self._starting[0])
            self._starting.pop(0)  # only now: `close` kills the workers still starting

    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        self.wait_ready()
        super().submit(commands, attempts)

    def _spawn(self) -> _Worker:
        parent, child = self.ctx.Pipe()
        p = self.ctx.Process(
            target=_worker_main, args=(child, self.task.name, self.settings, self.run_seed, self.prepare), daemon=True
        )
        with _ctrl_c_ignored():  # inherited: a Ctrl-C while the worker imports its libraries prints no traceback
            p.start()
        child.close()
        return _Worker(p, parent)

    def _await_ready(self, w: _Worker, timeout: float = 600.0) -> None:
        if not w.conn.poll(timeout):
            raise RuntimeError("a rollout worker did not start")
        tag, _ = w.conn.recv()
        assert tag == "ready"

    def _started(self, slot: int, job: tuple[int, Command] | None) -> None:
        self.workers[slot].job = job

    def _send(self, slot: int, attempt: int, command: Command, more: bool) -> None:
        w = self.workers[slot]
        w.attempt = attempt
        self._tell(w, ("run", attempt, command, more))

    @staticmethod
    def _tell(w: _Worker, message: tuple) -> None:
        with contextlib.suppress(BrokenPipeError, OSError):  # a dead worker is noticed by `_wait`
            w.conn.send(message)

    def _receive(self, w: _Worker) -> Rollout | Failure | None:
        """Read what a worker has sent: preparations are kept for `attach_prepared`; the outcome of its rollout,
        if among them, is returned."""
        outcome: Rollout | Failure | None = None
        try:
            while w.conn.poll():
                status, value = w.conn.recv()
                with self._arrived:
                    if status == "prepared":
                        attempt, prepared, timings = value
                        if self._unprepared.pop(attempt, None) is not None:  # else already here (taken over)
                            self._prepared[attempt] = (prepared, timings)
                        w.owed.pop(attempt, None)
                        for other in self.workers:  # an owner can finish one just handed to another worker
                            if other is not w and attempt in other.owed:
                                del other.owed[attempt]
                                self._tell(other, ("forget", attempt))
                        self._arrived.notify_all()
                    elif status == "ok":
                        if self.prepare is not None and value.feasible:
                            w.owed[w.attempt] = None
                            self._unprepared[w.attempt] = value
                        outcome = value
                    else:
                        outcome = Failure(f"raised an error:\n{value}")
        except (EOFError, OSError):
            return outcome or Failure("died")
        return outcome

    def _wait(self, busy: list[int], timeout: float) -> list[tuple[int, Rollout | Failure]]:
        sentinels = [self.workers[s].process.sentinel for s in busy]
        ready = wait([w.conn for w in self.workers] + sentinels, timeout=timeout)
        out: list[tuple[int, Rollout | Failure]] = []
        for slot, w in enumerate(self.workers):
            outcome = self._receive(w) if w.conn in ready else None
            if slot not in busy:
                if isinstance(outcome, Failure):  # died between rollouts, preparing episodes
                    self._replace_idle(slot)
            elif outcome is not None:
                out.append((slot, outcome))
            elif w.process.sentinel in ready or not w.process.is_alive():
                out.append((slot, Failure("died")))
        return out

    def _replace_idle(self, slot: int) -> None:
        self.failures += 1
        log.warning("rollout %s died between rollouts; replacing it", self.kind)
        self._replace(slot)

    def _replace(self, slot: int) -> None:
        w = self.workers[slot]
        w.process.kill()
        w.process.join(5)
        fresh = self._spawn()
        self._await_ready(fresh)
        self.workers[slot] = fresh
        for attempt in list(w.owed):  # what it owed, its replacement renders and prepares
            self._hand_over(fresh, attempt)

    def _hand_over(self, w: _Worker, attempt: int) -> None:
        tries = self._handed_over[attempt] = self._handed_over.get(attempt, 0) + 1
        if tries > self.max_retries:
            raise RuntimeError(f"preparing attempt {attempt}'s episode failed on {tries} {self.kind}es")
        with self._arrived:
            w.owed[attempt] = None
        self._tell(w, ("prepare", attempt, self._unprepared[attempt]))

    def attach_prepared(self, rollout: Rollout, attempt: int, wait: bool) -> bool:
        if self.prepare is None or not rollout.feasible:
            return True
        while True:
            with self._arrived:
                if attempt in self._prepared:
                    prepared, timings = self._prepared.pop(attempt)
                    self._handed_over.pop(attempt, None)
                    rollout.prepared.update(prepared)
                    rollout.timings.update(timings)
                    return True
                if self._thread is not None and self._thread.is_alive():
                    if not wait:
                        return False
                    self._arrived.wait(0.05)  # the dispatch thread reads the workers' messages
                    continue
            self._read_between_batches(0.05 if wait else 0.0)
            if not wait and attempt not in self._prepared:
                return False

    def _share_work(self, busy: set[int]) -> None:
        """Hand a worker with nothing to do the preparation another worker would do last: one that is running a
        rollout, or preparing more than one episode. The owner is told to forget it."""
        for slot, thief in enumerate(self.workers):
            if slot in busy or thief.owed:
                continue
            shareable = {
                s: list(w.owed) if s in busy else list(w.owed)[1:]  # an idle one is preparing its first
                for s, w in enumerate(self.workers)
                if s != slot
            }
            owner = max(shareable, key=lambda s: len(shareable[s]), default=None)
            if owner is None or not shareable[owner]:
                return
            attempt = shareable[owner][-1]
            with self._arrived:
                del self.workers[owner].owed[attempt]
                thief.owed[attempt] = None
            self._tell(self.workers[owner], ("forget", attempt))
            self._tell(thief, ("prepare", attempt, self._unprepared[attempt]))

    def _read_between_batches(self, timeout: float) -> None:
        """Read the workers' messages while no batch runs (only preparations can arrive); replace a worker that
        died owing some."""
        ready = wait([w.conn for w in self.workers], timeout=timeout)
        for slot, w in enumerate(self.workers):
            died = w.conn in ready and isinstance(self._receive(w), Failure)
            if died or (w.owed and not w.process.is_alive()):
                self._replace_idle(slot)

    def close(self) -> None:
        self._stop_dispatch()
        for w in self._starting:  # closed before they were ready (an error, Ctrl-C): nothing of theirs to keep
            w.process.kill()
        for w in self.workers:
            with contextlib.suppress(BrokenPipeError, OSError):
                w.conn.send(None)
        for w in self.workers:
            w.process.join(10)
            if w.process.is_alive():
                w.process.kill()


class RayEvaluator(PoolEvaluator):
    """One Ray actor per worker slot, each with its own World; same scheduling and failure policy."""

    kind = "Ray actor"

    def __init__(
        self,
        task: TaskSpec,
        settings: WorldSettings,
        run_seed: int,
        address: str,
        n: int | None = None,
        timeout: float = 300.0,
        retries: int = 2,
        prepare: Prepare | None = None,
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
        super().__init__(n, timeout, retries)

        @ray.remote(num_cpus=1, max_restarts=0)
        class RolloutActor:
            def __init__(self, task_name: str, settings: WorldSettings, run_seed: int, prepare: Prepare | None):
                os.environ.setdefault("LP_NUM_THREADS", "1")
                import torch

                torch.set_num_threads(1)
                from babblegen.evaluation import warm_up
                from babblegen.tasks import get_task
                from babblegen.world.world import World

                self.world = World(get_task(task_name), settings, seed=run_seed)
                warm_up(self.world, prepare)
                self.run_seed, self.prepare = run_seed, prepare

            def ping(self) -> bool:
                return True

            def rollout(self, attempt: int, command: Command) -> Rollout:
                from babblegen.evaluation import seeded_rollout

                return seeded_rollout(self.world, command, self.run_seed, attempt, self.prepare)

        self._actor_cls = RolloutActor
        self._args = (task.name, settings, run_seed, prepare)
        self.actors = [self._actor_cls.remote(*self._args) for _ in range(n)]
        ray.get([a.ping.remote() for a in self.actors])
        self._refs: dict[int, object] = {}

    def _send(self, slot: int, attempt: int, command: Command, more: bool) -> None:
        self._refs[slot] = self.actors[slot].rollout.remote(attempt, command)

    def _wait(self, busy: list[int], timeout: float) -> list[tuple[int, Rollout | Failure]]:
        ray = self.ray
        refs = {self._refs[s]: s for s in busy}
        if not refs:
            time.sleep(min(timeout, 0.05))
            return []
        ready, _ = ray.wait(list(refs), num_returns=1, timeout=timeout)
        if ready:  # and whatever else has finished meanwhile
            ready, _ = ray.wait(list(refs), num_returns=len(refs), timeout=0)
        out: list[tuple[int, Rollout | Failure]] = []
        for ref in ready:
            slot = refs[ref]
            del self._refs[slot]
            try:
                out.append((slot, ray.get(ref)))
            except ray.exceptions.RayActorError as e:
                out.append((slot, Failure(f"died ({type(e).__name__})")))
            except ray.exceptions.RayTaskError as e:
                out.append((slot, Failure(f"raised an error:\n{e}")))
        return out

    def _replace(self, slot: int) -> None:
        self._refs.pop(slot, None)
        self.ray.kill(self.actors[slot])
        self.actors[slot] = self._actor_cls.remote(*self._args)

    def close(self) -> None:
        self._stop_dispatch()
        for a in self.actors:
            self.ray.kill(a)
        if self._owns_ray:
            self.ray.shutdown()


def make_parallel_evaluator(task: TaskSpec, config: RunConfig, prepare: Prepare | None = None) -> Evaluator:
    if config.ray:
        n = config.workers if config.workers > 1 else None
        try:
            return RayEvaluator(task, config.world, config.seed, config.ray, n=n, prepare=prepare)
        except ImportError:
            raise ConfigError("--ray needs Ray: pip install 'babblegen[ray]'") from None
    return ProcessEvaluator(task, config.world, config.seed, config.workers, prepare=prepare)
