"""Scheduling rollouts over a pool of worker slots, in attempt order, whatever runs them.

`PoolEvaluator` queues the rollouts of every batch submitted and not collected (NovEB's overlapping generations
submit several). One dispatch thread hands them to whichever slot is free: the oldest batch first and, within a
batch, the genomes with the most waypoints first (the batch's last rollout, which the search waits for, is then a
short one). `collect` returns the oldest batch's rollouts, in submission order, once all are in: results are
applied in attempt order, never in the order they finish.

The one failure policy: a rollout whose worker dies, raises a Python error or exceeds ``timeout`` seconds is
counted (``failures``, and the attempt's ``worker_failures``), its worker is replaced by a fresh one and the
rollout is retried, at most ``retries`` times; then collecting its batch raises an error naming the attempt (the
rest of that batch is dropped; the pool goes on with the other batches).
What a slot is (a local process, a Ray actor, a benchmark's stand-in) is the subclass's: it implements the slot
operations `_send`, `_wait` and `_replace`.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import abstractmethod
from collections import deque
from dataclasses import dataclass, field

from babblegen.evaluation import Evaluator
from babblegen.world.rollout import Command, Rollout

log = logging.getLogger(__name__)


@dataclass
class Failure:
    """A rollout that did not come back: its worker died, raised, or was lost."""

    reason: str


@dataclass
class _Batch:
    commands: list[Command]
    attempts: list[int]
    queued: deque[int]  # indices in the batch not handed out yet, in dispatch order
    results: dict[int, Rollout] = field(default_factory=dict)
    retries: dict[int, int] = field(default_factory=dict)
    error: Exception | None = None  # a rollout of it failed too often: collecting it raises this

    @property
    def complete(self) -> bool:
        return self.error is not None or len(self.results) == len(self.commands)


class _Closing(Exception):
    pass


class PoolEvaluator(Evaluator):
    """Rollouts of every submitted batch over ``n`` worker slots (see the module docstring).

    Subclasses implement the slot operations. ``poll_seconds`` bounds how long the dispatch thread waits for an
    outcome before it looks at new work and timeouts again; a backend that can wake it on `submit` (`_wake`)
    can wait long.
    """

    kind = "worker"
    poll_seconds = 1.0

    def __init__(self, n: int, timeout: float = 300.0, retries: int = 2):
        self.n, self.timeout, self.max_retries = n, timeout, retries
        self.failures = 0
        self._state = threading.Condition()  # guards the batches and the error; notified when a batch completes
        self._batches: deque[_Batch] = deque()  # submitted, not collected, oldest first
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self._closing = False

    # --- slot operations (the backend's) --------------------------------------------------------------------
    @abstractmethod
    def _send(self, slot: int, attempt: int, command: Command, more: bool) -> None:
        """Start one rollout on a free slot (``more``: rollouts are queued behind it)."""

    @abstractmethod
    def _wait(self, busy: list[int], timeout: float) -> list[tuple[int, Rollout | Failure]]:
        """Outcomes of the busy slots that finished within ``timeout`` seconds (possibly none)."""

    @abstractmethod
    def _replace(self, slot: int) -> None:
        """Put a fresh worker in the slot."""

    def _wake(self) -> None:  # noqa: B027  (optional hook)
        """Make a `_wait` in progress return now (new work was submitted)."""

    def _started(self, slot: int, job: tuple[int, Command] | None) -> None:  # noqa: B027  (optional hook)
        """Called when a slot takes (``job``: attempt, command) or leaves (``None``) a rollout."""

    def _share_work(self, busy: set[int]) -> None:  # noqa: B027  (optional hook)
        """Called while no rollout is queued and only the ``busy`` slots run one."""

    # --- the Evaluator interface ----------------------------------------------------------------------------
    def submit(self, commands: list[Command], attempts: list[int]) -> None:
        order = deque(sorted(range(len(commands)), key=lambda i: -len(commands[i].values)))
        with self._state:
            self._batches.append(_Batch(list(commands), list(attempts), order))
        if self._thread is None:
            self._thread = threading.Thread(target=self._dispatch, name="rollout-dispatch", daemon=True)
            self._thread.start()
        self._wake()

    def collect(self) -> list[Rollout]:
        with self._state:
            if not self._batches:
                raise RuntimeError("nothing submitted")
            batch = self._batches[0]
            while not batch.complete and self._error is None:
                self._state.wait(0.2)  # short waits: the main thread stays responsive to Ctrl-C
            if self._error is not None:
                raise self._error
            self._batches.popleft()
        if batch.error is not None:
            raise batch.error
        out = [batch.results[i] for i in range(len(batch.commands))]
        for i, r in enumerate(out):
            r.timings["worker_failures"] = float(batch.retries.get(i, 0))
        return out

    def evaluate(self, commands: list[Command], attempts: list[int]) -> list[Rollout]:
        self.submit(commands, attempts)
        return self.collect()

    @property
    def dispatching(self) -> bool:
        """The dispatch thread runs (it stops at `close` or at an error that ends the run)."""
        return self._thread is not None and self._thread.is_alive()

    def _stop_dispatch(self) -> None:
        """Make the dispatch thread give up (on close, e.g. after an interruption) and wait for it."""
        self._closing = True
        self._wake()
        if self._thread is not None:
            self._thread.join(10)

    # --- the dispatch thread --------------------------------------------------------------------------------
    def _next_job(self) -> tuple[_Batch, int] | None:
        with self._state:
            for batch in self._batches:
                if batch.queued:
                    return batch, batch.queued.popleft()
        return None

    def _queued(self) -> bool:
        with self._state:
            return any(b.queued for b in self._batches)

    def _dispatch(self) -> None:
        jobs: dict[int, tuple[_Batch, int, float]] = {}  # slot -> (batch, index in it, start time)
        try:
            while True:
                if self._closing:
                    raise _Closing
                for slot in range(self.n):
                    if slot in jobs:
                        continue
                    job = self._next_job()
                    if job is None:
                        break
                    batch, i = job
                    jobs[slot] = (batch, i, time.monotonic())
                    self._started(slot, (batch.attempts[i], batch.commands[i]))
                    self._send(slot, batch.attempts[i], batch.commands[i], self._queued())
                if not self._queued():
                    self._share_work(set(jobs))
                for slot, outcome in self._wait(list(jobs), timeout=self.poll_seconds):
                    batch, i, _ = jobs.pop(slot)
                    self._started(slot, None)
                    if isinstance(outcome, Failure):
                        self._failed(slot, batch, i, outcome.reason)
                        continue
                    with self._state:
                        batch.results[i] = outcome
                        if batch.complete:
                            self._state.notify_all()
                now = time.monotonic()
                for slot, (batch, i, start) in list(jobs.items()):
                    if now - start > self.timeout:
                        del jobs[slot]
                        self._started(slot, None)
                        self._failed(slot, batch, i, f"timed out after {self.timeout:.0f} s")
        except _Closing:
            pass
        except BaseException as e:  # handed to collect() in the calling thread
            with self._state:
                self._error = e
                self._state.notify_all()

    def _failed(self, slot: int, batch: _Batch, i: int, reason: str) -> None:
        self.failures += 1
        if batch.error is not None:  # its batch failed already: nothing to retry
            self._replace(slot)
            return
        tries = batch.retries[i] = batch.retries.get(i, 0) + 1
        giving_up = tries > self.max_retries
        log.warning(
            "rollout %s for attempt %d %s; replacing it, %s",
            self.kind,
            batch.attempts[i],
            reason,
            "giving up" if giving_up else "retrying",
        )
        self._replace(slot)
        with self._state:
            if giving_up:
                batch.error = RuntimeError(f"attempt {batch.attempts[i]} failed on {tries} {self.kind}s: {reason}")
                batch.queued.clear()
                self._state.notify_all()
            else:
                batch.queued.appendleft(i)
