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


@pytest.mark.sim
def test_start_sensitivity_replays_each_moved_episode_exactly_without_a_shift(small_heldout_dataset):
    """benchmarks/start_sensitivity.py runs every episode in which an object moved again from its recorded start:
    unshifted, each object ends exactly where it was recorded (error 0.00x, F1 1.000); shifted, a row per shift."""
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "start_sensitivity.py"), str(small_heldout_dataset),
         "--shifts", "0", "5", "--workers", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    assert "moved objects" in lines[0], done.stdout
    assert "shift 0.0 mm, one draw: error 0.00x (median 0.00 cm), F1 1.000, within 1 cm 1.00" in lines[1]
    assert lines[2].startswith("  shift 5.0 mm, one draw: error ")


@pytest.mark.sim
def test_score_models_by_shape_splits_the_moved_objects(small_heldout_dataset, tmp_path):
    """benchmarks/score_models.py on a saved model: one line per model and, with --by-shape, a line per shape that
    moved, whose moved objects add up to the test set's; with --true-frames, a line per count over the same moved
    objects. A count under 1 is refused."""
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.simulator import GraphSettings, LearnedSimulator

    model = LearnedSimulator.fit(read_dataset(small_heldout_dataset).episodes, GraphSettings(steps=30, members=2))
    path = model.save(tmp_path / "tiny.pt")
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "score_models.py"), str(path), str(small_heldout_dataset),
         "--by-shape", "--true-frames", "1", "3"],
        capture_output=True, text=True, timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    first, *rest = done.stdout.splitlines()
    shapes, replays = rest[:-2], rest[-2:]
    for count, line in zip((1, 3), replays, strict=True):
        assert line.startswith(f"  {small_heldout_dataset} with its first {count} frames of motion recorded: F1 ")
        assert line.split(" over ")[1] == first.split(" over ")[1], done.stdout
    assert first.startswith("tiny.pt: ") and first.endswith(" moved"), done.stdout
    assert shapes and all(line.startswith(f"  {small_heldout_dataset} ") for line in shapes), done.stdout
    total = int(first.split(" over ")[1].split()[0])
    assert sum(int(line.split(" over ")[1].split()[0]) for line in shapes) == total


def test_score_models_refuses_a_count_of_no_frames(tmp_path):
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "score_models.py"), str(tmp_path), str(tmp_path), "--true-frames",
         "0"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2 and "--true-frames counts frames: 1 or more" in done.stderr
