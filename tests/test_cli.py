"""`babblegen generate` end to end through the real CLI: the dataset loads with LeRobot, sidecar and episodes
agree, interruption and resume lose nothing, and bad input is refused without touching anything."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from babblegen.cli import main
from babblegen.descriptors import from_hex, make_descriptor
from babblegen.exporters.lerobot import load_dataset, to_uint8_image
from babblegen.exporters.sidecar import read_attempts, read_run_info
from babblegen.novelty import hamming

SMALL = ["--max-attempts", "24", "--checkpoint-every", "1", "--width", "64", "--height", "64", "--no-progress"]


def generate(out: Path, *extra: str) -> int:
    return main(["generate", "--out", str(out), *SMALL, *extra])


def tree_digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


def comparable(rows: list[dict]) -> list[dict]:
    """Sidecar rows without wall-clock timings."""
    return [{k: v for k, v in r.items() if k != "timings"} for r in rows]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "ds"
    assert generate(out, "--seed", "1") == 0
    return out


def test_dataset_loads_and_agrees_with_sidecar(small_run):
    rows = read_attempts(small_run)
    info = read_run_info(small_run)
    assert len(rows) == 24 and [r["attempt"] for r in rows] == list(range(24))
    executed = [r for r in rows if r["feasible"]]
    assert all(r["episode_index"] is None and r["reason"] for r in rows if not r["feasible"])
    assert [r["episode_index"] for r in executed] == list(range(len(executed))), "episodes in attempt order"

    ds = load_dataset(small_run, info["repo_id"])
    assert ds.meta.total_episodes == len(executed) > 0
    assert ds.meta.features["observation.state"]["names"] == info["joint_names"]
    names = info["object_names"]
    assert ds.meta.features["observation.contacts"]["names"] == names
    item = ds[0]
    assert tuple(item["observation.images.head"].shape) == (3, 64, 64)
    assert tuple(item["observation.environment_state"].shape) == (7 * len(names),)

    phash = make_descriptor("phash")
    codes = np.stack([from_hex(r["descriptor"], 1) for r in executed])
    for row in executed:
        ep = ds.meta.episodes[row["episode_index"]]
        start, stop = int(ep["dataset_from_index"]), int(ep["dataset_to_index"])
        assert stop - start == row["n_frames"]
        frames = [ds[i] for i in range(start, stop)]
        contacts = np.stack([f["observation.contacts"].numpy() for f in frames])
        assert contacts.max(axis=0).astype(bool).tolist() == [row["touched"][n] for n in names]
        assert contacts.sum(axis=0).astype(int).tolist() == [row["contact_frames"][n] for n in names]
        final = frames[-1]["observation.environment_state"].numpy().reshape(len(names), 7)
        np.testing.assert_allclose(final, [row["final_poses"][n] for n in names], atol=1e-5)
        # The descriptor was computed on the raw render; the video is lossy (AV1, CRF 30), which moves a
        # 64-bit pHash by a bit or two at most (measured 0-2).
        code = phash(to_uint8_image(frames[-1]["observation.images.head"].numpy()))
        assert hamming(code[None], codes[row["episode_index"]][None])[0, 0] <= 4


def test_run_info_records_how_the_dataset_was_made(small_run):
    info = read_run_info(small_run)
    assert info["config"]["seed"] == 1 and info["config"]["world"]["camera_width"] == 64
    assert info["config"]["noveb"]["population"] == 12 and info["config"]["noveb"]["sigma"] == 0.3
    for package in ("lerobot", "sapien", "mani-skill", "ompl", "torch"):
        assert info["versions"][package] != "not installed"


def test_existing_output_is_refused_and_left_alone(small_run, capsys):
    before = tree_digest(small_run)
    assert generate(small_run) == 2
    assert "already exists and is not empty" in capsys.readouterr().err
    assert tree_digest(small_run) == before


def test_resume_refuses_a_directory_that_is_not_a_babblegen_dataset(tmp_path, capsys):
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    assert main(["generate", "--out", str(other), "--resume"]) == 2
    assert "not a babblegen dataset" in capsys.readouterr().err
    assert (other / "notes.txt").read_text() == "keep me" and len(list(other.iterdir())) == 1


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--population", "1"], "population"),
        (["--population", "4", "--k", "4"], "must be below the population"),
        (["--k", "0"], "k must be"),
    ],
)
def test_impossible_values_are_refused(tmp_path, capsys, flags, message):
    out = tmp_path / "ds"
    assert main(["generate", "--out", str(out), *flags]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--max-attempts", "-3"], "must not be negative"),
        (["--explorer", "genetic"], "invalid choice: 'genetic' (choose from 'noveb', 'random')"),
        (["--task", "kitchen"], "invalid choice: 'kitchen' (choose from 'noveb_tabletop'"),
    ],
)
def test_bad_flags_exit_2_with_the_valid_choices(tmp_path, capsys, flags, message):
    with pytest.raises(SystemExit) as exc:
        main(["generate", "--out", str(tmp_path / "ds"), *flags])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_unwritable_output_directory_is_refused(capsys):
    assert main(["generate", "--out", "/proc/babblegen-cannot-write-here"]) == 2
    assert "cannot write to" in capsys.readouterr().err


def _spawn(out: Path, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), *SMALL, *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)


def _wait_for_rows(out: Path, n: int, proc: subprocess.Popen, timeout: float = 240) -> None:
    path = out / "babblegen" / "attempts.jsonl"
    deadline = time.time() + timeout
    while time.time() < deadline:
        if path.exists() and path.read_bytes().count(b"\n") >= n:
            return
        assert proc.poll() is None, proc.stdout.read().decode()[-2000:]
        time.sleep(0.05)
    raise AssertionError(f"no {n} attempts within {timeout} s")


def test_sigkill_then_resume_matches_an_uninterrupted_run(small_run, tmp_path):
    killed = tmp_path / "killed"
    proc = _spawn(killed, "--seed", "1")
    _wait_for_rows(killed, 17, proc)  # mid-way through the second generation
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert generate(killed, "--seed", "1", "--resume") == 0

    assert comparable(read_attempts(killed)) == comparable(read_attempts(small_run))
    ref = load_dataset(small_run, read_run_info(small_run)["repo_id"])
    got = load_dataset(killed, read_run_info(killed)["repo_id"])
    assert got.meta.total_episodes == ref.meta.total_episodes and len(got) == len(ref)
    for key in ("observation.state", "action", "observation.environment_state", "observation.contacts"):
        np.testing.assert_array_equal(got.hf_dataset[key], ref.hf_dataset[key])
    assert got.hf_dataset["episode_index"] == ref.hf_dataset["episode_index"]
    leftovers = [*killed.glob("tmp*"), *(p for p in (killed / "images").rglob("*") if p.is_file())]
    assert leftovers == [], "what the killed writer had in flight is gone"


def test_sigterm_leaves_a_dataset_that_loads(tmp_path):
    out = tmp_path / "term"
    proc = _spawn(out, "--seed", "2", "--checkpoint-every", "100")
    _wait_for_rows(out, 14, proc)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=120) == 130
    rows = read_attempts(out)
    executed = [r for r in rows if r["feasible"]]
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    assert ds.meta.total_episodes == len(executed) > 0
    assert len(ds) == sum(r["n_frames"] for r in executed)
