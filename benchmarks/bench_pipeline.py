"""Whole-pipeline throughput, measured in one run: 1 worker, 2 worker processes, a local Ray cluster.

Every configuration runs the same seed and number of attempts through `babblegen generate` (real rollouts,
LeRobot writing, sidecar, Rerun), so they execute the same trajectories. Reported: attempts and executed
trajectories per second, the split of a rollout's time, the distance to the bare simulation + rendering
cost of those trajectories, the 2-worker speed-up, and the projected wall time of the paper's full run
(12 x 2,000 = 24,000 attempts).

    python benchmarks/bench_pipeline.py --attempts 96
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def run(out: Path, attempts: int, seed: int, workers: int, ray: str | None, rerun: bool) -> tuple[float, list[dict]]:
    from babblegen.config import RunConfig
    from babblegen.exporters.sidecar import read_attempts
    from babblegen.run import Run

    cfg = RunConfig(seed=seed, max_attempts=attempts, workers=workers, ray=ray, rerun=rerun)
    t = time.perf_counter()
    Run.start(out, cfg).execute(progress=False, echo=lambda *_: None)
    return time.perf_counter() - t, read_attempts(out)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=96)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-ray", action="store_true")
    p.add_argument("--no-rerun", action="store_true")
    args = p.parse_args()
    tmp = Path(tempfile.mkdtemp())
    configs = [("1 worker", 1, None), ("2 workers", 2, None)]
    if not args.no_ray:
        configs.append(("Ray, 2 actors", 2, "auto"))
    results = {}
    for name, workers, ray in configs:
        wall, rows = run(tmp / name.replace(" ", "_"), args.attempts, args.seed, workers, ray, not args.no_rerun)
        results[name] = (wall, rows)

    base_wall, base_rows = results["1 worker"]
    executed = [r for r in base_rows if r["feasible"]]
    stages = ("ik", "plan", "sim", "render", "descriptor", "write")
    split = {s: sum(r["timings"].get(s, 0.0) for r in base_rows) for s in stages}
    bare = split["sim"] + split["render"]
    print(f"{len(base_rows)} attempts, {len(executed)} executed, seed {args.seed}")
    print("time split with 1 worker (s per executed trajectory):")
    for s in stages:
        print(f"  {s:>10}: {split[s] / max(len(executed), 1):.3f}")
    print(f"{'config':>14} {'wall s':>8} {'att/s':>7} {'exec/s':>7} {'vs bare':>8} {'speed-up':>9}")
    for name, (wall, rows) in results.items():
        n_exec = sum(r["feasible"] for r in rows)
        print(
            f"{name:>14} {wall:8.1f} {len(rows) / wall:7.2f} {n_exec / wall:7.2f} {wall / bare:8.2f} "
            f"{base_wall / wall:9.2f}"
        )
    same = all([r["descriptor"] for r in rows] == [r["descriptor"] for r in base_rows] for _, rows in results.values())
    print(f"same descriptors in every configuration: {same}")
    best = min(wall for wall, _ in results.values())
    per_attempt = best / len(base_rows)
    print(f"projected paper run (24,000 attempts) at the best rate: {24000 * per_attempt / 3600:.1f} h")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
