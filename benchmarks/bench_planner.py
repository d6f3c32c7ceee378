"""What `babblegen evaluate`'s cem planner costs per model: the search with the model alone (IK of every sampled
genome, the model's batched rollouts, the collision checks of the elites) over N goals of a test set, on one core
(torch and numpy one thread each, as the evaluation's model workers run), in wall and CPU seconds and extrapolated to
200 goals; its parts (IK and trajectories, model rollouts) timed apart. No simulator runs.

    python benchmarks/bench_planner.py --train /work/data/nv1 --test /work/data/test_noveb --goals 200
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train", required=True, help="the dataset the model trains on")
    parser.add_argument("--test", required=True, help="the dataset whose episodes give the goals")
    parser.add_argument("--goals", type=int, default=200)
    parser.add_argument("--steps", type=int, default=3000, help="training steps (the speed hardly depends on it)")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--model", choices=("graph", "mlp"), default="graph")
    args = parser.parse_args()
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    import torch

    torch.set_num_threads(1)
    from babblegen.worldmodel import planning_cem
    from babblegen.worldmodel.baseline import TrainSettings
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.experiment import fit_model
    from babblegen.worldmodel.planning import PlanningSettings, choose_goals
    from babblegen.worldmodel.planning_sim import commander
    from babblegen.worldmodel.simulator import GraphSettings

    train = read_dataset(args.train).episodes
    test = read_dataset(args.test).episodes
    t0 = time.perf_counter()
    settings = GraphSettings(steps=args.steps) if args.model == "graph" else TrainSettings(steps=args.steps)
    model = fit_model(train, settings)
    print(f"model: {len(train)} episodes, {model.trained_steps} steps, {time.perf_counter() - t0:.0f} s")
    goals = choose_goals(test, PlanningSettings(goals=args.goals))
    episodes = [e for e, _ in goals]
    arm = commander(str(test.source[episodes[0]]))

    # time the parts: wrap the trajectory and model calls
    spent = {"ik and trajectories": 0.0, "model rollouts": 0.0, "collision checks": 0.0}

    def timed(name, fn):
        def wrapper(*a, **k):
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                spent[name] += time.process_time() - t

        return wrapper

    arm.joint_paths = timed("ik and trajectories", arm.joint_paths)
    arm.direct = timed("collision checks", arm.direct)
    planning_cem.predict_ends = timed("model rollouts", planning_cem.predict_ends)
    cem = planning_cem.CemSettings(samples=args.samples, iterations=args.iterations, elites=max(2, args.samples // 6))
    wall, cpu = time.perf_counter(), time.process_time()
    result = planning_cem.cem_plan(
        model,
        arm,
        test.first[episodes],
        np.stack([test.states[e][0] for e in episodes]),
        np.array([k for _, k in goals]),
        np.stack([test.final[e, k, :2] for e, k in goals]),
        cem,
        seed=0,
    )
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n = len(goals)
    print(f"{n} goals, {cem.samples} genomes x {cem.iterations} iterations: {result.rollouts} model rollouts")
    print(f"search: {wall:.1f} s wall, {cpu:.1f} s CPU", end="; ")
    print(f"per 200 goals {wall * 200 / n:.0f} s wall, {cpu * 200 / n:.0f} s CPU")
    print("  " + ", ".join(f"{k} {v:.1f} s CPU" for k, v in spent.items()))
    chosen = sum(g is not None for g in result.genomes)
    print(f"a plan for {chosen} of {n} goals; predicted miss median {np.median(result.predicted_miss) * 100:.1f} cm")
    print(f"load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
