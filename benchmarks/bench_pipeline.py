"""Whole-pipeline throughput against the machine's simulation limit, measured in one run.

1. ``babblegen generate`` with its defaults (NovEB, LeRobot + sidecar + Rerun, commit points) and ``--workers W``
   for ``--attempts`` attempts: executed trajectories and attempts per second in the steady state (after the
   first generation, which includes starting the workers), and over the whole wall time.
2. The same run's executed genomes replayed in one quiet process (`World.rollout`, renderer warmed up, one
   rendering and one torch thread as in a worker): the bare seconds per trajectory of simulating and rendering.
3. The ratio ``executed/s / (W / bare s)``: the share of what W cores could simulate that the pipeline delivers
   as written episodes (episode encoding, novelty, selection, writing and commits included).

    python benchmarks/bench_pipeline.py --attempts 240 --workers 2
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def generate(out: Path, attempts: int, seed: int, workers: int) -> tuple[float, list[dict]]:
    from babblegen.config import RunConfig
    from babblegen.exporters.sidecar import read_attempts
    from babblegen.run import Run

    cfg = RunConfig(seed=seed, max_attempts=attempts, workers=workers)
    t = time.perf_counter()
    Run.start(out, cfg).execute(progress=False, echo=lambda *_: None)
    return time.perf_counter() - t, read_attempts(out)


def steady_rate(rows: list[dict]) -> tuple[float, float]:
    """Attempts and executed trajectories per second after the first generation."""
    first = max(i for i, r in enumerate(rows) if r["generation"] == rows[0]["generation"])
    later = rows[first + 1 :]
    seconds = later[-1]["timings"]["written_at"] - rows[first]["timings"]["written_at"]
    return len(later) / seconds, sum(r["feasible"] for r in later) / seconds


def replay(rows: list[dict], seed: int, limit: int) -> list[float]:
    """Seconds per executed trajectory, the run's executed genomes replayed in this process, as its workers ran
    them (same per-attempt seeds), with nothing else running."""
    import torch

    torch.set_num_threads(1)
    from babblegen.evaluation import seeded_rollout
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World

    world = World(get_task(DEFAULT_TASK), seed=seed)
    world.warm_up()
    seconds = []
    for r in [r for r in rows if r["feasible"]][:limit]:
        t = time.perf_counter()
        rollout = seeded_rollout(world, Command(r["kind"], np.asarray(r["genome"], float)), seed, r["attempt"])
        seconds.append(time.perf_counter() - t)
        assert rollout.feasible, f"attempt {r['attempt']} did not replay"
    world.close()
    return seconds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--replay", type=int, default=80, help="executed genomes replayed for the bare cost")
    args = p.parse_args()
    os.environ.setdefault("LP_NUM_THREADS", "1")  # before the renderer starts: one thread, as in a worker

    tmp = Path(tempfile.mkdtemp())
    wall, rows = generate(tmp / "run", args.attempts, args.seed, args.workers)
    att_s, exec_s = steady_rate(rows)
    executed = [r for r in rows if r["feasible"]]
    bare = float(np.mean(replay(rows, args.seed, args.replay)))
    limit = args.workers / bare
    later = executed[len(executed) // 10 :]  # past the first rollouts
    split = {k: float(np.mean([r["timings"].get(k, 0.0) for r in later])) for k in ("total", "render", "prepare")}
    frames = float(np.mean([r["n_frames"] for r in later]))

    print(f"{len(rows)} attempts, {len(executed)} executed, seed {args.seed}, {args.workers} workers")
    whole = f"{len(rows) / wall:.2f} attempts/s, {len(executed) / wall:.2f} executed/s"
    print(f"wall {wall:.1f} s (start-up included): {whole}")
    print(f"steady state: {att_s:.2f} attempts/s, {exec_s:.2f} executed trajectories/s")
    print(f"in the run, per executed trajectory: rollout {split['total']:.3f} s (render {split['render']:.3f} s, ")
    print(f"  {split['render'] / frames * 1e3:.1f} ms per frame), episode preparation {split['prepare']:.3f} s")
    print(f"bare, replayed in one process: {bare:.3f} s per trajectory -> {args.workers} cores: {limit:.2f}/s")
    print(f"ratio executed/s / ({args.workers} / bare s): {exec_s / limit:.2f}")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
