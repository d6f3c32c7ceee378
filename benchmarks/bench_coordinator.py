"""How many episodes per second one coordinator sustains, and whether it keeps W workers busy.

Real rollouts are recorded once (one World, random genomes; executed and infeasible ones in their natural mix,
each executed one with its episode prepared as a worker prepares it), then replayed by a stand-in pool of W
worker slots behind the real scheduler (`babblegen.parallel.scheduler.PoolEvaluator`): each attempt goes to a
free slot and comes back after its own recorded worker seconds (the movement, then its episode's rendering and
encoding), pickled and unpickled as a worker's pipe would. The coordinator does everything else for real:
descriptor, novelty and selection (`tell`), asking ahead as the search's lag allows, LeRobot writing, the
sidecar, Rerun and commit points. The run loop is the real `Run`; only the evaluator is replaced.

Reported per W: executed episodes per second in the steady state, the capacity of W workers (W / recorded
worker seconds per executed episode), the share of it the run keeps, how busy the coordinator was, and where its
time goes. W = 0 hands every attempt back at once: what the coordinator sustains alone. ``--json`` prints one
JSON object per line; ``--plot`` saves the curve (episodes/s against workers).

    python benchmarks/bench_coordinator.py --workers 0 1 8 32 --json   # 4,000 attempts each (1,200: 7 s at 32)
    python benchmarks/bench_coordinator.py --workers 0 1 2 4 8 16 32 --plot docs/images/coordinator.png
    python benchmarks/bench_coordinator.py --set children=12 --set lag=0 --workers 0 8 32   # the paper's form
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import tempfile
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from babblegen.parallel.scheduler import PoolEvaluator


def record(n: int, seed: int, config: dict, replay: list[dict] | None = None) -> list:
    """``n`` real rollouts of random one-waypoint genomes, in order (infeasible ones included), or with
    ``replay`` (a run's sidecar rows) its executed genomes at ``n`` evenly spaced attempts, so that the episodes
    written are as long as that run's at that point; each made as a worker process makes it: the movement with
    its first and last frames (``total``), then the other frames rendered and the episode prepared
    (``prepare``)."""
    from babblegen.assembly import arm_info
    from babblegen.dataset.schema import features, with_default_features
    from babblegen.descriptors import make_descriptor
    from babblegen.evaluation import Preparers, render_and_prepare_stepwise, seeded_rollout, warm_up
    from babblegen.exporters.lerobot_encoding import EpisodeEncoder
    from babblegen.exporters.rerun import JpegFrames
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.settings import WorldSettings
    from babblegen.world.world import World

    task, settings = get_task(config.get("task", DEFAULT_TASK)), WorldSettings(**config["world"])
    shape = (settings.camera_height, settings.camera_width)
    feats = features(arm_info(task)["joints"], task.object_names, *shape, settings.cameras, task, settings)
    feats = with_default_features(feats)  # the run's schema, as `RunOutputs.features` makes it
    prepare = Preparers({"lerobot": EpisodeEncoder(settings.fps, feats), "rerun": JpegFrames()})
    describe = make_descriptor("phash16")
    world = World(task, settings, seed)
    warm_up(world, prepare)
    rng = np.random.default_rng(seed)

    def made(attempt: int, command: Command):
        r = seeded_rollout(world, command, seed, attempt, defer_render=True, describe=describe)
        for _ in render_and_prepare_stepwise(world, r, prepare):
            pass
        return r

    # the first movements warm the simulator and renderer up (one took 11 s): not representative, not kept
    for warm in ([[0.5, 0.3, 0.5]], [[0.4, 0.2, 0.3]]):
        made(10**6, Command("ee_waypoints", np.array(warm)))
    if replay is None:
        rollouts = [made(i, Command("ee_waypoints", rng.random((1, 3)))) for i in range(n)]
    else:
        executed = [r for r in replay if r["feasible"]]
        picked = [executed[int(i)] for i in np.linspace(0, len(executed) - 1, n).round()]
        rollouts = [made(r["attempt"], Command(r["kind"], np.asarray(r["genome"]))) for r in picked]
        for r, row in zip(rollouts, picked, strict=True):
            r.timings["replayed_attempt"] = row["attempt"]
    world.close()
    return rollouts


class ReplayPool(PoolEvaluator):
    """Stands in for ``workers`` worker processes behind the real scheduler, timed as they work: a movement
    comes back after its ``total`` seconds, and its episode's rendering and encoding (``prepare`` seconds) then
    waits in one queue that any worker with no movement to run works off, set aside whenever a movement comes
    (what worker processes do, sharing work). ``whole`` instead returns each rollout after ``total + prepare``,
    prepared. 0 workers: everything at once, on as many slots as there is work.

    Attempt i replays recorded rollout ``i mod len(rollouts)``, or with ``replay`` (a run's sidecar rows) that
    run's attempt i: its feasibility, behaviour code and seconds, with a recorded rollout's content to write, so
    that the search retraces the run. Rollouts come back pickled, as through a worker's pipe, and are unpickled
    here as the real dispatch thread does (the pickling is a worker's, done once)."""

    kind = "stand-in worker"

    def __init__(self, rollouts: list, workers: int, whole: bool = False, replay: list[dict] | None = None):
        super().__init__(workers or 256, timeout=1e9, retries=0)
        self.delay, self.whole, self.replay = workers > 0, whole, replay
        self.recorded = [pickle.dumps(r, pickle.HIGHEST_PROTOCOL) for r in rollouts]
        self.feasible = [i for i, r in enumerate(rollouts) if r.feasible]
        self.infeasible = [i for i, r in enumerate(rollouts) if not r.feasible] or [0]
        self.times = [(r.timings.get("total", 0.0), r.timings.get("prepare", 0.0)) for r in rollouts]
        replayed = [r.timings.get("replayed_attempt") for r in rollouts]
        self.at_attempt = None if None in replayed else np.asarray(replayed)  # recorded from the replayed run
        self._running: dict[int, tuple] = {}  # slot -> (done at, pickled rollout, command, attempt, prepare s, code)
        self._queue: deque[list] = deque()  # preparations waiting: [attempt, seconds left]
        self._preparing: dict[int, list] = {}  # slot -> the preparation it works on
        self._prepared: set[int] = set()
        self._clock = time.perf_counter()
        self._new_work = threading.Event()
        self._done = threading.Condition()
        self.worker_seconds = 0.0  # of every attempt handed out

    def _job(self, attempt: int) -> tuple[bytes, float, float, np.ndarray | None]:
        if self.replay is None or attempt >= len(self.replay):
            k = attempt % len(self.recorded)
            return self.recorded[k], *self.times[k], None
        row, t = self.replay[attempt], self.replay[attempt]["timings"]
        seconds = (t.get("total", 0.0), t.get("prepare", 0.0))
        if not row["feasible"]:  # as the run found it: not executed, for this reason
            from babblegen.world.rollout import Command, Rollout

            infeasible = Rollout(Command(row["kind"], np.asarray(row["genome"])), False, row["reason"])
            return pickle.dumps(infeasible, pickle.HIGHEST_PROTOCOL), *seconds, None
        if self.at_attempt is not None:  # the recorded episode nearest this attempt in the run
            k = int(np.argmin(np.abs(self.at_attempt - attempt)))
        else:
            k = self.feasible[attempt % len(self.feasible)]
        from babblegen.descriptors import from_hex

        return self.recorded[k], *seconds, from_hex(row["descriptor"], -(-len(row["descriptor"]) * 4 // 64))

    def _advance(self) -> None:
        """Let the workers with no movement work off preparations up to now."""
        now = time.perf_counter()
        for slot in range(self.n):
            if slot in self._running or not self.delay:
                continue
            spare = now - self._clock
            while spare > 0:
                job = self._preparing.get(slot) or (self._queue.popleft() if self._queue else None)
                if job is None:
                    break
                self._preparing[slot] = job
                used = min(spare, job[1])
                job[1] -= used
                spare -= used
                if job[1] <= 0:
                    del self._preparing[slot]
                    with self._done:
                        self._prepared.add(job[0])
                        self._done.notify_all()
        self._clock = now

    def _send(self, slot: int, attempt: int, command, more: bool) -> None:
        self._advance()
        if slot in self._preparing:  # set aside for the movement; whoever is free next goes on with it
            self._queue.appendleft(self._preparing.pop(slot))
        pickled, total, prepare, code = self._job(attempt)
        self.worker_seconds += total + prepare
        seconds = total + prepare if self.whole else total
        done_at = time.perf_counter() + (seconds if self.delay else 0.0)
        self._running[slot] = (done_at, pickled, command, attempt, prepare, code)

    def _wait(self, busy: list[int], timeout: float) -> list:
        self._advance()
        now = time.perf_counter()
        ends = [self._running[s][0] for s in busy]
        ends += [now + job[1] for job in self._preparing.values()]
        soonest = min(ends, default=now + timeout)
        if soonest > now:
            self._new_work.wait(min(timeout, soonest - now))
            self._new_work.clear()
        self._advance()
        now = time.perf_counter()
        out = []
        for s in busy:
            if self._running[s][0] <= now:
                _, pickled, command, attempt, prepare, code = self._running.pop(s)
                rollout = pickle.loads(pickled)
                rollout.command = command
                if code is not None:
                    rollout.code = code
                if rollout.feasible:
                    if self.whole or not self.delay or prepare <= 0:
                        with self._done:
                            self._prepared.add(attempt)
                    else:
                        self._queue.append([attempt, prepare])
                out.append((s, rollout))
        return out

    def attach_prepared(self, rollout, attempt: int, wait: bool) -> bool:
        if not rollout.feasible:
            return True
        with self._done:
            while attempt not in self._prepared:
                if not wait:
                    return False
                self._done.wait(0.05)
            self._prepared.discard(attempt)
        return True

    def _wake(self) -> None:
        self._new_work.set()

    def _replace(self, slot: int) -> None:
        raise AssertionError("stand-in workers do not fail")


def worker_seconds(rollout) -> float:
    """What the rollout cost its worker: planning, simulation, rendering and preparing its episode."""
    return rollout.timings.get("total", 0.0) + rollout.timings.get("prepare", 0.0)


def worker_seconds_of_row(row: dict) -> float:
    """The same, from a sidecar row."""
    return row["timings"].get("total", 0.0) + row["timings"].get("prepare", 0.0)


def run(
    rollouts: list, workers: int, out: Path, config: dict, whole: bool = False, replay: list[dict] | None = None
) -> dict:
    import babblegen.run as run_module
    from babblegen.config import RunConfig
    from babblegen.dataset.sidecar import read_attempts
    from babblegen.run import Run

    cfg = RunConfig.from_dict(config)
    pool = ReplayPool(rollouts, workers, whole, replay)
    original = run_module.build_evaluator  # where the run loop looks it up
    run_module.build_evaluator = lambda task, config, prepare=None, describe=None: pool
    try:
        run = Run.start(out, cfg)
        t0 = time.perf_counter()
        run.execute(progress=False, echo=lambda *_: None)
        wall = time.perf_counter() - t0
    finally:
        run_module.build_evaluator = original
    rows = read_attempts(out)
    # the steady state: after the first commit point, when every attempt before it has been written (between
    # commit points rows are written as their episodes are prepared, which idle workers may leave for later)
    first_commit = rows[0]["generation"] + cfg.checkpoint_every - 1
    if rows[-1]["generation"] <= first_commit:
        first_commit = rows[0]["generation"]
    start = max(i for i, r in enumerate(rows) if r["generation"] <= first_commit)
    later = rows[start + 1 :]
    seconds = later[-1]["timings"]["written_at"] - rows[start]["timings"]["written_at"]
    executed = sum(r["feasible"] for r in later)
    waited = sum(r["timings"]["wait_for_batch"] for r in later if r["attempt"] in _first_of_generation(later))
    return {
        "workers": workers,
        "wall": wall,
        "worker_seconds": pool.worker_seconds,
        "attempts": len(rows),
        "episodes": sum(r["feasible"] for r in rows),
        "episodes_per_s": executed / seconds,
        "attempts_per_s": len(later) / seconds,
        "coordinator_busy": 1.0 - waited / seconds,
        "sinks": {k: v / max(1, sum(r["feasible"] for r in rows)) for k, v in run.store.seconds.items()},
        "descriptor": float(np.mean([r["timings"]["descriptor"] for r in rows if r["feasible"]])),
        "same_attempts_as_replayed": None
        if replay is None
        else all(
            (r["feasible"], r.get("descriptor"), r["genome"]) == (q["feasible"], q.get("descriptor"), q["genome"])
            for r, q in zip(rows, replay, strict=False)
        ),
    }


def _first_of_generation(rows: list[dict]) -> set[int]:
    seen, first = set(), set()
    for r in rows:
        if r["generation"] not in seen:
            seen.add(r["generation"])
            first.add(r["attempt"])
    return first


def plot(results: list[dict], label: str, width: int, path: Path) -> None:
    """Episodes/s against workers fed, beside the workers' capacity and what the coordinator sustains alone."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    fig = Figure(figsize=(5.4, 3.4), layout="constrained")
    ax = fig.subplots()
    fed = sorted((r for r in results if r["workers"]), key=lambda r: r["workers"])
    ax.plot([r["workers"] for r in fed], [r["episodes_per_s"] for r in fed], "o-", label=f"NovEB, {label}")
    ax.plot([r["workers"] for r in fed], [r["capacity_per_s"] for r in fed], "--", color="gray", label="capacity")
    for r in results:
        if not r["workers"]:
            ax.axhline(r["episodes_per_s"], color="C0", ls=":", lw=1)
            ax.annotate(
                f"coordinator alone: {r['episodes_per_s']:.0f}/s",
                (fed[0]["workers"] if fed else 1, r["episodes_per_s"]),
                textcoords="offset points",
                xytext=(2, 3),
                fontsize=7,
            )
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(FixedLocator([r["workers"] for r in fed]))
    ax.yaxis.set_major_locator(FixedLocator([1, 2, 5, 10, 20, 50, 100, 200, 500]))
    ax.yaxis.set_minor_locator(NullLocator())
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(ScalarFormatter())
    ax.set_xlabel("workers fed")
    ax.set_ylabel("executed episodes / s")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(f"one coordinator ({width}x{width} video)", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def recorded_cameras(root: Path, configured: list[dict]) -> list[dict]:
    """The cameras and kinds a dataset holds (its features), of those its configuration names."""
    from babblegen.dataset.schema import image_sources

    held = json.loads((root / "meta" / "info.json").read_text())["features"]
    kinds: dict[str, set[str]] = {}
    for camera, kind in image_sources(held).values():
        kinds.setdefault(camera, set()).add(kind)
    return [
        {**cam, "depth": "depth" in kinds[cam["name"]], "segmentation": "segmentation" in kinds[cam["name"]]}
        for cam in map(dict, configured)
        if cam["name"] in kinds
    ]


def _option(item: str) -> tuple[str, object]:
    key, _, value = item.partition("=")
    return key, json.loads(value) if value[:1].isdigit() or value in ("true", "false") else value


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=None, help="attempts per worker count [4000; a replay: all]")
    p.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2, 4, 8, 16, 32])
    p.add_argument("--record", type=int, default=48, help="real rollouts recorded and replayed")
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a NovEB option (repeatable)")
    p.add_argument(
        "--replay", type=Path, default=None, help="retrace this dataset's run (its config, codes and seconds)"
    )
    p.add_argument(
        "--recorded", type=Path, default=None, help="keep the recorded rollouts here; reuse them if it exists"
    )
    p.add_argument("--whole-rollouts", action="store_true", help="return each rollout after all its worker time")
    p.add_argument("--json", action="store_true", help="one JSON object per worker count on stdout, nothing else")
    p.add_argument("--plot", type=Path, default=None, help="save the curve here (PNG)")
    args = p.parse_args()
    from babblegen.config import RunConfig, resumed_config
    from babblegen.dataset.sidecar import read_attempts, read_run_info

    say = (lambda *a, **k: None) if args.json else print
    replay = None
    if args.replay is not None:
        replay = read_attempts(args.replay)
        config = resumed_config(read_run_info(args.replay)["config"]).to_dict()  # in this version's terms
        config["world"]["cameras"] = recorded_cameras(args.replay, config["world"]["cameras"])
        attempts = args.attempts or len(replay)
        config["world"]["camera_width"] = config["world"]["camera_height"] = width = config["world"]["camera_width"]
        seconds = [worker_seconds_of_row(r) for r in replay[:attempts]]
        executed = sum(r["feasible"] for r in replay[:attempts])
    else:
        attempts, width = args.attempts or 4000, args.width
        config = RunConfig().to_dict()
        config["noveb"].update(dict(_option(item) for item in args.set))
        config["world"].update(camera_width=width, camera_height=width)
    config.update(max_attempts=attempts, workers=1, ray=None, rerun=True)

    if args.recorded is not None and args.recorded.exists():
        rollouts = pickle.loads(args.recorded.read_bytes())
    else:
        rollouts = record(args.record, 0, config, replay)
        if args.recorded is not None:
            args.recorded.write_bytes(pickle.dumps(rollouts, pickle.HIGHEST_PROTOCOL))
    if replay is None:
        seconds = [worker_seconds(r) for r in rollouts]
        executed = sum(r.feasible for r in rollouts)
    per_executed = float(np.sum(seconds)) / max(1, executed)
    say(f"{len(seconds)} attempts ({executed} executed) of {np.mean(seconds):.3f} worker seconds on average,")
    say(f"{per_executed:.3f} s per executed episode" + (f", replayed from {args.replay}" if replay else ""))
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for w in args.workers:
            r = run(rollouts, w, Path(tmp) / f"w{w}", config, args.whole_rollouts, replay)
            r["capacity_per_s"] = w / per_executed if w else r["episodes_per_s"]
            results.append(r)
            if args.json:
                keys = ("workers", "episodes_per_s", "capacity_per_s", "attempts_per_s", "coordinator_busy", "wall")
                print(json.dumps({k: r[k] for k in keys}), flush=True)
    say("workers 0: every attempt back at once (the coordinator alone)")
    say(f"{'workers':>8} {'eps/s':>7} {'capacity':>8} {'kept':>6} {'busy':>6} {'wall s':>7}  coordinator s per episode")
    for r in results:
        kept = f"{min(1.0, r['episodes_per_s'] / r['capacity_per_s']):6.0%}" if r["workers"] else f"{'-':>6}"
        sinks = " ".join(f"{k} {v:.4f}" for k, v in r["sinks"].items())
        say(
            f"{r['workers']:>8} {r['episodes_per_s']:7.2f} {r['capacity_per_s']:8.2f} {kept} "
            f"{r['coordinator_busy']:6.0%} {r['wall']:7.0f}  descriptor {r['descriptor']:.4f} {sinks}"
        )
        if r["same_attempts_as_replayed"] is False:
            say("  warning: the search did not retrace the replayed run")
    noveb = {k: v for k, v in config["noveb"].items() if v != RunConfig().noveb.__dict__[k]}
    label = ", ".join(f"{k} {v}" for k, v in noveb.items()) or "default settings"
    if args.plot:
        plot(results, label, width, args.plot)
        say(f"curve: {args.plot}")
    (Path(tempfile.gettempdir()) / "bench_coordinator.json").write_text(
        json.dumps({"per_executed": per_executed, "width": width, "noveb": noveb, "results": results}, indent=1)
    )
    if not math.isfinite(results[-1]["episodes_per_s"]):
        raise SystemExit("no executed episodes in the steady state")


if __name__ == "__main__":
    main()
