"""The sidecar beside LeRobot's meta/: one JSON line per attempted movement, infeasible ones included.

Append-only and flushed per row, so it survives a crash up to the last complete line; the run's commit
record stores the byte offset it agrees with, and resume truncates to it. Fields are documented in
README.md ("The sidecar table").
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

SIDECAR_DIR = "babblegen"
ATTEMPTS = "attempts.jsonl"
CLONES = "clones.jsonl"  # children that repeated a genome already tried and reused its outcome
RUN_INFO = "run.json"
CHECKPOINT = "checkpoint.json"  # the last commit point (exporters.state_file format)
PREVIOUS_CHECKPOINT = "checkpoint.prev.json"  # the one before: the fallback if the last is damaged


def sidecar_dir(root: str | Path) -> Path:
    return Path(root) / SIDECAR_DIR


class AttemptLog:
    """Append-only JSON-lines table of attempts."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "ab")  # noqa: SIM115  (kept open for the whole run)

    def append(self, row: dict[str, Any]) -> None:
        self._f.write(json.dumps(row, separators=(",", ":")).encode() + b"\n")
        self._f.flush()

    def offset(self) -> int:
        """Byte length of the complete rows written so far (synced to disk)."""
        self._f.flush()
        os.fsync(self._f.fileno())
        return self._f.tell()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    @staticmethod
    def truncate(path: Path, offset: int) -> None:
        with open(path, "a+b") as f:
            f.truncate(offset)


def read_attempts(root: str | Path, table: str = ATTEMPTS) -> list[dict[str, Any]]:
    """All complete rows of a dataset's sidecar table (a torn last line is ignored); ``table=CLONES`` reads
    the clones (an empty list for datasets made before clones were recorded)."""
    rows = []
    path = sidecar_dir(root) / table
    if table != ATTEMPTS and not path.exists():
        return rows
    with open(path, "rb") as f:
        for line in f:
            if line.endswith(b"\n"):
                rows.append(json.loads(line))
    return rows


def read_run_info(root: str | Path) -> dict[str, Any]:
    with open(sidecar_dir(root) / RUN_INFO) as f:
        return json.load(f)
