"""The planner's ceiling: the cem search with the true simulator as its model, on an evaluation's planning goals.

A learned model's planning success is bounded by what the search finds when every prediction is right; this
measures that bound on goals spread evenly over the stored goals (each candidate is one simulator run, about 0.1 s:
64 samples x 4 iterations cost about 20 s per goal on one core).

    .venv/bin/python benchmarks/planning_ceiling.py EVAL_OUT/planning_held.npz --goals 20 [--samples 64 --iterations 4]

Run it from the directory the evaluation ran in (the goals name their test datasets as the command gave them).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from babblegen.worldmodel.planning import PlanningTask, bootstrap_ci
from babblegen.worldmodel.planning_cem import CemSettings
from babblegen.worldmodel.planning_oracle import simulator_search


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("goals_file", type=Path, help="an evaluation's planning_<test>.npz")
    parser.add_argument("--goals", type=int, default=20, help="goals, spread evenly over the stored ones")
    parser.add_argument("--samples", type=int, default=CemSettings().samples)
    parser.add_argument("--iterations", type=int, default=CemSettings().iterations)
    parser.add_argument("--success-cm", type=float, default=3.0)
    args = parser.parse_args()
    with np.load(args.goals_file) as f:
        key = str(f["key"])
    task = PlanningTask.load(args.goals_file, key)
    if task is None:
        raise SystemExit(f"{args.goals_file}: not an evaluation's planning goals")
    count = len(task.goal_object)
    goals = sorted(set(np.linspace(0, count - 1, min(args.goals, count)).round().astype(int).tolist()))
    cem = CemSettings(samples=args.samples, iterations=args.iterations)
    out = simulator_search(task, goals, cem)
    miss_cm = out["executed_miss"] * 100
    hit = np.nan_to_num(miss_cm, nan=np.inf) <= args.success_cm
    exact = np.array_equal(np.isnan(out["predicted_miss"]), np.isnan(out["executed_miss"])) and np.allclose(
        out["predicted_miss"], out["executed_miss"], rtol=0, atol=0, equal_nan=True
    )
    for g, m in zip(goals, miss_cm, strict=True):
        strata = ", ".join(name for name, flags in task.strata.items() if flags[g]) or "-"
        print(f"goal {g:4d} ({strata}): executed miss {m:6.1f} cm")
    print(
        f"true simulator as the model, cem {cem.samples} x {cem.iterations}: {int(hit.sum())} of {len(goals)} goals "
        f"within {args.success_cm:g} cm, {hit.mean():.2f} {bootstrap_ci(hit.astype(float))}; misses (cm) median "
        f"{np.nanmedian(miss_cm):.1f}; {out['runs']} simulator runs, {out['seconds']:.0f} s; every choice ended where "
        f"it was predicted: {exact}"
    )


if __name__ == "__main__":
    main()
