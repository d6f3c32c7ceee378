"""SIGINT / SIGTERM at any moment of a run: a stop that never tears a dataset write in half, and never fails.

One `Interrupts` takes both signals over for a run's whole life. The console script installs it at its first line
(`babblegen.console`), before the half second of imports, and it stays until the process ends; a run started from
Python gets one for the run's duration (`for_command`).

- Outside `raising()` a signal is recorded only: during the imports (nothing is written yet), and from the end of
  the run's last commit to the process's end (closing, the summary). A stop recorded before `raising()` is raised
  on entering it.
- Inside `raising()` (the run's start-up and its loop) a signal raises `Interrupted` at once, so a stop is prompt
  during imports, simulation and waits. Inside a `protected()` section (opening the dataset, writing an episode,
  committing, starting a worker process) it is held until the section ends, because LeRobot's writer runs
  image-writer threads and an encoder that an exception raised in the middle leaves inconsistent. A second signal
  during a protected section raises at once: the user insists.
- Never while an exception is being handled (an ``except`` or ``finally`` block: the clean-up after a stop or an
  error): an exception raised there would replace the one being handled and cut its clean-up short. The signal is
  recorded and the clean-up goes on.

`Interrupted` is a BaseException, like KeyboardInterrupt, so that library code's ``except Exception`` neither
swallows it nor turns it into an error of its own: SAPIEN's URDF parser, which runs in every scene rebuild (in the
run's process with one worker), re-raises whatever it catches as a ValueError, which ended a stopped run with exit
status 1. `stopped_by` still recognises an error raised while a stop was being handled (a bare ``except:``).
Worker processes never act on these signals (`spawning`): the run stops them itself.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)

_installed: Interrupts | None = None  # the one whose handlers are in place


class Interrupted(BaseException):
    """Raised in the main thread by SIGINT / SIGTERM (a BaseException: see the module docstring)."""


class Interrupts:
    """Install with `with Interrupts() as stop:` (or `install`); the previous handlers come back on exit (`restore`).
    ``raising``: whether a signal raises at once from the start; otherwise only inside `raising()`."""

    def __init__(self, raising: bool = True) -> None:
        self.pending: str | None = None
        self._depth = 0
        self._raising = raising
        self._previous: dict = {}
        self._outer: Interrupts | None = None

    def install(self) -> Interrupts:
        global _installed
        self._previous = {s: signal.getsignal(s) for s in SIGNALS}
        self._outer = _installed
        for s in SIGNALS:
            signal.signal(s, self._handle)
        _installed = self
        return self

    def restore(self) -> None:
        global _installed
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        _installed = self._outer

    def __enter__(self) -> Interrupts:
        return self.install()

    def __exit__(self, *exc) -> None:
        self.restore()

    def _handle(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        first = self.pending is None
        # Recorded in every case: Python drops an exception raised while a __del__ runs (the simulator frees its old
        # scene on every reset), and then the end of the next protected section raises it again.
        self.pending = self.pending or name
        if not self._raising or sys.exception() is not None:
            return
        if self._depth and first:
            return
        raise Interrupted(name)

    def check(self) -> None:
        """Raise the stop recorded, if any (inside `raising()`)."""
        if self.pending is not None and self._raising:
            raise Interrupted(self.pending)

    @contextmanager
    def raising(self) -> Iterator[None]:
        """Raise at once meanwhile (a stop recorded before raises on entry); record only after."""
        self._raising = True
        try:
            self.check()
            yield
        finally:
            self._raising = False

    def record_only(self) -> None:
        """From now on a signal is only recorded (the run has finished: what is left is closing it)."""
        self._raising = False

    @contextmanager
    def protected(self) -> Iterator[None]:
        """Hold a stop until the block is done, then raise it."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if not self._depth:
            self.check()

    @contextmanager
    def closing(self) -> Iterator[None]:
        """Record signals without raising, for the final commit and cleanup."""
        raising, self._raising = self._raising, False
        try:
            yield
        finally:
            self._raising = raising


def installed() -> Interrupts | None:
    """The `Interrupts` whose handlers are in place, if any."""
    return _installed


@contextmanager
def for_command() -> Iterator[Interrupts]:
    """The installed `Interrupts` (the console script's, which stays until the process ends), or one installed for
    the block, recording only until `Interrupts.raising` (a run started from Python)."""
    if _installed is not None:
        yield _installed
        return
    with Interrupts(raising=False) as stop:
        yield stop


@contextmanager
def spawning() -> Iterator[None]:
    """Start child processes meanwhile that never act on SIGINT or SIGTERM: both are blocked in this thread, and a
    child starts with the signals its parent's thread blocks (a run's workers leave the stopping to the run, which
    ends them; Ctrl-C in a terminal, ``timeout`` and batch schedulers signal the whole process group). A signal that
    arrives meanwhile is delivered once they are unblocked, never lost; in the main thread a stop is also held
    until the block is done, so a child is never left half started (reading the rest of its start-up data, which
    never comes, it would print a traceback)."""
    main = threading.current_thread() is threading.main_thread()
    with _installed.protected() if main and _installed is not None else contextlib.nullcontext():
        previous = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
        try:
            yield
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def stopped_by(error: BaseException) -> bool:
    """Whether ``error`` is a stop, or was raised while one was handled (library code that wraps what it catches)."""
    seen, todo = set(), [error]
    while todo:
        e = todo.pop()
        if e is None or id(e) in seen:
            continue
        if isinstance(e, Interrupted | KeyboardInterrupt):
            return True
        seen.add(id(e))
        todo += [e.__cause__, e.__context__]
    return False
