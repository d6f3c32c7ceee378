"""The run store: where a run's outputs go, and the one commit / resume / rollback protocol they share.

Every output of a run is a *sink*: the LeRobot episodes, the sidecar tables, the Rerun recordings, the dataset
card. The store hands each attempt to every sink in order, and at a commit point asks each sink for a small
state that describes what it has made durable; those states, the explorer's state and the counters go into
``DIR/babblegen/checkpoint.json`` (the one before it is kept as ``checkpoint.prev.json``, the fallback when the
last is damaged). On resume each sink is rebuilt from its committed state, which rolls back whatever it wrote
after that commit point, however the process ended.
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.config import ConfigError
from babblegen.dataset.paths import CHECKPOINT, PREVIOUS_CHECKPOINT, RUN_INFO, sidecar_dir
from babblegen.dataset.sidecar import read_run_info
from babblegen.lock import DatasetLock
from babblegen.state_file import StateFileError, dumps, loads

FORMAT_VERSION = 2  # 1: sink states stored under their own top-level keys


@dataclass
class AttemptRecord:
    """One attempted movement as the sinks receive it: the sidecar row (``row["episode_index"]`` is set when
    the movement executed) and the rollout with its frames."""

    row: dict[str, Any]
    rollout: Any


class Sink:
    """An output of a run. ``name`` keys its state in the checkpoint. A sink is built from its last committed
    state (``None`` for a new run) and must then hold exactly what that state describes."""

    name = "sink"

    def write(self, record: AttemptRecord) -> None:
        """Take one attempt (called in attempt order)."""

    def write_clones(self, rows: list[dict[str, Any]]) -> None:
        """Take the generation's clones (children that reused a tried genome's outcome)."""

    def commit(self, counters: dict[str, int], final: bool = False) -> dict[str, Any]:
        """Make everything written so far durable; return the state that :meth:`__init__` restores."""
        return {}

    def close(self) -> None:
        """Release files; what was written stays readable (idempotent)."""


SinkMaker = Callable[[dict[str, Any] | None], Sink]


def atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


class RunStore:
    """The directory of one run: its lock, ``run.json``, its checkpoints and its sinks."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.dir = sidecar_dir(self.root)
        self.lock = DatasetLock(self.dir)
        self.sinks: list[Sink] = []
        self.seconds: dict[str, float] = {}  # time spent in each sink (write and commit), for benchmarks

    # --- run.json -------------------------------------------------------------------------------------------
    def write_info(self, info: dict[str, Any]) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        atomic_write(self.dir / RUN_INFO, json.dumps(info, indent=2, default=json_default).encode())

    def info(self) -> dict[str, Any]:
        return read_run_info(self.root)

    def record_extension(self, config: dict[str, Any]) -> None:
        """A resume that extends the run: ``run.json`` says what the run now is, and when it changed."""
        info = self.info()
        if info["config"] != config:
            info["config"] = config
            info.setdefault("resumed", []).append({"at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": sys.argv})
            self.write_info(info)

    # --- checkpoints ----------------------------------------------------------------------------------------
    def has_checkpoint(self) -> bool:
        return (self.dir / CHECKPOINT).exists() or (self.dir / PREVIOUS_CHECKPOINT).exists()

    def read_checkpoint(self, warn: Callable[[str], None]) -> dict[str, Any]:
        """The last commit point, or the one before it when the last is missing or damaged."""
        problems = []
        for name in (CHECKPOINT, PREVIOUS_CHECKPOINT):
            try:
                ckpt = _upgrade(loads((self.dir / name).read_bytes()))
                missing = {"explorer", "counters", "sinks"} - set(ckpt)
                if missing:
                    raise StateFileError(f"missing {', '.join(sorted(missing))}")
            except (OSError, StateFileError) as e:
                problems.append(f"{name}: {e}")
                continue
            if problems:
                warn(f"{problems[0]}; resuming from the commit point before it")
            return ckpt
        raise ConfigError(
            f"--resume: the run state in {self.dir} is damaged and there is no earlier commit point to fall back "
            f"to ({'; '.join(problems)}); the episodes written so far still load with LeRobot"
        )

    # --- writing in the background ------------------------------------------------------------------------
    def start_writer(self) -> None:
        """From now on `write`, `write_clones` and `commit` hand their work to a writer thread and return: the
        run loop goes on asking and telling while a commit point writes its files (a segment's video, tables and
        recording take about a second, which 32 workers would otherwise spend waiting for the next generation).
        The work is done in the order handed over; at most one commit point waits behind the one being written
        (the caller waits for room); an error in the writer is raised by the next call, and by `close`."""
        self._work: deque[tuple] = deque()
        self._commits_waiting = 0
        self._writer_error: BaseException | None = None
        self._handed = threading.Condition()
        self._writer = threading.Thread(target=self._write_in_background, name="dataset-writer", daemon=True)
        self._writer.start()

    def _hand_over(self, job: tuple) -> None:
        with self._handed:
            self._raise_writer_error()
            if job[0] == "commit":
                while self._commits_waiting >= 2 and self._writer_error is None:
                    self._handed.wait(0.2)  # short waits: a Ctrl-C is not held up
                self._raise_writer_error()
                self._commits_waiting += 1
            self._work.append(job)
            self._handed.notify_all()

    def _raise_writer_error(self) -> None:
        if self._writer_error is not None:
            error, self._writer_error = self._writer_error, None
            self._writer_failed = True
            raise error

    def wait_written(self) -> None:
        """Wait until everything handed over is written (raises the writer's error, if any)."""
        if getattr(self, "_writer", None) is None:
            return
        with self._handed:
            while (self._work or self._busy) and self._writer_error is None:
                self._handed.wait(0.2)
            self._raise_writer_error()

    _busy = False
    _writer_failed = False

    def _write_in_background(self) -> None:
        while True:
            with self._handed:
                while not self._work:
                    self._handed.wait()
                job = self._work.popleft()
                if job[0] == "stop":
                    return
                self._busy = True
            try:
                getattr(self, f"_{job[0]}_now")(*job[1:])
            except BaseException as e:
                with self._handed:
                    self._writer_error = e
                    self._work.clear()
                    self._commits_waiting = 0
            finally:
                with self._handed:
                    self._busy = False
                    if job[0] == "commit":
                        self._commits_waiting = max(0, self._commits_waiting - 1)
                    self._handed.notify_all()

    def _stop_writer(self) -> None:
        """Let the writer finish what it was handed, then end it; raises its error, if any."""
        if getattr(self, "_writer", None) is None:
            return
        try:
            self.wait_written()
        finally:
            with self._handed:
                self._work.append(("stop",))
                self._handed.notify_all()
            self._writer.join()
            self._writer = None

    # --- sinks ----------------------------------------------------------------------------------------------
    def open_sinks(self, makers: list[tuple[str, SinkMaker]], states: dict[str, Any] | None = None) -> None:
        """Build each sink from its committed state (``states`` from a checkpoint; ``None`` for a new run)."""
        for name, make in makers:
            self.sinks.append(make(None if states is None else states.get(name)))

    def write(self, record: AttemptRecord) -> None:
        if getattr(self, "_writer", None) is not None:
            return self._hand_over(("write", record))
        self._write_now(record)

    def _write_now(self, record: AttemptRecord) -> None:
        for sink in self.sinks:
            t = time.perf_counter()
            sink.write(record)
            self.seconds[sink.name] = self.seconds.get(sink.name, 0.0) + time.perf_counter() - t

    def write_clones(self, rows: list[dict[str, Any]]) -> None:
        if getattr(self, "_writer", None) is not None:
            return self._hand_over(("write_clones", rows))
        self._write_clones_now(rows)

    def _write_clones_now(self, rows: list[dict[str, Any]]) -> None:
        for sink in self.sinks:
            sink.write_clones(rows)

    def commit(self, explorer_state: dict[str, Any], counters: dict[str, int], final: bool = False) -> None:
        """A commit point: every sink made durable, then one checkpoint naming all their states. With the writer
        started, ``explorer_state`` must be a snapshot (``state_dict`` makes one); a final commit is waited for."""
        if getattr(self, "_writer", None) is None:
            return self._commit_now(explorer_state, dict(counters), final)
        self._hand_over(("commit", explorer_state, dict(counters), final))
        if final:
            self.wait_written()

    def _commit_now(self, explorer_state: dict[str, Any], counters: dict[str, int], final: bool) -> None:
        states = {}
        for sink in self.sinks:
            t = time.perf_counter()
            states[sink.name] = sink.commit(counters, final)
            self.seconds[sink.name] = self.seconds.get(sink.name, 0.0) + time.perf_counter() - t
        data = dumps(
            {
                "format_version": FORMAT_VERSION,
                "explorer": explorer_state,
                "counters": dict(counters),
                "sinks": states,
            }
        )
        if (self.dir / CHECKPOINT).exists():
            os.replace(self.dir / CHECKPOINT, self.dir / PREVIOUS_CHECKPOINT)  # a crash here resumes from this one
        atomic_write(self.dir / CHECKPOINT, data)

    def close(self) -> None:
        """Write what was handed over, close every sink (whatever happened, what is written loads) and release the
        lock; then raise the writer's error, if it had one nobody was told of yet."""
        error = None
        try:
            self._stop_writer()
        except BaseException as e:
            error = e
        try:
            if not self._writer_failed and error is None:
                for sink in self.sinks:
                    sink.close()
            else:  # after a failed write the sinks may not close cleanly: each is closed as far as it can be
                for sink in self.sinks:
                    with contextlib.suppress(Exception):
                        sink.close()
        finally:
            self.lock.release()
        if error is not None:
            raise error


def _upgrade(ckpt: dict[str, Any]) -> dict[str, Any]:
    """Read a format-1 checkpoint (sink states under their own keys) as the current format."""
    if "sinks" in ckpt or "dataset" not in ckpt:
        return ckpt
    out = {k: v for k, v in ckpt.items() if k not in ("dataset", "sidecar_offset", "clones_offset")}
    out["sinks"] = {
        "lerobot": ckpt["dataset"],
        "sidecar": {"attempts": ckpt.get("sidecar_offset", 0), "clones": ckpt.get("clones_offset", 0)},
        "rerun": {"episodes": ckpt.get("counters", {}).get("executed", 0)},
    }
    return out
