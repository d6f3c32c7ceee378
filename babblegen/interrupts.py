"""SIGINT / SIGTERM handling that never tears a dataset write in half.

A signal raises `Interrupted` at once while the run is simulating or waiting, so a stop is prompt. Inside a
`protected()` section (writing an episode, committing) the stop is held until the section ends, because LeRobot's
writer runs image-writer threads and an encoder that an exception raised in the middle leaves inconsistent. A
second signal during a protected section raises at once: the user insists. During `closing()` signals are only
recorded, so the final commit completes. While an exception is being handled (an ``except`` or ``finally`` block:
the clean-up after a stop or an error) a signal is recorded, never raised: an exception raised there would
replace the one being handled and cut its clean-up short.

`Interrupted` is a BaseException, like KeyboardInterrupt, so that library code's ``except Exception`` neither
swallows it nor turns it into an error of its own: SAPIEN's URDF parser, which runs in every scene rebuild (in the
run's process with one worker), re-raises whatever it catches as a ValueError, which ended a stopped run with exit
status 1. `stopped_by` still recognises an error raised while a stop was being handled (a bare ``except:``).
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """Raised inside the loop by SIGINT / SIGTERM (a BaseException: see the module docstring)."""


class Interrupts:
    """Install with `with Interrupts() as stop:`; the previous handlers come back on exit."""

    def __init__(self) -> None:
        self.pending: str | None = None
        self._depth = 0
        self._closing = False
        self._previous: dict = {}

    def __enter__(self) -> Interrupts:
        self._previous = {s: signal.getsignal(s) for s in SIGNALS}
        for s in SIGNALS:
            signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)

    def _handle(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        if self._closing or sys.exception() is not None:
            self.pending = self.pending or name
            return
        if self._depth and self.pending is None:
            self.pending = name
            return
        # Recorded as well: Python drops an exception raised while a __del__ runs (the simulator frees its old
        # scene on every reset), and then the end of the next protected section raises it again.
        self.pending = self.pending or name
        raise Interrupted(name)

    @contextmanager
    def protected(self) -> Iterator[None]:
        """Hold a stop until the block is done, then raise it."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if not self._depth and self.pending is not None:
            raise Interrupted(self.pending)

    @contextmanager
    def closing(self) -> Iterator[None]:
        """Record signals without raising, for the final commit and cleanup."""
        self._closing = True
        try:
            yield
        finally:
            self._closing = False


class StartupInterrupts:
    """Ctrl-C while a run starts up (imports, workers warming up), before `Interrupts` takes over: a
    KeyboardInterrupt at once, and again at `check()`, because a library can swallow the first one (a bare
    ``except:`` around an optional import) and the run would then go on as if nothing was pressed."""

    def __enter__(self) -> StartupInterrupts:
        self.pending = False
        self._previous = signal.getsignal(signal.SIGINT)
        signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        signal.signal(signal.SIGINT, self._previous)

    def _handle(self, signum: int, frame) -> None:
        self.pending = True
        raise KeyboardInterrupt

    def check(self) -> None:
        if self.pending:
            raise KeyboardInterrupt


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
