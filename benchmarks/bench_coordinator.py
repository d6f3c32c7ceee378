"""How many episodes per second one coordinator sustains, and how that caps the workers it can feed.

Real rollouts are recorded once (one World, random genomes; executed and infeasible ones in their natural mix),
then replayed by an evaluator that stands in for W workers: a batch comes back after the time W workers would
take to run it (each rollout costs its recorded seconds), while the coordinator does everything else for
real: descriptor, novelty and selection (`tell`), LeRobot writing, the sidecar, Rerun and commit points. The
run loop is the real `Run`; only the evaluator is replaced.

Reported per population and W: executed episodes per second, what W workers could deliver (W / seconds per
executed rollout), the share of that the run keeps up with, how busy the coordinator was, and where its time
goes. W = 0 hands every batch back at once: what the coordinator sustains alone. The curve is saved as a PNG
(episodes/s against workers fed). Beyond a few workers NovEB's generations, not the coordinator, set the
pace: a generation is told before the next is asked, so a run has at most two generations in flight.

    python benchmarks/bench_coordinator.py --attempts 480 --workers 0 1 2 4 8 16 32 --population 12 96 \
        --plot docs/images/coordinator.png
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from babblegen.evaluation import Evaluator


def record(n: int, seed: int, width: int) -> list:
    """``n`` real rollouts of random one-waypoint genomes, in order (infeasible ones included), each executed
    one with its episode encoded as a worker encodes it."""
    from babblegen.evaluation import LocalEvaluator, Preparers, arm_info
    from babblegen.exporters.lerobot_encoding import EpisodeEncoder, features, with_default_features
    from babblegen.exporters.rerun import JpegFrames
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.settings import WorldSettings

    task, settings = get_task(DEFAULT_TASK), WorldSettings(camera_width=width, camera_height=width)
    feats = with_default_features(features(arm_info(task)["joints"], task.object_names, width, width))
    prepare = Preparers({"lerobot": EpisodeEncoder(settings.fps, feats), "rerun": JpegFrames()})
    ev = LocalEvaluator(task, settings, seed, prepare=prepare)
    rng = np.random.default_rng(seed)
    # the first movements warm the simulator and renderer up (one took 11 s): not representative, not kept
    warm = [Command("ee_waypoints", np.array([[0.5, 0.3, 0.5]])), Command("ee_waypoints", np.array([[0.4, 0.2, 0.3]]))]
    ev.evaluate(warm, [10**6, 10**6 + 1])
    rollouts = ev.evaluate([Command("ee_waypoints", rng.random((1, 3))) for _ in range(n)], list(range(n)))
    ev.close()
    return rollouts


class ReplayEvaluator(Evaluator):
    """Stands in for ``workers`` workers: hands back recorded rollouts after the time those workers would need
    (their episodes prepared, as a worker prepares them before or soon after returning them)."""

    def __init__(self, rollouts: list, workers: int):
        self.rollouts, self.workers = rollouts, workers
        self._batch: tuple[list, float] | None = None

    def submit(self, commands: list, attempts: list[int]) -> None:
        chosen = [self.rollouts[a % len(self.rollouts)] for a in attempts]
        costs = sorted((worker_seconds(r) for r in chosen), reverse=True)
        finish = [0.0] * max(self.workers, 1)  # longest first onto the least loaded worker (0: no wait at all)
        for c in costs:
            finish[int(np.argmin(finish))] += c
        ready_at = time.perf_counter() + (max(finish) if finish and self.workers else 0.0)
        self._batch = ([_fresh(r, cmd) for r, cmd in zip(chosen, commands, strict=True)], ready_at)

    def collect(self) -> list:
        rollouts, ready_at = self._batch
        self._batch = None
        delay = ready_at - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        return rollouts

    def evaluate(self, commands: list, attempts: list[int]) -> list:
        self.submit(commands, attempts)
        return self.collect()


def worker_seconds(rollout) -> float:
    """What the rollout cost its worker: planning, simulation, rendering and preparing its episode."""
    return rollout.timings.get("total", 0.0) + rollout.timings.get("prepare", 0.0)


def _fresh(rollout, command):
    """A copy carrying this attempt's command (the run pops per-attempt timing keys from it)."""
    import dataclasses

    return dataclasses.replace(rollout, command=command, timings=dict(rollout.timings))


def run(rollouts: list, workers: int, attempts: int, width: int, population: int, out: Path) -> dict:
    import babblegen.assembly as assembly
    from babblegen.config import RunConfig
    from babblegen.exporters.sidecar import read_attempts
    from babblegen.run import Run

    cfg = RunConfig(seed=0, max_attempts=attempts, workers=1)
    cfg.noveb.population = population
    cfg.world = type(cfg.world)(camera_width=width, camera_height=width)
    original = assembly.build_evaluator
    assembly.build_evaluator = lambda task, config, prepare=None: ReplayEvaluator(rollouts, workers)
    try:
        run = Run.start(out, cfg)
        t0 = time.perf_counter()
        run.execute(progress=False, echo=lambda *_: None)
        wall = time.perf_counter() - t0
    finally:
        assembly.build_evaluator = original
    rows = read_attempts(out)
    first_gen_end = max(i for i, r in enumerate(rows) if r["generation"] == rows[0]["generation"])
    later = rows[first_gen_end + 1 :]
    seconds = later[-1]["timings"]["written_at"] - rows[first_gen_end]["timings"]["written_at"]
    executed = sum(r["feasible"] for r in later)
    waited = sum(r["timings"]["wait_for_batch"] for r in later if r["attempt"] in _first_of_generation(later))
    return {
        "workers": workers,
        "wall": wall,
        "episodes_per_s": executed / seconds,
        "attempts_per_s": len(later) / seconds,
        "coordinator_busy": 1.0 - waited / seconds,
        "sinks": {k: v / max(1, sum(r["feasible"] for r in rows)) for k, v in run.store.seconds.items()},
        "descriptor": float(np.mean([r["timings"]["descriptor"] for r in rows if r["feasible"]])),
    }


def _first_of_generation(rows: list[dict]) -> set[int]:
    seen, first = set(), set()
    for r in rows:
        if r["generation"] not in seen:
            seen.add(r["generation"])
            first.add(r["attempt"])
    return first


def plot(results: list[dict], per_executed: float, width: int, path: Path) -> None:
    """Episodes/s against workers fed, one line per population, beside what the workers would deliver and what
    the coordinator sustains alone (workers 0)."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FixedLocator, NullLocator, ScalarFormatter

    fig = Figure(figsize=(5.4, 3.4), layout="constrained")
    ax = fig.subplots()
    fed = sorted({r["workers"] for r in results if r["workers"]})
    for pop in sorted({r["population"] for r in results}):
        mine = [r for r in results if r["population"] == pop]
        line = [r for r in mine if r["workers"]]
        (handle,) = ax.plot([r["workers"] for r in line], [r["episodes_per_s"] for r in line], "o-")
        handle.set_label(f"NovEB, population {pop}")
        for r in mine:
            if not r["workers"]:
                ax.axhline(r["episodes_per_s"], color=handle.get_color(), ls=":", lw=1)
                ax.annotate(
                    f"coordinator alone, population {pop}: {r['episodes_per_s']:.0f}/s",
                    (fed[0], r["episodes_per_s"]),
                    textcoords="offset points",
                    xytext=(2, 3),
                    fontsize=7,
                )
    ax.plot(fed, [w / per_executed for w in fed], "--", color="gray", label="what the workers deliver")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(FixedLocator(fed))
    ax.yaxis.set_major_locator(FixedLocator([1, 2, 5, 10, 20, 50, 100, 200]))
    ax.yaxis.set_minor_locator(NullLocator())
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(ScalarFormatter())
    ax.set_xlabel("workers fed")
    ax.set_ylabel("executed episodes / s")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(f"one coordinator ({width}x{width} video)", fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240, help="attempts per configuration")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    p.add_argument("--record", type=int, default=48, help="real rollouts recorded and replayed")
    p.add_argument("--width", type=int, default=128)
    p.add_argument("--population", type=int, nargs="+", default=[12], help="NovEB populations to run")
    p.add_argument("--plot", type=Path, default=None, help="save the curve here (PNG)")
    args = p.parse_args()

    rollouts = record(args.record, 0, args.width)
    executed = [r for r in rollouts if r.feasible]
    per_attempt = float(np.mean([worker_seconds(r) for r in rollouts]))
    per_executed = per_attempt * len(rollouts) / max(1, len(executed))
    print(f"recorded {len(rollouts)} rollouts ({len(executed)} executed): {per_attempt:.3f} s per attempt,")
    print(f"{per_executed:.3f} s of worker time per executed episode")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for pop in args.population:
            for w in args.workers:
                results.append(run(rollouts, w, args.attempts, args.width, pop, Path(tmp) / f"p{pop}w{w}"))
                results[-1]["population"] = pop
    print("workers 0: every batch back at once (the coordinator alone)")
    print(f"{'pop':>4} {'workers':>8} {'eps/s':>7} {'ideal':>7} {'kept':>6} {'busy':>6}  coordinator s per episode")
    for r in results:
        ideal = r["workers"] / per_executed if r["workers"] else math.inf
        kept = f"{min(1.0, r['episodes_per_s'] / ideal):6.0%}" if r["workers"] else f"{'-':>6}"
        sinks = " ".join(f"{k} {v:.3f}" for k, v in r["sinks"].items())
        print(
            f"{r['population']:>4} {r['workers']:>8} {r['episodes_per_s']:7.2f} {ideal:7.2f} "
            f"{kept} {r['coordinator_busy']:6.0%}  "
            f"descriptor {r['descriptor']:.3f} {sinks}"
        )
    if args.plot:
        plot(results, per_executed, args.width, args.plot)
        print(f"curve: {args.plot}")
    (Path(tempfile.gettempdir()) / "bench_coordinator.json").write_text(
        json.dumps({"per_executed": per_executed, "width": args.width, "results": results}, indent=1)
    )
    if not math.isfinite(results[-1]["episodes_per_s"]):
        raise SystemExit("no executed episodes in the steady state")


if __name__ == "__main__":
    main()
