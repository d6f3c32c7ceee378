"""`babblegen generate` end to end through the real CLI: the dataset loads with LeRobot, sidecar and episodes
agree, interruption and resume lose nothing, and bad input is refused without touching anything."""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import SMALL_RUN

from babblegen.cli import main
from babblegen.config import ConfigError, RunConfig, resumed_config
from babblegen.dataset.lerobot import load_dataset, to_uint8_image
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.descriptors import from_hex, make_descriptor
from babblegen.novelty import hamming

SMALL = SMALL_RUN  # one worker: the datasets are compared with in-process runs


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


def assert_contact_rich(rows: list[dict]) -> None:
    """Several episodes with contact, one right after another: equal datasets then show that an outcome does
    not depend on what ran before it in the same world."""
    touched = [any(r["touched"].values()) for r in rows if r["feasible"]]
    assert sum(touched) >= 4, touched
    assert any(a and b for a, b in zip(touched, touched[1:], strict=False)), touched


def console_run(tmp_path_factory, *flags: str) -> Path:
    """24 attempts, a commit point after every generation, made by the real console script; what it printed
    is kept in console.txt beside the dataset."""
    out = tmp_path_factory.mktemp("cli") / "ds"
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), *SMALL, "--seed", "2", *flags]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (out.parent / "console.txt").write_text(proc.stdout + proc.stderr)
    return out


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    """The defaults (varied starts)."""
    return console_run(tmp_path_factory)


@pytest.fixture(scope="module")
def small_paper_run(tmp_path_factory) -> Path:
    """Varied starts of the paper's objects: contacts in most of the first generations' movements (drawn objects
    are touched by about one in ten of them)."""
    return console_run(tmp_path_factory, "--objects", "paper")


@pytest.fixture(scope="module")
def small_fixed_run(tmp_path_factory) -> Path:
    """The paper's scene, hashed by the plain pHash of the after image."""
    return console_run(tmp_path_factory, "--starts", "fixed")


def test_a_run_with_many_commit_points_prints_a_handful_of_lines(small_run):
    lines = (small_run.parent / "console.txt").read_text().splitlines()
    generations = len({r["generation"] for r in read_attempts(small_run)})
    assert generations >= 3, "several commit points (one per generation)"
    assert 2 <= len(lines) <= 4, lines  # the summary, the dataset, how to load it: no per-episode bars
    assert lines[0].startswith("finished: 24 attempts")


@pytest.mark.parametrize("run", ["small_run", "small_fixed_run"])
def test_dataset_loads_and_agrees_with_sidecar(run, request):
    small_run = request.getfixturevalue(run)
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

    phash = make_descriptor(info["config"]["descriptor"])
    codes = np.stack([from_hex(r["descriptor"], phash.n_words) for r in executed])
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
        if getattr(phash, "compares_before", False):
            # Not from the video: the change descriptor gates each pixel's difference between the first and last
            # frame at 24 levels, and H.264 at CRF 27 on 64 px frames moves some pixels across it, so episodes
            # recorded as "nothing changed" read as changed (11 of 24 here). The plain pHash is checked below.
            continue
        # The descriptor was computed on the raw render; the video is lossy (H.264, CRF 27), which moves a
        # pHash by a few bits (64-bit: 0-2 measured; 256-bit: a few more), far below two outcomes' distance.
        code = phash(to_uint8_image(frames[-1]["observation.images.head"].numpy()))
        assert hamming(code[None], codes[row["episode_index"]][None])[0, 0] <= phash.n_bits // 16


def test_run_info_records_how_the_dataset_was_made(small_run):
    info = read_run_info(small_run)
    assert info["config"]["seed"] == 2 and info["config"]["world"]["camera_width"] == 64
    assert info["config"]["noveb"]["population"] == 12 and info["config"]["noveb"]["sigma"] == 0.3
    for package in ("lerobot", "sapien", "mani-skill", "ompl", "torch", "scipy", "pillow", "av"):
        assert info["versions"][package] != "not installed"
    # the machine it ran on, as /proc/cpuinfo tells it: what to compare when two machines disagree
    cpuinfo = Path("/proc/cpuinfo").read_text()
    flags = set(next(line for line in cpuinfo.splitlines() if line.startswith("flags")).split(":", 1)[1].split())
    some = {"sse4_2", "avx2", "fma", "avx512f"}
    assert set(info["machine"]["cpu_flags"]) & some == flags & some
    # how this machine computes: the hash of a short canonical simulation and render (babblegen.fingerprint)
    assert set(info["fingerprint"]) == {"hash", "mixed"} and not info["fingerprint"]["mixed"]
    assert len(info["fingerprint"]["hash"]) == 16 and int(info["fingerprint"]["hash"], 16) >= 0
    assert info["machine"]["cpu"].split(" (family")[0] in cpuinfo


def test_dataset_card_describes_the_dataset(small_run):
    card = (small_run / "README.md").read_text()
    rows = read_attempts(small_run)
    executed = sum(bool(r["feasible"]) for r in rows)
    assert card.startswith("---\n") and "license: mit" in card and "- LeRobot" in card  # hub card metadata
    assert f"**Episodes:** {executed} executed movements out of {len(rows)} attempted" in card
    assert '"robot_type": "pr2_like_arm"' in card and '"fps": 10' in card  # meta/info.json, as LeRobot shows it
    assert "`action[t]` leads to" in card and '"explorer": "noveb"' in card


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


def test_resume_of_a_run_that_stopped_while_starting_says_to_run_it_without_resume(tmp_path, capsys):
    """A run stopped during its start-up leaves the empty folder it checked it could write to."""
    out = tmp_path / "started"
    out.mkdir()
    assert main(["generate", "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert f"nothing was written to {out} yet" in err and "without --resume" in err, err
    assert list(out.iterdir()) == []


def test_a_stop_during_the_console_scripts_imports_ends_the_run_before_it_writes_anything(tmp_path, capsys):
    """The console script records a signal from its first line on (`babblegen.console`); the run then stops as
    soon as it starts, before any part of it is built."""
    from babblegen.interrupts import Interrupts

    out = tmp_path / "never"
    with Interrupts(raising=False):
        os.kill(os.getpid(), signal.SIGTERM)
        assert main(["generate", "--out", str(out), *SMALL]) == 130
    assert "interrupted before the first episode was written; nothing was written" in capsys.readouterr().err
    assert list(out.iterdir()) == []


def test_a_signal_as_the_run_ends_still_gives_130(tmp_path):
    """A signal while `generate` prints its summary: the dataset is complete, the run says so and exits with 130."""
    script = (
        "import os, signal, sys\n"
        "import babblegen.cli as cli\n"
        "def finished():\n"
        "    print('finished: 3 attempts')\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "    print('dataset: out')\n"
        "    return 0\n"
        "cli.main = finished\n"
        f"sys.argv = ['babblegen', 'generate', '--out', {str(tmp_path / 'out')!r}]\n"
        "cli.entry_point()\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    printed = proc.stdout + proc.stderr
    assert proc.returncode == 130, printed
    assert "SIGTERM arrived as babblegen ended: the dataset is complete" in proc.stderr, printed
    assert proc.stdout.splitlines() == ["finished: 3 attempts", "dataset: out"], printed


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--population", "1"], "population"),
        (["--population", "4", "--k", "4"], "must be below the population"),
        (["--k", "0"], "k must be"),
        (["--width", "100000"], "at most 2048x2048"),
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
        (["--explorer", "genetic"], "invalid choice: 'genetic' (choose from 'noveb', 'random', 'random_waypoints')"),
        (["--task", "kitchen"], "invalid choice: 'kitchen' (choose from 'noveb_tabletop'"),
        (["--video-codec", "vp9"], "invalid choice: 'vp9' (choose from 'h264', 'libsvtav1', 'h264_mbtree')"),
        (["--starts", "random"], "invalid choice: 'random' (choose from 'fixed', 'varied')"),
    ],
)
def test_bad_flags_exit_2_with_the_valid_choices(tmp_path, capsys, flags, message):
    with pytest.raises(SystemExit) as exc:
        main(["generate", "--out", str(tmp_path / "ds"), *flags])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_bad_start_modes_in_a_config_file_write_nothing(tmp_path, capsys):
    out = tmp_path / "ds"
    (tmp_path / "run.toml").write_text('[world]\nstarts = "shuffled"\n')
    assert main(["generate", "--out", str(out), "--config", str(tmp_path / "run.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["babblegen: error: [world] unknown starts 'shuffled'; choose one of: fixed, varied"]
    assert not out.exists()


def test_generate_help_states_each_default_once(capsys):
    with pytest.raises(SystemExit):
        main(["generate", "--help"])
    text = capsys.readouterr().out
    assert "(default:" not in text
    assert "[default: noveb]" in text and "[default: 12]" in text
    assert text.count("[default: noveb]") == 1


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


def test_sigkill_then_resume_matches_an_uninterrupted_run(small_paper_run, tmp_path):
    killed = tmp_path / "killed"
    proc = _spawn(killed, "--seed", "2", "--objects", "paper")
    # the first generation is written and committed; the second is being simulated (seconds): a generation's
    # rows are written in a burst of milliseconds, so a kill cannot be aimed inside one
    _wait_for_rows(killed, 12, proc)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert generate(killed, "--seed", "2", "--resume") == 0

    assert comparable(read_attempts(killed)) == comparable(read_attempts(small_paper_run))
    assert_contact_rich(read_attempts(small_paper_run))
    ref = load_dataset(small_paper_run, read_run_info(small_paper_run)["repo_id"])
    got = load_dataset(killed, read_run_info(killed)["repo_id"])
    assert got.meta.total_episodes == ref.meta.total_episodes and len(got) == len(ref)
    for key in ("observation.state", "action", "observation.environment_state", "observation.contacts"):
        np.testing.assert_array_equal(got.hf_dataset[key], ref.hf_dataset[key])
    assert got.hf_dataset["episode_index"] == ref.hf_dataset["episode_index"]
    card = (small_paper_run / "README.md").read_text()
    episodes_line = next(line for line in card.splitlines() if "**Episodes:**" in line)
    assert episodes_line in (killed / "README.md").read_text(), "the card is current after a resume"
    leftovers = [*killed.glob("tmp*"), *(p for p in (killed / "images").rglob("*") if p.is_file())]
    assert leftovers == [], "what the killed writer had in flight is gone"


@pytest.mark.sim
def test_killed_before_its_first_commit_point_a_run_starts_afresh_on_resume(small_run, tmp_path):
    out = tmp_path / "early"
    proc = _spawn(out, "--seed", "2", "--max-attempts", "200", "--checkpoint-every", "100")
    _wait_for_rows(out, 5, proc)
    proc.kill()
    proc.wait(timeout=60)
    assert not (out / "babblegen" / "checkpoint.json").exists()
    assert generate(out, "--resume") == 0  # SMALL: --max-attempts 24, a change the resume records
    assert comparable(read_attempts(out)) == comparable(read_attempts(small_run))
    info = read_run_info(out)
    assert info["config"]["max_attempts"] == 24 and len(info["resumed"]) == 1


@pytest.mark.sim
def test_sigterm_leaves_a_dataset_that_loads(tmp_path):
    """The SIGTERM lands where a stop once ended the run with exit status 1: in the run's own process (one worker),
    inside SAPIEN's URDF parser (every scene rebuild runs it), which re-raises whatever it catches as a ValueError."""
    out = tmp_path / "term"
    flags = [*SMALL, "--seed", "2", "--max-attempts", "200", "--checkpoint-every", "100"]
    script = (
        "import os, signal, sys\n"
        "from pathlib import Path\n"
        "from sapien.wrapper.urchin import urdf\n"
        f"rows = Path({str(out)!r}) / 'babblegen' / 'attempts.jsonl'\n"
        "parse, sent = urdf.URDFType._parse_attrib.__func__, []\n"
        "def parse_and_stop(cls, kind, value):\n"
        "    required = sys._getframe(1).f_locals.get('r')  # parsed inside `except Exception: raise ValueError`\n"
        "    if required and not sent and rows.exists() and rows.read_bytes().count(b'\\n') >= 14:\n"
        "        sent.append(os.kill(os.getpid(), signal.SIGTERM))\n"
        "    return parse(cls, kind, value)\n"
        "urdf.URDFType._parse_attrib = classmethod(parse_and_stop)\n"
        "from babblegen.cli import entry_point\n"
        f"sys.argv = ['babblegen', 'generate', '--out', {str(out)!r}, *{flags!r}]\n"
        "entry_point()\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900)
    printed = proc.stdout + proc.stderr
    assert proc.returncode == 130, printed
    assert "Traceback" not in printed and "resume with: babblegen generate --out" in printed, printed
    rows = read_attempts(out)
    executed = [r for r in rows if r["feasible"]]
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    assert ds.meta.total_episodes == len(executed) > 0
    assert len(ds) == sum(r["n_frames"] for r in executed)


@pytest.mark.sim
def test_ctrl_c_in_a_terminal_stops_a_run_with_workers_quietly(tmp_path):
    """Ctrl-C reaches the whole process group: the workers leave the stopping to the main process."""
    out = tmp_path / "ctrl-c"
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), *SMALL, "--max-attempts", "400"]
    cmd[cmd.index("--workers") + 1] = "2"
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    _wait_for_rows(out, 14, proc)
    os.killpg(proc.pid, signal.SIGINT)
    code = proc.wait(timeout=120)
    printed = proc.stdout.read().decode()
    assert code == 130, printed
    assert "Traceback" not in printed and "died" not in printed and "leaked" not in printed, printed
    assert "resume with: babblegen generate --out" in printed
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    assert ds.meta.total_episodes == sum(r["feasible"] for r in read_attempts(out)) > 0


@pytest.mark.sim
def test_a_second_run_on_a_dataset_in_use_is_refused(tmp_path, capsys):
    out = tmp_path / "busy"
    proc = _spawn(out, "--seed", "3", "--max-attempts", "400")
    try:
        _wait_for_rows(out, 14, proc)
        assert generate(out, "--seed", "3", "--resume") == 2
        assert "in use by another babblegen run" in capsys.readouterr().err
        assert proc.poll() is None, "the first run goes on"
        _wait_for_rows(out, 30, proc)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
    rows = read_attempts(out)
    executed = [r for r in rows if r["feasible"]]
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    assert ds.meta.total_episodes == len(executed) > 0, "the first run's dataset is whole"
    assert generate(out, "--seed", "3", "--resume", "--max-attempts", "40") == 0, "free again once it stopped"


def test_a_damaged_checkpoint_falls_back_to_the_commit_point_before_it(small_run, tmp_path, capsys):
    import shutil

    out = tmp_path / "damaged"
    proc = _spawn(out, "--seed", "2")
    deadline = time.time() + 240
    sdir = out / "babblegen"
    while not ((sdir / "checkpoint.prev.json").exists() and (sdir / "checkpoint.json").exists()):  # two made
        assert proc.poll() is None and time.time() < deadline, "no second commit point"
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (sdir / "checkpoint.prev.json").read_bytes().startswith(b'{"format":"babblegen-state/1"'), "plain JSON"
    spare, missing = tmp_path / "spare", tmp_path / "missing"
    shutil.copytree(out, spare)
    shutil.copytree(out, missing)

    if (sdir / "checkpoint.json").exists():
        state = (sdir / "checkpoint.json").read_bytes()
        (sdir / "checkpoint.json").write_bytes(state[: len(state) // 2])  # torn
    # else the kill fell between a commit point's two renames (the last one moved aside, the new one not yet in
    # place): a missing last commit point, which falls back the same way
    assert generate(out, "--seed", "2", "--resume") == 0
    assert "resuming from the commit point before it" in capsys.readouterr().err
    assert comparable(read_attempts(out)) == comparable(read_attempts(small_run)), "exact all the same"

    (missing / "babblegen" / "checkpoint.json").unlink(missing_ok=True)  # a kill between a commit's two renames
    assert generate(missing, "--seed", "2", "--resume") == 0
    assert "resuming from the commit point before it" in capsys.readouterr().err
    assert comparable(read_attempts(missing)) == comparable(read_attempts(small_run))

    for name in ("checkpoint.json", "checkpoint.prev.json"):
        (spare / "babblegen" / name).write_bytes(b"\x80\x04garbage")
    assert generate(spare, "--seed", "2", "--resume") == 2
    err = capsys.readouterr().err
    assert "damaged" in err and "no earlier commit point" in err and "Traceback" not in err


def test_a_resume_on_a_machine_that_computes_otherwise_is_refused_unless_mixed_machines_are_allowed(
    small_run, tmp_path, capsys, monkeypatch
):
    import shutil

    out = tmp_path / "elsewhere"
    shutil.copytree(small_run, out)
    made = read_run_info(out)["fingerprint"]["hash"]
    monkeypatch.setenv("BABBLEGEN_FINGERPRINT_SALT", "another machine")  # as a machine of another kind computes
    files = {f: f.read_bytes() for f in out.rglob("*") if f.is_file() and f.name != "run.lock"}
    assert generate(out, "--seed", "2", "--resume") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "this machine computes differently from the one that made" in err[0], err
    assert made in err[0] and "--allow-mixed-machines" in err[0]
    after = {f: f.read_bytes() for f in out.rglob("*") if f.is_file() and f.name != "run.lock"}
    assert after == files, "refused before anything was written"
    assert generate(out, "--seed", "2", "--resume", "--allow-mixed-machines") == 0
    record = read_run_info(out)["fingerprint"]
    assert record["hash"] == made and record["mixed"] is True
    (where, theirs), *more = record["nodes"].items()
    assert not more and where.startswith("resumed on ") and theirs != made


def test_resume_extends_a_run(small_run, tmp_path, capsys):
    import shutil

    out = tmp_path / "more-attempts"
    shutil.copytree(small_run, out)
    assert generate(out, "--seed", "2", "--resume", "--max-attempts", "36") == 0
    finished = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("finished:"))
    assert finished.startswith("finished: 36 attempts (12 in this sitting), ")
    seconds, rate = finished.rsplit(", ", 1)[1].removesuffix(" attempts/s)").split(" s (")
    # the rate counts this sitting's 12 attempts (seconds are printed rounded to the unit, the rate to 0.01)
    assert abs(float(rate) * float(seconds) - 12) <= 0.5 * float(rate) + 0.005 * float(seconds) + 1e-9
    assert [r["attempt"] for r in read_attempts(out)] == list(range(36))
    assert read_run_info(out)["config"]["max_attempts"] == 36

    gens = tmp_path / "more-generations"
    flags = ["--generations", "2", *SMALL_RUN[:2], *SMALL_RUN[4:]]  # all but --max-attempts
    assert main(["generate", "--out", str(gens), *flags, "--no-rerun"]) == 0
    assert {r["generation"] for r in read_attempts(gens)} == {0, 1}
    assert main(["generate", "--out", str(gens), "--resume", "--generations", "3", "--no-progress"]) == 0
    assert {r["generation"] for r in read_attempts(gens)} == {0, 1, 2}


@pytest.mark.sim
@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_full_disk_stops_with_one_clear_line_and_resume_completes(tmp_path, workers):
    """With worker processes too: they go without a traceback or the bindings' leak report, and the Rerun
    recording's failure is one warning line, not the SDK's own log."""
    disk = tmp_path / "disk"
    disk.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=768k", "tmpfs", str(disk)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        out = disk / "ds"
        cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--max-attempts", "60"]
        cmd += ["--workers", workers, "--checkpoint-every", "1", "--no-progress"]
        cmd += ["--no-rerun"] if workers == "1" else []
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        assert proc.returncode == 1, proc.stdout + proc.stderr
        printed = proc.stdout + proc.stderr
        assert "Traceback" not in printed and "leaked" not in printed, printed
        assert all(line.startswith("babblegen: ") for line in proc.stderr.splitlines()), proc.stderr
        assert (
            proc.stderr.strip()
            .splitlines()[-1]
            .startswith(f"babblegen: error: no space left on the device holding {out}")
        )
        subprocess.run(["mount", "-o", "remount,size=200m", str(disk)], check=True)
        resumed = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=900)
        assert resumed.returncode == 0, resumed.stdout + resumed.stderr
        rows = read_attempts(out)
        assert len(rows) == 60
        ds = load_dataset(out, read_run_info(out)["repo_id"])
        assert ds.meta.total_episodes == sum(bool(r["feasible"]) for r in rows)
    finally:
        subprocess.run(["umount", "-l", str(disk)], capture_output=True)


def test_help_and_config_do_not_load_the_simulator():
    code = (
        "import sys\n"
        "from babblegen.cli import build_parser\n"
        "from babblegen.config import RunConfig\n"
        "build_parser(); RunConfig().validate()\n"
        "loaded = {m.split('.')[0] for m in sys.modules}\n"
        "heavy = sorted(loaded & {'sapien', 'mani_skill', 'torch', 'ompl', 'lerobot'})\n"
        "assert not heavy, heavy\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ('seed = "3"\n', "seed must be int, got '3'"),
        ("[world]\nfps = 2.5\n", "[world] fps must be int, got 2.5"),
        ("noveb = 3\n", "[noveb] must be a table"),
        ("[noveb]\nnot_an_option = 1\n", "unknown keys in [noveb]: not_an_option"),
        ("seed = \n", "is not valid TOML"),
        ('video_codec = "vp9"\n', "unknown video codec 'vp9'; choose one of: h264, libsvtav1, h264_mbtree"),
    ],
)
def test_a_bad_config_file_is_refused_with_one_line(tmp_path, capsys, toml, message):
    config = tmp_path / "run.toml"
    config.write_text(toml)
    assert main(["generate", "--out", str(tmp_path / "ds"), "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "ds").exists()


def test_workers_default_to_one_per_core():
    assert RunConfig().workers == len(os.sched_getaffinity(0))
    assert RunConfig.from_dict({"workers": 1}).workers == 1


def test_a_resumed_run_keeps_its_video_codec():
    stored = RunConfig().to_dict()
    assert resumed_config(stored).video_codec == "h264"
    with pytest.raises(ConfigError, match="cannot change 'video_codec'"):
        resumed_config(stored, {"video_codec": "libsvtav1"})
    del stored["video_codec"]  # stored before the setting existed, when every run recorded AV1
    assert resumed_config(stored).video_codec == "libsvtav1"


def test_a_run_stored_before_pcm_went_off_resumes_with_pcm_and_x264_s_macroblock_tree():
    """Runs stored before these settings ran PhysX with persistent contact manifolds and x264 with its
    macroblock-tree rate control at CRF 22: they resume as they were made; new runs use neither."""
    from babblegen.exporters.lerobot_codecs import video_encoder

    stored = RunConfig().to_dict()
    assert resumed_config(stored).video_codec == "h264"
    del stored["world"]["pcm"], stored["world"]["box_hulls"]
    old = resumed_config(stored)
    assert old.world.pcm and not old.world.box_hulls and old.video_codec == "h264_mbtree"
    new, before = video_encoder("h264"), video_encoder("h264_mbtree")
    assert new.vcodec == before.vcodec == "h264"
    assert (new.crf, before.crf) == (27, 22)
    assert new.extra_options == {"x264-params": "mbtree=0"} and not before.extra_options
    stored["video_codec"] = "libsvtav1"
    assert resumed_config(stored).video_codec == "libsvtav1"


def test_a_run_stored_before_boxes_were_hulls_resumes_with_physx_boxes():
    """New runs collide the scene's boxes as convex hulls with persistent contact manifolds on; a run stored
    between the two changes (PCM off, PhysX boxes) resumes as it was made, and neither may change on resume."""
    stored = RunConfig().to_dict()
    assert resumed_config(stored).world.pcm and resumed_config(stored).world.box_hulls
    stored["world"]["pcm"] = False
    del stored["world"]["box_hulls"]
    old = resumed_config(stored)
    assert not old.world.pcm and not old.world.box_hulls and old.video_codec == "h264"
    for key in ("pcm", "box_hulls"):
        with pytest.raises(ConfigError, match=f"cannot change '{key}'"):
            resumed_config(stored, {key: True})


def test_recording_frames_may_change_on_resume_and_older_runs_keep_every_frame():
    stored = RunConfig().to_dict()
    assert resumed_config(stored).rerun_frames == "ends"
    assert resumed_config(stored, {"rerun_frames": "all"}).rerun_frames == "all"  # the recordings only
    del stored["rerun_frames"]  # stored before the setting existed: its recordings so far log every frame
    assert resumed_config(stored).rerun_frames == "all"


def test_a_run_stored_by_the_generational_version_resumes_as_the_same_search():
    """Runs made before the number of children was a setting stored ``keep_fraction`` (and knew no lag): they
    resume with the children that meant, not with today's defaults."""
    stored = RunConfig().to_dict()
    for key in ("children", "lag", "remove_prob", "remove_above", "max_waypoints"):
        del stored["noveb"][key]
    for key in ("max_move_seconds", "count_approach", "return_home"):
        del stored["world"][key]
    stored["noveb"]["keep_fraction"] = 0.5
    stored["max_attempts"] = None  # "all generations", the default then
    config = resumed_config(stored)
    assert (config.noveb.population, config.noveb.children, config.noveb.lag) == (12, 12, 0)
    assert (config.noveb.max_waypoints, config.noveb.remove_prob) == (None, 0.0), "genomes grew without bound"
    assert config.noveb.remove_above == 1
    assert (config.world.max_move_seconds, config.world.return_home) == (0.0, "retrace"), "and were executed"
    assert config.world.count_approach
    assert config.max_attempts is None
    assert RunConfig().max_attempts == 8000 and RunConfig(max_attempts=0).max_attempts == 0
    zero = RunConfig(max_attempts=0)
    zero.validate()
    assert zero.max_attempts is None, "0 means no limit"


@pytest.mark.sim
@pytest.mark.parametrize("group", [True, False], ids=["ctrl-c to the group", "sigterm to the run"])
def test_a_stop_while_a_run_starts_exits_130_with_one_line_and_writes_nothing(tmp_path, group):
    """Ctrl-C (SIGINT to the process group) or SIGTERM during the seconds of start-up (imports, workers warming
    up) stops at once, without a traceback; SIGTERM used to kill the run there (no handler yet)."""
    out = tmp_path / "early"
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), *SMALL]
    cmd[cmd.index("--workers") + 1] = "2"
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 60
    while not _spawned_workers(proc.pid) and time.monotonic() < deadline:
        assert proc.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)  # they are importing their libraries (seconds), where a Ctrl-C printed tracebacks
    os.killpg(proc.pid, signal.SIGINT) if group else proc.send_signal(signal.SIGTERM)
    started = time.monotonic()
    code = proc.wait(timeout=60)
    printed = proc.stdout.read().decode()
    assert code == 130, printed
    assert time.monotonic() - started < 10  # workers still warming up are not waited for
    assert "Traceback" not in printed and "leaked" not in printed, printed
    assert "babblegen: interrupted before the first episode was written; nothing was written" in printed, printed
    assert list(out.iterdir()) == []


@pytest.mark.sim
def test_a_stop_after_the_dataset_opened_but_before_its_first_episode_leaves_nothing(tmp_path, capsys, monkeypatch):
    """LeRobot loads no dataset of no episode: what the run made is removed, and the directory is left as found."""
    from babblegen.run import Run

    def stopped(self, bar):
        assert (tmp_path / "ds" / "babblegen" / "run.json").exists() and (tmp_path / "ds" / "meta").exists()
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(Run, "_loop", stopped)
    assert generate(tmp_path / "ds") == 130
    assert "interrupted before the first episode was written; nothing was written" in capsys.readouterr().err
    assert list((tmp_path / "ds").iterdir()) == []


def _spawned_workers(pid: int) -> list[int]:
    """The worker processes ``pid`` has spawned so far (multiprocessing's spawn)."""
    children = Path(f"/proc/{pid}/task/{pid}/children")
    found = []
    for child in children.read_text().split() if children.exists() else []:
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes():
                found.append(int(child))
    return found


@pytest.mark.parametrize(
    ("max_attempts", "counts"),
    [(0, "gen"), (600, "attempt"), (2000 * 128 - 1, "attempt"), (2000 * 128, "gen"), (10**6, "gen")],
)
def test_the_progress_bar_counts_what_ends_the_run(max_attempts, counts):
    """With the default generations (2,000 of at most 128 new movements) at most 256,000 movements are
    attempted: a larger --max-attempts cannot end the run, and a bar counting to it would promise days too many
    (0: no limit, the generations end the run)."""
    from babblegen.config import RunConfig
    from babblegen.progress import Progress

    config = RunConfig(max_attempts=max_attempts)
    config.validate()
    bar = Progress(config, dict.fromkeys(("attempts", "generations"), 0), explorer=None).bar
    try:
        assert bar.unit == counts
        assert bar.total == (max_attempts if counts == "attempt" else 2000)
    finally:
        bar.close()


@pytest.mark.sim
def test_an_error_in_the_coordinator_stops_the_workers_without_their_tracebacks(tmp_path):
    """A bug in the main process shows its own traceback once; the worker processes go quietly (no
    EOFError or ConnectionResetError from their pipes, no leak report) and the dataset still loads."""
    out = tmp_path / "bug"
    script = (
        "import sys\n"
        "from babblegen import run\n"
        "original = run.Run._write_attempt\n"
        "def failing(self, cand, *args):\n"
        "    if cand.index == 20:\n"
        "        raise RuntimeError('a bug in the coordinator')\n"
        "    return original(self, cand, *args)\n"
        "run.Run._write_attempt = failing\n"
        "from babblegen.cli import entry_point\n"
        f"sys.argv = ['babblegen', 'generate', '--out', {str(out)!r}, '--workers', '2', '--max-attempts', '60',\n"
        "            '--checkpoint-every', '1', '--width', '64', '--height', '64', '--no-progress']\n"
        "entry_point()\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    printed = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert printed.count("Traceback") == 1 and "a bug in the coordinator" in printed, printed
    assert "EOFError" not in printed and "ConnectionResetError" not in printed and "leaked" not in printed, printed
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    assert ds.meta.total_episodes == sum(r["feasible"] for r in read_attempts(out)) > 0


def _config_from_flags(*flags: str, toml: str | None = None, tmp_path: Path | None = None) -> RunConfig:
    """The configuration `generate` would run with (defaults < TOML < flags), without running it."""
    from babblegen.cli import build_parser
    from babblegen.config import load_toml, merge
    from babblegen.generate_flags import camera_overrides, overrides

    args = build_parser().parse_args(["generate", "--out", "x", *flags])
    data = {}
    if toml is not None:
        path = tmp_path / "run.toml"
        path.write_text(toml)
        data = load_toml(path)
    data = merge(data, overrides(args))
    camera_overrides(args, data)
    return RunConfig.from_dict(data)


def test_cameras_by_flag_and_by_file(tmp_path):
    default = RunConfig().world.cameras
    assert [(v.name, v.depth, v.segmentation) for v in default] == [("head", False, True)]
    views = _config_from_flags("--cameras", "front,wrist", "--depth").world.cameras
    assert [(v.name, v.mount, v.depth, v.segmentation) for v in views] == [
        ("head", "head", True, True),  # the behaviour camera is always recorded
        ("front", "fixed", True, True),
        ("wrist", "wrist", True, True),
    ]
    flat = _config_from_flags("--cameras", "front", "--no-segmentation").world.cameras
    assert [v.name for v in flat] == ["head", "front"] and not any(v.segmentation or v.depth for v in flat)
    assert [v.depth for v in _config_from_flags("--depth").world.cameras] == [True]
    toml = (
        '[[world.cameras]]\nname = "head"\nmount = "head"\ndepth = true\n\n'
        '[[world.cameras]]\nname = "top"\neye = [0.75, -0.1, 2.2]\ntarget = [0.75, -0.1, 0.7]\nfov = 0.9\n'
        "width = 96\nheight = 64\n"
    )
    from_file = _config_from_flags(toml=toml, tmp_path=tmp_path).world.cameras
    top = from_file[1]
    assert (top.name, top.eye, top.width, top.height, top.depth) == ("top", (0.75, -0.1, 2.2), 96, 64, False)
    assert from_file[0].depth and not from_file[0].segmentation


@pytest.mark.parametrize(
    ("flags", "toml", "message"),
    [
        (["--cameras", "ceiling"], None, "unknown camera 'ceiling'"),
        ([], '[[world.cameras]]\nname = "front"\neye = [1, 0, 1]\ntarget = [0, 0, 0]\n', "must include 'head'"),
        ([], '[[world.cameras]]\nname = "head"\nmount = "head"\n[[world.cameras]]\nname = "top"\n', "needs an eye"),
    ],
)
def test_bad_cameras_exit_2_before_anything_is_written(tmp_path, capsys, flags, toml, message):
    out = tmp_path / "ds"
    extra = []
    if toml is not None:
        (tmp_path / "c.toml").write_text(toml)
        extra = ["--config", str(tmp_path / "c.toml")]
    assert main(["generate", "--out", str(out), *flags, *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_a_run_stored_before_cameras_were_settings_resumes_with_the_head_camera_alone():
    stored = RunConfig().to_dict()
    del stored["world"]["cameras"]
    views = resumed_config(stored).world.cameras
    assert [(v.name, v.depth, v.segmentation) for v in views] == [("head", False, False)]
    with pytest.raises(ConfigError, match="cannot change"):
        resumed_config(RunConfig().to_dict(), {"cameras": []})


# --- objects drawn per start: view, report and verify --------------------------------------------------------------
# the primitives each shape is drawn from (babblegen.scene.ObjectSpec.parts), as the recordings name them
PART_ENTITIES = {
    "box": ["part0_box"],
    "cylinder": ["part0_cylinder"],
    "sphere": ["part0_sphere"],
    "capsule": ["part0_capsule"],
    "hull": ["part0_hull"],
    "dumbbell": ["part0_sphere", "part1_sphere", "part2_capsule"],
}


@pytest.fixture(scope="module")
def six_objects_dataset(tmp_path_factory) -> Path:
    """Six objects drawn per start, a few attempts, with the run's Rerun recordings."""
    out = tmp_path_factory.mktemp("six") / "ds"
    flags = ["--objects", "varied", "--num-objects", "6", "--max-attempts", "8", "--children", "4", "--workers", "1"]
    flags += ["--checkpoint-every", "1", "--width", "32", "--height", "32", "--no-progress", "--rerun"]
    assert main(["generate", "--out", str(out), *flags]) == 0
    return out


def drawn_parts(paths: list[Path], slot: str, index: int) -> dict[str, dict[str, list]]:
    """The part entities of an object slot that draw something at dataset index ``index`` in the recordings at
    ``paths``, with their components' values then."""
    from rerun.chunk import RrdReader

    latest: dict[str, dict[str, tuple[int, list]]] = {}
    prefix = f"/world/objects/{slot}/"
    for path in paths:
        for chunk in RrdReader(path).stream():
            if chunk.is_static or not chunk.entity_path.startswith(prefix):
                continue
            batch = chunk.to_record_batch()
            times = batch.column("index").to_pylist()
            for name in (n for n in batch.schema.names if ":" in n):
                for t, value in zip(times, batch.column(name).to_pylist(), strict=True):
                    mine = latest.setdefault(chunk.entity_path[len(prefix) :], {})
                    if t <= index and (name not in mine or mine[name][0] <= t):
                        mine[name] = (t, value)
    return {
        e: {c: v for c, (_, v) in comps.items()} for e, comps in latest.items() if any(v for _, v in comps.values())
    }


def rgba(color: list[float]) -> int:
    r, g, b, a = (round(255 * c) for c in color)
    return (r << 24) | (g << 16) | (b << 8) | a


def expected_parts(shape: str, size: list[float]) -> dict[str, dict[str, list]]:
    """What the recordings hold of each part of an object of ``shape`` and ``size`` (hulls: see below)."""
    if shape == "box":
        return {"part0_box": {"Boxes3D:half_sizes": [size]}}
    if shape == "sphere":
        return {"part0_sphere": {"Ellipsoids3D:half_sizes": [[size[0]] * 3]}}
    if shape == "cylinder":  # upright, (radius, half height)
        return {"part0_cylinder": {"Cylinders3D:radii": [size[0]], "Cylinders3D:lengths": [2 * size[1]]}}
    if shape == "capsule":  # (radius, half length of the straight part)
        return {"part0_capsule": {"Capsules3D:radii": [size[0]], "Capsules3D:lengths": [2 * size[1]]}}
    if shape == "dumbbell":  # (ball radius, bar radius, half distance between the balls' centres) along x
        ball, bar, half = size
        return {
            "part0_sphere": {"Ellipsoids3D:centers": [[-half, 0, 0]], "Ellipsoids3D:half_sizes": [[ball] * 3]},
            "part1_sphere": {"Ellipsoids3D:centers": [[half, 0, 0]]},
            "part2_capsule": {"Capsules3D:radii": [bar], "Capsules3D:lengths": [2 * max(half - ball, 1e-3)]},
        }
    return {}


def check_drawn_objects(paths: list[Path], row: dict, index: int) -> None:
    """The recordings draw the episode's objects at its first frame (dataset index ``index``): one entity per part,
    each in the object's colour and of its sizes."""
    for obj in row["objects"]:
        parts = drawn_parts(paths, obj["name"], index)
        assert sorted(parts) == sorted(PART_ENTITIES[obj["shape"]]), (obj["name"], obj["shape"])
        for entity, values in parts.items():
            color = values.get("Mesh3D:albedo_factor") or next(v for c, v in values.items() if c.endswith(":colors"))
            assert color == [rgba(obj["color"])], entity
        expect = expected_parts(obj["shape"], obj["size"])
        for entity, components in expect.items():
            for component, want in components.items():
                np.testing.assert_allclose(parts[entity][component], want, atol=1e-6, err_msg=f"{entity} {component}")
        if obj["shape"] == "hull":  # the hull's corners are its points
            corners = np.asarray(parts["part0_hull"]["Mesh3D:vertex_positions"])
            gaps = np.linalg.norm(corners[:, None] - np.asarray(obj["vertices"])[None], axis=2).min(axis=1)
            assert len(corners) >= 12 and gaps.max() < 1e-6


@pytest.mark.sim
def test_view_report_and_verify_take_six_drawn_objects(six_objects_dataset, tmp_path, capsys):
    from babblegen.exporters.rerun import recording_files

    root = six_objects_dataset
    rows = [r for r in read_attempts(root) if r.get("episode_index") is not None]
    assert rows and all(len(r["objects"]) == 6 for r in rows)
    info = load_dataset(root, read_run_info(root)["repo_id"]).meta.episodes
    row = rows[-1]
    first = int(info[row["episode_index"]]["dataset_from_index"])
    # the run's own recording, and one `babblegen view` writes of that episode
    check_drawn_objects(recording_files(root), row, first)
    out = tmp_path / "one.rrd"
    assert main(["view", str(root), "--episode", str(row["episode_index"]), "--save", str(out)]) == 0
    check_drawn_objects([out], row, first)
    done = subprocess.run([Path(sys.executable).parent / "rerun", "rrd", "verify", out], capture_output=True)
    assert done.returncode == 0, done.stderr
    assert main(["report", str(root), "--out", str(tmp_path / "report")]) == 0
    assert (
        "| objects (paper: the task's; varied, heldout: drawn per start into slots) | varied, 6 |"
        in (tmp_path / "report" / "summary.md").read_text()
    )
    capsys.readouterr()
    assert main(["verify", str(root), "--episodes", "1"]) == 0
    assert "1 of 1 sampled episodes reproduce exactly" in capsys.readouterr().out
