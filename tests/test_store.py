"""The run store's protocol without the simulator: every sink is committed together, rebuilt from its own
committed state on resume, and a damaged last checkpoint falls back to the one before it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from babblegen import state_file
from babblegen.config import ConfigError
from babblegen.dataset.paths import CHECKPOINT, PREVIOUS_CHECKPOINT
from babblegen.store import AttemptRecord, RunStore, Sink


class ListSink(Sink):
    """Keeps rows in a text file, one per line; its state is the number of rows committed."""

    def __init__(self, state: dict | None, path: Path, name: str):
        self.name, self.path = name, path
        if state is None:
            path.write_text("")
        else:  # roll back to the committed rows
            path.write_text("".join(path.read_text().splitlines(keepends=True)[: state["rows"]]))
        self.rows = len(path.read_text().splitlines())

    def write(self, record: AttemptRecord) -> None:
        with open(self.path, "a") as f:
            f.write(f"{record.row['attempt']}\n")
        self.rows += 1

    def commit(self, counters: dict[str, int], final: bool = False) -> dict:
        return {"rows": self.rows}


def makers(root: Path) -> list:
    return [(n, lambda state, n=n: ListSink(state, root / f"{n}.txt", n)) for n in ("a", "b")]


def open_store(root: Path, states: dict | None = None) -> RunStore:
    store = RunStore(root)
    store.write_info({"config": {}})
    store.open_sinks(makers(root), states)
    return store


def write(store: RunStore, attempts: range) -> None:
    for i in attempts:
        store.write(AttemptRecord({"attempt": i}, None))


def test_resume_rolls_every_sink_back_to_the_last_commit_point(tmp_path):
    store = open_store(tmp_path)
    write(store, range(3))
    store.commit({"step": 0}, {"attempts": 3})
    write(store, range(3, 5))  # written, never committed: the process dies here
    store.close()

    ckpt = RunStore(tmp_path).read_checkpoint(warn=pytest.fail)
    assert ckpt["counters"] == {"attempts": 3} and ckpt["explorer"] == {"step": 0}
    assert ckpt["sinks"] == {"a": {"rows": 3}, "b": {"rows": 3}}
    resumed = open_store(tmp_path, ckpt["sinks"])
    assert [(tmp_path / f"{n}.txt").read_text().split() for n in "ab"] == [["0", "1", "2"]] * 2
    write(resumed, range(3, 4))
    assert (tmp_path / "a.txt").read_text().split() == ["0", "1", "2", "3"]
    assert set(resumed.seconds) == {"a", "b"}, "time spent in each sink is measured"


def test_a_damaged_checkpoint_falls_back_to_the_one_before(tmp_path):
    store = open_store(tmp_path)
    write(store, range(2))
    store.commit({}, {"attempts": 2})
    write(store, range(2, 4))
    store.commit({}, {"attempts": 4})
    path = tmp_path / "babblegen" / CHECKPOINT
    path.write_bytes(path.read_bytes()[:20])  # torn
    warnings: list[str] = []
    ckpt = RunStore(tmp_path).read_checkpoint(warn=warnings.append)
    assert ckpt["counters"] == {"attempts": 2} and len(warnings) == 1 and CHECKPOINT in warnings[0]
    (tmp_path / "babblegen" / PREVIOUS_CHECKPOINT).write_bytes(b"{")
    with pytest.raises(ConfigError, match="damaged and there is no earlier commit point"):
        RunStore(tmp_path).read_checkpoint(warn=warnings.append)


def test_a_format_1_checkpoint_still_resumes(tmp_path):
    (tmp_path / "babblegen").mkdir()
    old = {
        "format_version": 1,
        "explorer": {"x": np.arange(3)},
        "counters": {"executed": 7},
        "sidecar_offset": 120,
        "clones_offset": 40,
        "dataset": {"files": {}, "meta": {}},
    }
    (tmp_path / "babblegen" / CHECKPOINT).write_bytes(state_file.dumps(old))
    ckpt = RunStore(tmp_path).read_checkpoint(warn=pytest.fail)
    assert ckpt["sinks"] == {
        "lerobot": {"files": {}, "meta": {}},
        "sidecar": {"attempts": 120, "clones": 40},
        "rerun": {"episodes": 7},
    }
    np.testing.assert_array_equal(ckpt["explorer"]["x"], np.arange(3))


class SlowSink(ListSink):
    """A sink whose commits take a while (a segment's files) and that can be told to fail on an attempt."""

    def __init__(self, *args, commit_seconds: float = 0.0, fail_on: int | None = None):
        super().__init__(*args)
        self.commit_seconds, self.fail_on, self.threads = commit_seconds, fail_on, set()

    def write(self, record: AttemptRecord) -> None:
        import threading

        self.threads.add(threading.current_thread().name)
        if record.row["attempt"] == self.fail_on:
            raise OSError(28, "No space left on device")
        super().write(record)

    def commit(self, counters: dict[str, int], final: bool = False) -> dict:
        import time

        time.sleep(self.commit_seconds)
        return super().commit(counters, final)


def test_the_writer_thread_writes_in_order_while_the_caller_goes_on(tmp_path):
    import time

    store = RunStore(tmp_path)
    store.write_info({"config": {}})
    sink = SlowSink(None, tmp_path / "a.txt", "a", commit_seconds=0.5)
    store.open_sinks([("a", lambda state: sink)])
    store.start_writer()
    t = time.perf_counter()
    for segment in range(3):
        write(store, range(10 * segment, 10 * segment + 10))
        store.commit({"segment": segment}, {"attempts": 10 * segment + 10})
    handed_over = time.perf_counter() - t
    assert handed_over < 0.9, "two commit points may wait behind the one being written: the caller went on"
    store.commit({"segment": 3}, {"attempts": 30}, final=True)  # waited for
    assert time.perf_counter() - t >= 4 * 0.5
    store.close()
    assert sink.threads == {"dataset-writer"}
    assert (tmp_path / "a.txt").read_text().split() == [str(i) for i in range(30)]
    ckpt = RunStore(tmp_path).read_checkpoint(warn=pytest.fail)
    assert ckpt["explorer"] == {"segment": 3} and ckpt["sinks"]["a"] == {"rows": 30}


def test_an_error_in_the_writer_thread_reaches_the_caller_and_the_last_commit_point_stays(tmp_path):
    store = RunStore(tmp_path)
    store.write_info({"config": {}})
    store.open_sinks([("a", lambda state: SlowSink(state, tmp_path / "a.txt", "a", fail_on=13))])
    store.start_writer()
    write(store, range(10))
    store.commit({"segment": 0}, {"attempts": 10})
    with pytest.raises(OSError, match="No space left"):
        for i in range(10, 1000):
            store.write(AttemptRecord({"attempt": i}, None))
            store.wait_written() if i == 999 else None
    store.close()
    ckpt = RunStore(tmp_path).read_checkpoint(warn=pytest.fail)
    assert ckpt["explorer"] == {"segment": 0} and ckpt["sinks"]["a"] == {"rows": 10}
