"""Reading the sidecar: ``run.json`` and the attempt tables (``attempts.jsonl``, ``clones.jsonl``), as plain JSON.
Their fields are documented in docs/dataset.md ("The sidecar table"); `babblegen.exporters.sidecar` writes them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from babblegen.dataset.paths import ATTEMPTS, RUN_INFO, sidecar_dir


def read_run_info(root: str | Path) -> dict[str, Any]:
    """The run's ``run.json``: its configuration, versions, machine, task, robot and names."""
    with open(sidecar_dir(root) / RUN_INFO) as f:
        return json.load(f)


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
