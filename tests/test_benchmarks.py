"""The benchmarks the README quotes still run against the current interfaces (numbers are theirs to report)."""

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
    # Fed by 2 simulated workers the run cannot write faster than they deliver; alone it must be faster.
    ideal = 2 / report["per_executed"]
    assert 0 < by_workers[2]["episodes_per_s"] <= ideal * 1.05
    assert by_workers[0]["episodes_per_s"] > by_workers[2]["episodes_per_s"]
