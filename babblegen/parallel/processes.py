"""Rollouts on local worker processes: spawning, pipes, replacing the dead, and sharing the episodes' rendering
and encoding among the workers (what runs when is `babblegen.parallel.scheduler`'s)."""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import threading
from dataclasses import dataclass, field
from multiprocessing import resource_tracker
from multiprocessing.connection import wait

from babblegen.evaluation import Describe, Prepare
from babblegen.interrupts import spawning
from babblegen.parallel.scheduler import Failure, PoolEvaluator
from babblegen.parallel.worker import worker_main
from babblegen.scene import TaskSpec
from babblegen.world.rollout import Command, Rollout
from babblegen.world.settings import WorldSettings

log = logging.getLogger(__name__)


@dataclass
class _Worker:
    process: mp.Process
    conn: object
    job: tuple[int, Command] | None = None
    attempt: int | None = None  # of the rollout last handed to it
    owed: dict[int, None] = field(default_factory=dict)  # attempts whose preparation it is to send, in its order


def _kill(process: mp.Process) -> None:
    """Kill a worker process and reap it: nothing of the run's session outlives the run."""
    process.kill()
    process.join(5)


class ProcessEvaluator(PoolEvaluator):
    """``n`` local worker processes (`babblegen.parallel.worker`). Each returns a rollout as soon as it is
    simulated, and renders and prepares the episode when it has no rollout to run; a worker left with nothing to
    do takes over preparations from a busy one (`_share_work`). `attach_prepared` hands each preparation to its
    rollout. The preparations a worker owed when it died go to its replacement (this process has no renderer),
    at most ``retries`` times per attempt. Every message from the workers is read by the dispatch thread."""

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
        describe: Describe | None = None,
    ):
        super().__init__(n, timeout, retries)
        self.task, self.settings, self.run_seed, self.prepare = task, settings, run_seed, prepare
        self.describe = describe
        self._prepared: dict[int, tuple[dict, dict]] = {}  # attempt -> (preparation, its render/prepare seconds)
        self._unprepared: dict[int, Rollout] = {}  # returned rollouts whose preparation has not arrived
        self._handed_over: dict[int, int] = {}  # attempt -> times its preparation went to a replacement worker
        self._arrived = threading.Condition()
        self._wake_reader, self._wake_writer = mp.Pipe(duplex=False)
        self.ctx = mp.get_context("spawn")
        self.workers: list[_Worker] = []
        try:
            for _ in range(n):  # they start in the background: see `wait_ready`
                self.workers.append(self._spawn())
        except BaseException:  # a stop (or an error) while spawning: none is left starting for nobody
            for w in self.workers:
                _kill(w.process)
            raise
        self._starting = list(self.workers)

    def wait_ready(self) -> None:
        while self._starting:
            self._await_ready(self._starting[0])
            self._starting.pop(0)  # only now: `close` kills the workers still starting

    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        self.wait_ready()
        super().submit(commands, attempts)

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_writer.send_bytes(b"")

    def _spawn(self) -> _Worker:
        parent, child = self.ctx.Pipe()
        p = self.ctx.Process(
            target=worker_main,
            args=(child, self.task.name, self.settings, self.run_seed, self.prepare, self.describe),
            daemon=True,
        )
        # Starting multiprocessing's resource tracker (the first spawn does) unblocks SIGINT and SIGTERM in this
        # thread: done before, so that the worker is started with both blocked
        resource_tracker.ensure_running()
        try:
            with spawning():  # it never acts on SIGINT / SIGTERM, not even while it imports its libraries
                p.start()
        except BaseException:  # a stop, held until it was started: it is not left warming up for nobody
            if p.pid is not None:
                _kill(p)
            raise
        finally:
            child.close()
        return _Worker(p, parent)

    def _await_ready(self, w: _Worker, timeout: float = 600.0) -> None:
        if not w.conn.poll(timeout):
            raise RuntimeError("a rollout worker did not start")
        tag, fingerprint = w.conn.recv()
        assert tag == "ready"
        self.fingerprint = self.fingerprint or fingerprint  # every worker runs on this machine

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
        ready = wait([self._wake_reader] + [w.conn for w in self.workers] + sentinels, timeout=timeout)
        if self._wake_reader in ready:
            while self._wake_reader.poll():
                self._wake_reader.recv_bytes()
        out: list[tuple[int, Rollout | Failure]] = []
        for slot, w in enumerate(self.workers):
            outcome = self._receive(w) if w.conn in ready else None
            if slot not in busy:
                if isinstance(outcome, Failure) or (w.owed and not w.process.is_alive()):
                    self._replace_idle(slot)  # died between rollouts, preparing episodes
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
        _kill(w.process)
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
        with self._arrived:
            while attempt not in self._prepared:
                if not wait:
                    return False
                if self._error is not None:
                    raise self._error
                if not self.dispatching:
                    raise RuntimeError(f"attempt {attempt}'s episode cannot be prepared: the rollout workers stopped")
                self._arrived.wait(0.05)  # the dispatch thread reads the workers' messages
            prepared, timings = self._prepared.pop(attempt)
            self._handed_over.pop(attempt, None)
        rollout.prepared.update(prepared)
        rollout.timings.update(timings)
        return True

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

    def close(self) -> None:
        self._stop_dispatch()
        for w in self._starting:  # closed before they were ready (an error, Ctrl-C): nothing of theirs to keep
            _kill(w.process)
        for w in self.workers:
            with contextlib.suppress(BrokenPipeError, OSError):
                w.conn.send(None)
        for w in self.workers:
            w.process.join(10)
            if w.process.is_alive():
                _kill(w.process)
