"""The run store's protocol without the simulator: every sink is committed together, rebuilt from its own
committed state on resume, and a damaged last checkpoint falls back to the one before it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from babblegen import state_file
from babblegen.config import ConfigError
from babblegen.store import CHECKPOINT, PREVIOUS_CHECKPOINT, AttemptRecord, RunStore, Sink


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
