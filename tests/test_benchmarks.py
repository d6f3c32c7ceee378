"""The benchmarks the docs quote still run against the current interfaces (numbers are theirs to report)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.sim
def test_coordinator_benchmark_runs_a_real_run_on_replayed_rollouts(tmp_path):
    args = ["--record", "6", "--attempts", "24", "--workers", "0", "2", "--width", "64"]
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_coordinator.py"), *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads((tmp_path / "bench_coordinator.json").read_text())
    by_workers = {r["workers"]: r for r in report["results"]}
    assert set(by_workers) == {0, 2}
    # Two stand-in workers cannot do their work in less than half its seconds; alone the run must be faster.
    two, alone = by_workers[2], by_workers[0]
    assert two["worker_seconds"] > 0 and two["wall"] >= two["worker_seconds"] / 2
    assert two["episodes_per_s"] > 0 and alone["wall"] < two["wall"]
