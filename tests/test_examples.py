"""The scripts in examples/ run as written on small real datasets (the session fixtures of conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
RERUN = Path(sys.executable).parent / "rerun"


def run_example(name: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / name), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc


def test_load_dataset(small_noveb_dataset: Path, tmp_path: Path):
    out = tmp_path / "before_after.png"
    proc = run_example("load_dataset.py", str(small_noveb_dataset), "--out", str(out), "--scale", "1", cwd=tmp_path)
    for text in ("features:", "observation.environment_state", "r_shoulder_pan_joint", "one batch of", "sidecar:"):
        assert text in proc.stdout
    img = Image.open(out)
    assert img.size == (2 * 64 + 4, 64)
    assert len(np.unique(np.asarray(img.convert("L")))) > 10  # a rendered scene, not a blank image


def test_train_world_model(small_noveb_dataset: Path, small_random_dataset: Path, tmp_path: Path):
    args = ["--train", f"noveb={small_noveb_dataset}", "--test", f"random={small_random_dataset}", "--epochs", "3"]
    proc = run_example("train_world_model.py", *args, "--json", str(tmp_path / "scores.json"), cwd=tmp_path)
    table = [line for line in proc.stdout.splitlines() if line.startswith("|")]
    assert len(table) == 4, proc.stdout  # header, rule, baseline, the one training source
    assert any("nothing moves" in line for line in table) and any(line.startswith("| noveb") for line in table)
    assert (tmp_path / "scores.json").stat().st_size > 0
    again = run_example("train_world_model.py", *args, cwd=tmp_path)
    assert [line for line in again.stdout.splitlines() if line.startswith("|")] == table  # seeded: the same numbers


def test_view_episode(small_noveb_dataset: Path, tmp_path: Path):
    for extra, name in (([], "full.rrd"), (["--minimal"], "minimal.rrd")):
        out = tmp_path / name
        run_example(
            "view_episode.py", str(small_noveb_dataset), "--episode", "1", "--save", str(out), *extra, cwd=tmp_path
        )
        assert out.stat().st_size > 10_000
        verify = subprocess.run([str(RERUN), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=300)
        assert verify.returncode == 0, verify.stderr
