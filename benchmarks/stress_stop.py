"""Stop `babblegen generate` at random moments and check every stop (outside the test suite: it takes hours).

Each trial starts a small run through the console script, in a session of its own as a terminal would, and
sends one signal at a moment drawn uniformly over a run's whole life (start-up and shutdown included), or, for a
share of the trials, drawn uniformly from the span after an event of the run to the next event (its workers
spawned, ``run.json`` written, the first row, the first commit point, the last row, the ``finished:`` line; the
spans an uninterrupted run shows, at least 50 ms): start-up takes most of a small run's life on a loaded machine,
and these cover the rest as densely. The signal is SIGTERM to the run's process (``kill``), SIGINT to its process
group (Ctrl-C in a terminal) or SIGTERM to its process group (``timeout``, batch schedulers). A moment that comes
after the run has ended (exited, or exiting: its exit status is decided) is not a stop; another is drawn.
Then it checks:

- the exit status is 130, and nothing printed a traceback;
- no process of the run's session is left 10 s after its exit (the longest wait is reported);
- the dataset loads with LeRobot's ``LeRobotDataset`` (offline) with one episode per executed attempt of the sidecar
  and every frame; ``--resume`` completes it (exit 0, every attempt), it loads again, and its attempts equal an
  uninterrupted run's (timings aside);
- or, for a stop before the dataset holds an episode, that nothing is left in the output directory.

The phase each signal hit is what the run had done by then (seen from outside: its children, its files, what it
printed, whether it catches SIGTERM yet). A table of the outcomes by phase ends the output; every trial is also
appended to ``ROOT/trials.jsonl`` (``--table`` prints the table of such a file again).

    nice -n 10 python benchmarks/stress_stop.py --runs 200 --root /tmp/stress-stop
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

FLAGS = ["--max-attempts", "40", "--workers", "2", "--no-rerun", "--children", "6", "--checkpoint-every", "1"]
FLAGS += ["--width", "64", "--height", "64", "--no-progress", "--seed", "3"]
PHASES = [
    "start-up: before workers",
    "start-up: workers starting",
    "opened: no row yet",
    "rows: before first commit",
    "after a commit point",
    "last row written",
    "shutdown: finished printed",
]
EVENTS = ["workers", "opened", "first row", "first commit", "last row", "finished"]
KINDS = {
    "SIGTERM": (signal.SIGTERM, False),
    "SIGINT group": (signal.SIGINT, True),
    "SIGTERM group": (signal.SIGTERM, True),
}


def babblegen() -> str:
    return str(Path(sys.executable).with_name("babblegen"))


def rows(out: Path) -> list[dict]:
    path = out / "babblegen" / "attempts.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def row_count(out: Path) -> int:
    path = out / "babblegen" / "attempts.jsonl"
    try:
        return path.read_bytes().count(b"\n")
    except OSError:
        return 0


def caught(pid: int, signum: int) -> bool | None:
    """Whether the process has a handler for ``signum`` now (its SigCgt mask)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    except OSError:
        return None
    return None


def alive(pid: int) -> bool:
    """Still running: not ended, and not a zombie whose exit status is decided already."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    state, flags = stat[stat.rindex(")") + 2 :].split()[0:7:6]
    return state not in "ZX" and not int(flags) & 0x4  # PF_EXITING: it called exit already


def children(pid: int) -> list[int]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    try:
        return [int(c) for c in path.read_text().split()]
    except OSError:
        return []


LINGER_S = 10.0  # a process of the run's session still alive this long after its exit is left running


def session_members(sid: int) -> list[int]:
    """Live processes of the session ``sid`` (the run and whatever it spawned)."""
    found = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            stat = (p / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        if fields[0] != "Z" and int(fields[3]) == sid:
            found.append(int(p.name))
    return found


class Watch:
    """What a run has done so far, seen from outside."""

    def __init__(self, proc: subprocess.Popen, out: Path, log: Path, max_rows: int):
        self.proc, self.out, self.log, self.max_rows = proc, out, log, max_rows
        self.t0 = time.monotonic()
        self.events: dict[str, float] = {}

    def look(self) -> dict:
        pid = self.proc.pid
        state = {
            "t": round(time.monotonic() - self.t0, 3),
            "term_caught": caught(pid, signal.SIGTERM),
            "children": len(children(pid)),
            "opened": (self.out / "babblegen" / "run.json").exists(),
            "rows": row_count(self.out),
            "committed": (self.out / "babblegen" / "checkpoint.json").exists(),
            "finished": b"finished:" in self.log.read_bytes() if self.log.exists() else False,
        }
        for event, seen in (
            ("workers", state["children"] > 0),
            ("opened", state["opened"]),
            ("first row", state["rows"] > 0),
            ("first commit", state["committed"]),
            ("last row", state["rows"] >= self.max_rows),
            ("finished", state["finished"]),
        ):
            if seen and event not in self.events:
                self.events[event] = state["t"]
        return state


def phase(state: dict) -> str:
    if state["finished"]:
        return PHASES[6]
    if state["rows"] >= state.get("max_rows", 40):
        return PHASES[5]
    if state["committed"]:
        return PHASES[4]
    if state["rows"]:
        return PHASES[3]
    if state["opened"]:
        return PHASES[2]
    return PHASES[1] if state["children"] else PHASES[0]


def start(out: Path, log: Path, *extra: str) -> subprocess.Popen:
    with open(log, "wb") as f:
        return subprocess.Popen(
            [babblegen(), "generate", "--out", str(out), *FLAGS, *extra],
            stdout=f,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def finish(proc: subprocess.Popen, timeout: float) -> int | None:
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return None


def load(out: Path) -> str | None:
    """None if the dataset loads with one episode per executed attempt and every frame; else what is wrong."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    try:
        repo_id = json.loads((out / "babblegen" / "run.json").read_text())["repo_id"]
        ds = LeRobotDataset(repo_id, root=out)
        executed = [r for r in rows(out) if r["feasible"]]
        if ds.meta.total_episodes != len(executed):
            return f"{ds.meta.total_episodes} episodes, {len(executed)} executed attempts"
        if len(ds) != sum(r["n_frames"] for r in executed):
            return f"{len(ds)} frames, {sum(r['n_frames'] for r in executed)} recorded"
        ds[len(ds) - 1]  # the last frame decodes
    except Exception as e:  # noqa: BLE001  (any failure is the finding)
        return f"{type(e).__name__}: {str(e)[:200]}"
    return None


def comparable(found: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "timings"} for r in found]


def calibrate(root: Path, n: int) -> tuple[float, list[dict], dict[str, float]]:
    """Uninterrupted runs: their lifetimes (the median is the span moments are drawn from), their attempts (what a
    resumed run must equal) and when each event happened."""
    lives, reference, events = [], None, collections.defaultdict(list)
    for i in range(n):
        out, log = root / f"reference-{i}", root / f"reference-{i}.log"
        shutil.rmtree(out, ignore_errors=True)
        proc = start(out, log)
        watch = Watch(proc, out, log, 40)
        while proc.poll() is None:
            watch.look()
            time.sleep(0.01)
        lives.append(time.monotonic() - watch.t0)
        if proc.returncode != 0:
            raise SystemExit(f"the uninterrupted run failed ({proc.returncode}):\n{log.read_text()[-3000:]}")
        reference = comparable(rows(out))
        for k, v in watch.events.items():
            events[k].append(v)
        print(f"reference run {i}: {lives[-1]:.1f} s, events {watch.events}", flush=True)
    return sorted(lives)[len(lives) // 2], reference, {k: sorted(v)[len(v) // 2] for k, v in events.items()}


def trial(
    root: Path, i: int, rng: random.Random, life: float, spans: dict[str, float], reference: list[dict], args
) -> dict | None:
    kind = rng.choices(
        list(KINDS), weights=[1 - args.sigint_share - args.group_term_share, args.sigint_share, args.group_term_share]
    )[0]
    signum, group = KINDS[kind]
    aimed = rng.random() < args.aimed_share
    event = rng.choice(EVENTS) if aimed else None
    delay = rng.uniform(0, spans[event]) if aimed else rng.uniform(0, life)
    out, log = root / f"trial-{i:03d}", root / f"trial-{i:03d}.log"
    shutil.rmtree(out, ignore_errors=True)
    proc = start(out, log)
    watch = Watch(proc, out, log, 40)
    due = None if aimed else watch.t0 + delay
    state = None
    while proc.poll() is None:
        now = time.monotonic()
        if due is None:
            watch.look()
            if event in watch.events:
                due = now + delay
            time.sleep(0.002)
            continue
        if now >= due:
            state = watch.look()
            state["max_rows"] = 40
            if not alive(proc.pid):  # it ended just now: a signal would come after its exit status
                state = None
                break
            try:
                os.killpg(proc.pid, signum) if group else os.kill(proc.pid, signum)
            except ProcessLookupError:
                state = None
            break
        time.sleep(min(0.002, due - now))
    if state is None:  # it ended before the moment came: no stop to check
        finish(proc, 600)
        shutil.rmtree(out, ignore_errors=True)
        return None
    code = finish(proc, args.stop_timeout)
    printed = log.read_text(errors="replace")
    ended = time.monotonic()  # what the run started may take a moment to go on a loaded machine (not 10 s)
    while session_members(proc.pid) and time.monotonic() - ended < LINGER_S:
        time.sleep(0.05)
    lingered = round(time.monotonic() - ended, 2)
    record = {
        "trial": i,
        "kind": kind,
        "aimed": event,
        "at": state["t"],
        "drawn": round(delay, 3),
        "events": watch.events,
        "phase": phase(state),
        "state": state,
        "exit": code,
        "traceback": "Traceback" in printed,
        "left": len(session_members(proc.pid)),
        "lingered_s": lingered,
        "load": os.getloadavg()[0],
    }
    contents = list(out.iterdir()) if out.is_dir() else []
    if not contents:
        record["dataset"] = "nothing"
    elif not (out / "babblegen" / "run.json").exists():
        record["dataset"] = "incomplete: " + ", ".join(sorted(p.name for p in contents))
    else:
        record["dataset"] = "dataset"
        record["load_error"] = load(out)
        resumed = subprocess.run(
            [babblegen(), "generate", "--out", str(out), "--resume", "--no-progress"],
            capture_output=True,
            text=True,
            timeout=1800,
        )
        record["resume_exit"] = resumed.returncode
        if resumed.returncode == 0:
            record["resumed_load_error"] = load(out)
            record["same_as_uninterrupted"] = comparable(rows(out)) == reference
        else:
            record["resume_output"] = (resumed.stdout + resumed.stderr)[-2000:]
    if not ok(record):
        record["output"] = printed[-4000:]
    elif not args.keep:
        shutil.rmtree(out, ignore_errors=True)
    return record


def ok(r: dict) -> bool:
    if r["exit"] != 130 or r["traceback"] or r["left"]:
        return False
    if r["dataset"] == "nothing":
        return True
    return (
        r["dataset"] == "dataset"
        and r.get("load_error") is None
        and r.get("resume_exit") == 0
        and r.get("resumed_load_error") is None
        and r.get("same_as_uninterrupted") is True
    )


def table(records: list[dict]) -> str:
    lines = [
        "| phase | signals | exit 130 | other exits | loaded | resumed (0, loads, = uninterrupted) | nothing kept "
        "| traceback | left running | SIGTERM not caught yet |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    by_phase = collections.defaultdict(list)
    for r in records:
        by_phase[r["phase"]].append(r)
    for name in [*PHASES, "all"]:
        rs = records if name == "all" else by_phase.get(name, [])
        if not rs:
            continue
        others = collections.Counter(r["exit"] for r in rs if r["exit"] != 130)
        datasets = [r for r in rs if r["dataset"] == "dataset"]
        loaded = sum(r.get("load_error") is None for r in datasets)
        resumed = sum(
            r.get("resume_exit") == 0 and r.get("resumed_load_error") is None and r.get("same_as_uninterrupted")
            for r in datasets
        )
        lines.append(
            f"| {name} | {len(rs)} | {sum(r['exit'] == 130 for r in rs)} | "
            f"{', '.join(f'{k}: {v}' for k, v in sorted(others.items(), key=str)) or '-'} | "
            f"{loaded}/{len(datasets)} | {resumed}/{len(datasets)} | {sum(r['dataset'] == 'nothing' for r in rs)} | "
            f"{sum(r['traceback'] for r in rs)} | {sum(r['left'] > 0 for r in rs)} | "
            f"{sum(r['state']['term_caught'] is False for r in rs)} |"
        )
    kinds = collections.Counter(r["kind"] for r in records)
    aimed = collections.Counter(r["aimed"] for r in records if r["aimed"])
    lines.append("")
    lines.append(
        f"signals: {dict(kinds)}; aimed after an event: {dict(aimed)}; all passed: "
        f"{sum(ok(r) for r in records)}/{len(records)}; the longest wait for the run's processes to go after its "
        f"exit: {max((r.get('lingered_s', 0.0) for r in records), default=0.0):.2f} s"
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=200, help="signals delivered to a live run")
    parser.add_argument("--root", type=Path, default=Path("/tmp/stress-stop"))
    parser.add_argument("--seed", type=int, default=0, help="of the moments and kinds drawn")
    parser.add_argument("--sigint-share", type=float, default=0.25, help="share of SIGINT to the process group")
    parser.add_argument("--group-term-share", type=float, default=0.1, help="share of SIGTERM to the process group")
    parser.add_argument("--aimed-share", type=float, default=0.4, help="share drawn from the span after an event")
    parser.add_argument("--calibration", type=int, default=2, help="uninterrupted runs first")
    parser.add_argument("--stop-timeout", type=float, default=180.0, help="seconds a stop may take")
    parser.add_argument("--burn", type=int, default=0, help="CPU burner processes to run meanwhile")
    parser.add_argument("--keep", action="store_true", help="keep every dataset (failed ones are always kept)")
    parser.add_argument("--table", type=Path, default=None, help="print the table of a trials.jsonl and exit")
    args = parser.parse_args()
    if args.table is not None:
        print(table([json.loads(line) for line in args.table.read_text().splitlines() if line.strip()]))
        return
    os.environ["HF_HUB_OFFLINE"] = "1"
    args.root.mkdir(parents=True, exist_ok=True)
    burners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True) for _ in range(args.burn)
    ]
    try:
        life, reference, events = calibrate(args.root, args.calibration)
        times = [events.get(e, life) for e in EVENTS] + [life]
        spans = {e: max(0.05, times[k + 1] - times[k]) for k, e in enumerate(EVENTS)}
        print(
            f"a run lives {life:.1f} s; moments are drawn from [0, {life:.1f}] s, or from the span after an event:"
            f" {spans}",
            flush=True,
        )
        rng = random.Random(args.seed)
        records, i = [], 0
        with open(args.root / "trials.jsonl", "a") as journal:
            while len(records) < args.runs:
                r = trial(args.root, i, rng, life, spans, reference, args)
                i += 1
                if r is None:
                    continue
                records.append(r)
                journal.write(json.dumps(r) + "\n")
                journal.flush()
                print(
                    f"{len(records):3d} {r['kind']:13s} {r['aimed'] or 'uniform':12s} at {r['at']:6.2f} s "
                    f"{r['phase']:28s} exit {r['exit']} {r['dataset']:8s} {'ok' if ok(r) else 'FAILED'}",
                    flush=True,
                )
        print(table(records))
    finally:
        for b in burners:
            b.kill()
            b.wait()


if __name__ == "__main__":
    main()
