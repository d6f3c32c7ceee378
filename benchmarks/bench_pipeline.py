"""Whole-pipeline throughput, measured in one run: 1 worker, 1 and 2 worker processes, a local Ray cluster.

Every configuration runs the same seed and number of attempts through `babblegen generate` (real rollouts,
LeRobot writing, sidecar, Rerun), so they execute the same trajectories. Reported: the split of a rollout's
time; per configuration, attempts and executed trajectories per second in the steady state, and "vs bare",
the pipeline's seconds per executed trajectory over the bare simulation + rendering cost of the same
trajectories; the speed-up over 1 worker; the projected wall time of the paper's full run (24,000 attempts).
"1 process" runs the single worker in its own process, so the writer overlaps it.

    python benchmarks/bench_pipeline.py --attempts 96
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def run(
    out: Path, attempts: int, seed: int, workers: int, ray: str | None, rerun: bool, one_process: bool = False
) -> tuple[float, list[dict]]:
    """One `generate` run; `one_process` puts the single worker in its own process (the writer then overlaps)."""
    import babblegen.evaluation as evaluation
    from babblegen.config import RunConfig
    from babblegen.exporters.sidecar import read_attempts
    from babblegen.parallel import ProcessEvaluator
    from babblegen.run import Run

    cfg = RunConfig(seed=seed, max_attempts=attempts, workers=workers, ray=ray, rerun=rerun)
    local = evaluation.LocalEvaluator
    if one_process:
        evaluation.LocalEvaluator = lambda task, settings, run_seed: ProcessEvaluator(task, settings, run_seed, 1)
    try:
        t = time.perf_counter()
        Run.start(out, cfg).execute(progress=False, echo=lambda *_: None)
        wall = time.perf_counter() - t
    finally:
        evaluation.LocalEvaluator = local
    return wall, read_attempts(out)


def steady_rate(rows: list[dict]) -> tuple[float, float]:
    """Attempts and executed trajectories per second after the first generation."""
    first = max(i for i, r in enumerate(rows) if r["generation"] == rows[0]["generation"])
    later = rows[first + 1 :]
    seconds = later[-1]["timings"]["written_at"] - rows[first]["timings"]["written_at"]
    return len(later) / seconds, sum(r["feasible"] for r in later) / seconds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=96)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-ray", action="store_true")
    p.add_argument("--no-rerun", action="store_true")
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp())
    configs = [("1 worker", 1, None, False), ("1 process", 1, None, True), ("2 workers", 2, None, False)]
    if not args.no_ray:
        configs.append(("Ray, 2 actors", 2, "auto", False))
    results = {}
    for name, workers, ray, one_process in configs:
        out = tmp / name.replace(" ", "_").replace(",", "")
        results[name] = run(out, args.attempts, args.seed, workers, ray, not args.no_rerun, one_process)

    base_rows = results["1 worker"][1]
    executed = [r for r in base_rows if r["feasible"]]
    stages = ("ik", "plan", "sim", "render", "descriptor", "write")
    split = {s: sum(r["timings"].get(s, 0.0) for r in executed) / len(executed) for s in stages}
    bare = split["sim"] + split["render"]
    print(f"{len(base_rows)} attempts, {len(executed)} executed, seed {args.seed}")
    print("time split with 1 worker (s per executed trajectory):")
    for s in stages:
        print(f"  {s:>10}: {split[s]:.3f}")
    print(f"  bare sim + render: {bare:.3f} s per executed trajectory")
    print("steady state (after the first generation, which includes starting the workers):")
    print(f"{'config':>14} {'wall s':>7} {'att/s':>6} {'exec/s':>7} {'s/exec':>7} {'vs bare':>8} {'speed-up':>9}")
    rates = {name: steady_rate(rows) for name, (_, rows) in results.items()}
    for name, (wall, _rows) in results.items():
        att_s, exec_s = rates[name]
        print(
            f"{name:>14} {wall:7.1f} {att_s:6.2f} {exec_s:7.2f} {1 / exec_s:7.3f} {1 / exec_s / bare:8.2f} "
            f"{exec_s / rates['1 worker'][1]:9.2f}"
        )
    same = all([r["descriptor"] for r in rows] == [r["descriptor"] for r in base_rows] for _, rows in results.values())
    print(f"same descriptors in every configuration: {same}")
    best = max(rates.values())[0]
    print(f"projected paper run (24,000 attempts) at the best steady rate: {24000 / best / 3600:.1f} h")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
