"""What the learned simulator costs: training the whole ensemble on one source, and planning goals with it.

    python benchmarks/bench_learned_simulator.py --train d/nv1 --attempts 4000 --test test/ho_nv,test/ho_rw \\
        [--threads 2] [--goals 40]
    python benchmarks/bench_learned_simulator.py --model models/noveb.pt --test test/ho_nv,test/ho_rw --goals 200

Trains `babblegen evaluate`'s default model (an ensemble of graph networks) on the training dataset cut to its
first --attempts attempts, with --threads torch threads (2: a source's share of a 2-core machine when trained
alone; the evaluation trains one model per worker on one thread each), then plans --goals goals of the test sets
with the cem planner (64 genomes x 4 iterations, one thread) and prints the seconds per 200 goals. Wall and CPU
seconds of each part. With --model, a saved model (`babblegen evaluate --save-models`) plans and nothing trains.
The planner's commanders (the task's kinematics, built once per dataset in an evaluation) are built before the clock.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--train", help="a dataset to train the model on")
    source.add_argument("--model", type=Path, help="a saved model (.pt) to plan with instead")
    parser.add_argument("--attempts", type=int, default=None)
    parser.add_argument("--test", required=True, help="comma-separated datasets whose episodes give the goals")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--goals", type=int, default=40)
    parser.add_argument("--steps", type=int, default=None)
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import numpy as np
    import torch

    from babblegen.worldmodel.episodes import EpisodeSet, read_dataset
    from babblegen.worldmodel.planning import PlanningSettings, choose_goals
    from babblegen.worldmodel.planning_cem import CemSettings, cem_plan
    from babblegen.worldmodel.planning_sim import commander
    from babblegen.worldmodel.simulator import GraphSettings, LearnedSimulator

    test = EpisodeSet.union([read_dataset(Path(d)).episodes for d in args.test.split(",")])
    if args.model is not None:
        model = LearnedSimulator.load(args.model)
    else:
        train = read_dataset(Path(args.train)).budget(attempts=args.attempts)
        torch.set_num_threads(args.threads)
        settings = GraphSettings(**({} if args.steps is None else {"steps": args.steps}))
        wall, cpu = time.perf_counter(), time.process_time()
        model = LearnedSimulator.fit(train, settings)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        print(f"train: {len(train)} episodes, {settings.members} members, {model.trained_steps} steps, "
              f"{args.threads} threads: {wall:.0f} s wall, {cpu:.0f} s CPU")  # fmt: skip
    torch.set_num_threads(1)
    goals = choose_goals(test, PlanningSettings(goals=args.goals))
    episodes = [e for e, _ in goals]
    by_source: dict[str, list[int]] = {}
    for g, e in enumerate(episodes):
        by_source.setdefault(str(test.source[e]), []).append(g)
    for root in by_source:
        commander(root)
    wall, cpu = time.perf_counter(), time.process_time()
    for root, idx in by_source.items():
        ep = [episodes[g] for g in idx]
        k = np.array([goals[g][1] for g in idx])
        cem_plan(
            model, commander(root), test.first[ep], np.stack([test.states[e][0] for e in ep]), k,
            test.final[ep, k, :2], CemSettings(), 0, test.objects[ep],
        )  # fmt: skip
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    n = len(goals)
    print(f"plan: {n} goals, one thread: {wall:.0f} s wall, {cpu:.0f} s CPU; per 200 goals {wall * 200 / n:.0f} s wall")


if __name__ == "__main__":
    main()
