"""Whole-pipeline throughput against the machine's simulation limit, measured in one run.

1. ``babblegen generate`` with its defaults (NovEB, LeRobot + sidecar + Rerun, commit points) and ``--workers W``
   for ``--attempts`` attempts: executed trajectories and attempts per second in the steady state (after the
   first generation, which includes starting the workers), and over the whole wall time.
2. The same run's executed genomes replayed (`World.rollout`, renderer warmed up, one rendering and one torch
   thread as in a worker) by W quiet processes, in rounds that alternate one process alone and all W at once:
   the bare seconds per trajectory of simulating and rendering, and what they become when W simulations share
   the machine (caches, memory, the host).
3. The same ``generate`` again (same seed, same attempts), so the replays sit between two runs: this machine's
   speed drifts by 10-20 % over minutes, and the mean of the two runs is compared with the replays.
4. The ratio ``executed/s / (W / bare s)``: the share of what W cores could simulate that the pipeline delivers
   as written episodes (episode encoding, novelty, selection, writing and commits included); and the ceiling
   ``bare s / side-by-side s``, which no pipeline of W processes exceeds on this machine.

    python benchmarks/bench_pipeline.py --attempts 240 --workers 2
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def generate(out: Path, attempts: int, seed: int, workers: int) -> tuple[float, list[dict]]:
    from babblegen.config import RunConfig
    from babblegen.dataset.sidecar import read_attempts
    from babblegen.run import Run

    cfg = RunConfig(seed=seed, max_attempts=attempts, workers=workers)
    t = time.perf_counter()
    Run.start(out, cfg).execute(progress=False, echo=lambda *_: None)
    return time.perf_counter() - t, read_attempts(out)


def steady_rows(rows: list[dict]) -> tuple[list[dict], dict]:
    """The attempts after the first generation (which includes starting the workers), and the last row before
    them."""
    first = max(i for i, r in enumerate(rows) if r["generation"] == rows[0]["generation"])
    return rows[first + 1 :], rows[first]


def steady_rate(rows: list[dict], workers: int) -> tuple[float, float, float, float]:
    """Attempts and executed trajectories per second after the first generation, and the share of the
    workers' time spent on rollouts and on preparing episodes meanwhile."""
    later, before = steady_rows(rows)
    seconds = later[-1]["timings"]["written_at"] - before["timings"]["written_at"]
    busy = [sum(r["timings"].get(k, 0.0) for r in later) / (workers * seconds) for k in ("total", "prepare")]
    return len(later) / seconds, sum(r["feasible"] for r in later) / seconds, *busy


PARTS = ("ik", "plan", "reset", "sim", "render", "total")  # a rollout's timings


def _replayer(me: int, rows: list[dict], seed: int, schedule: list[set[int]], barrier, results) -> None:
    """One replaying process: replays the executed genomes in the rounds of ``schedule`` that name it (as the
    run's workers ran them: same per-attempt seeds) and reports (round, mean seconds per trajectory)."""
    os.environ.setdefault("LP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    from babblegen.evaluation import seeded_rollout
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World

    world = World(get_task(DEFAULT_TASK), seed=seed)
    world.warm_up()
    for round_, active in enumerate(schedule):
        barrier.wait()
        if me in active:
            parts = []
            for r in rows:
                t = time.perf_counter()
                command = Command(r["kind"], np.asarray(r["genome"], float))
                rollout = seeded_rollout(world, command, seed, r["attempt"])
                parts.append({**rollout.timings, "wall": time.perf_counter() - t})
                assert rollout.feasible, f"attempt {r['attempt']} did not replay"
            results.put((round_, {k: float(np.mean([p[k] for p in parts])) for k in PARTS + ("wall",)}))
        barrier.wait()
    world.close()


def replay(rows: list[dict], seed: int, processes: int, rounds: int) -> tuple[dict, dict]:
    """Seconds per trajectory (``wall``, and the rollout's parts) of one quiet process alone, and of each of
    ``processes`` replaying at once, from ``rounds`` alternations of the two."""
    schedule: list[set[int]] = []
    for i in range(rounds):
        schedule += [{i % processes}, set(range(processes))]
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(processes), ctx.Queue()
    children = [
        ctx.Process(target=_replayer, args=(me, rows, seed, schedule, barrier, results)) for me in range(processes)
    ]
    for c in children:
        c.start()
    reports = [results.get() for _ in range(sum(len(s) for s in schedule))]
    for c in children:
        c.join()
    alone = [s for r, s in reports if len(schedule[r]) == 1]
    together = [s for r, s in reports if len(schedule[r]) > 1]
    return tuple({k: float(np.mean([s[k] for s in group])) for k in alone[0]} for group in (alone, together))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--replay", type=int, default=40, help="executed genomes replayed per round (evenly sampled)")
    p.add_argument("--rounds", type=int, default=3, help="alternations of one replaying process and all at once")
    args = p.parse_args()
    os.environ.setdefault("LP_NUM_THREADS", "1")  # before the renderer starts: one thread, as in a worker

    tmp = Path(tempfile.mkdtemp())
    wall, rows = generate(tmp / "first", args.attempts, args.seed, args.workers)
    executed = [r for r in rows if r["feasible"]]
    later = [r for r in steady_rows(rows)[0] if r["feasible"]]  # the trajectories the steady rate counts
    sample = [later[int(i)] for i in np.linspace(0, len(later) - 1, min(args.replay, len(later)))]
    alone, together = replay(sample, args.seed, args.workers, args.rounds)
    bare, side_by_side = alone["wall"], together["wall"]
    wall_again, rows_again = generate(tmp / "again", args.attempts, args.seed, args.workers)
    assert [r["genome"] for r in rows_again] == [r["genome"] for r in rows], "the same seed gave other attempts"

    rates = [steady_rate(r, args.workers) for r in (rows, rows_again)]
    att_s, exec_s, rolling, preparing = np.mean(rates, axis=0)
    in_run = {k: float(np.mean([r["timings"].get(k, 0.0) for r in sample])) for k in (*PARTS, "prepare")}
    limit = args.workers / bare
    ceiling = bare / side_by_side

    print(f"{len(rows)} attempts, {len(executed)} executed, seed {args.seed}, {args.workers} workers")
    for label, w, r in (("first run", wall, rows), ("second run", wall_again, rows_again)):
        a, e = steady_rate(r, args.workers)[:2]
        print(f"{label}: wall {w:.1f} s (start-up included); steady state {a:.2f} attempts/s, {e:.2f} executed/s")
    print(f"steady state, mean of the two: {att_s:.2f} attempts/s, {exec_s:.2f} executed trajectories/s")
    print(f"  workers busy {rolling + preparing:.0%} of the time: rollouts {rolling:.0%}, preparation {preparing:.0%}")
    print(f"bare, replayed by one quiet process: {bare:.3f} s per trajectory -> {args.workers} cores: {limit:.2f}/s")
    print(f"  {args.workers} quiet processes replaying at once: {side_by_side:.3f} s per trajectory each")
    print("seconds per replayed trajectory: " + "  ".join(f"{k:>6}" for k in PARTS) + "  prepare")
    for label, parts in (("in the first run", in_run), ("one process alone", alone), ("side by side", together)):
        row = "  ".join(f"{parts[k]:6.3f}" for k in PARTS)
        print(f"  {label:>29}: {row}" + (f"  {parts['prepare']:6.3f}" if "prepare" in parts else ""))
    print(f"ratio executed/s / ({args.workers} / bare s): {exec_s / limit:.2f}")
    print(
        f"  at most {ceiling:.2f} on this machine for {args.workers} processes; the pipeline reaches "
        f"{exec_s / limit / ceiling:.0%} of that"
    )
    shutil.rmtree(tmp)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
