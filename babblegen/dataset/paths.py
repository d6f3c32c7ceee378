"""Where a dataset's files are: LeRobot's tree at the root (``meta/``, ``data/``, ``videos/``), babblegen's sidecar
beside it under ``DIR/babblegen/``."""

from __future__ import annotations

from pathlib import Path

SIDECAR_DIR = "babblegen"
RUN_INFO = "run.json"  # the run's configuration, versions, machine, task and robot
ATTEMPTS = "attempts.jsonl"  # one row per attempted movement, infeasible ones included
CLONES = "clones.jsonl"  # children that repeated a genome already tried and reused its outcome
CHECKPOINT = "checkpoint.json"  # the last commit point (babblegen.state_file format)
PREVIOUS_CHECKPOINT = "checkpoint.prev.json"  # the one before: the fallback if the last is damaged
RECORDINGS_DIR = "rerun"  # the run's Rerun recordings, one .rrd per commit segment
LEROBOT_INFO = "meta/info.json"  # LeRobot's description of the dataset: features, episode and frame counts


def sidecar_dir(root: str | Path) -> Path:
    """``DIR/babblegen/``: the run's own files beside the LeRobot dataset."""
    return Path(root) / SIDECAR_DIR


def recordings_dir(root: str | Path) -> Path:
    """``DIR/babblegen/rerun/``."""
    return sidecar_dir(root) / RECORDINGS_DIR


def is_babblegen_dataset(root: str | Path) -> bool:
    """Whether ``root`` holds a run's ``run.json`` (written before its first attempt)."""
    return (sidecar_dir(root) / RUN_INFO).is_file()
