"""A learned simulator you keep: train it on a dataset (or load one `babblegen evaluate --save-models` wrote), ask
it where a recorded movement sends the objects, then plan with it and run the plan in the real simulator.

    python examples/learned_simulator.py --train dataset/ --test test/ [--save model.pt]
    python examples/learned_simulator.py --model model.pt --test test/ --episode 5

--train trains an ensemble of graph networks (babblegen/worldmodel/simulator.py) on every executed episode of the
datasets named (minutes on a CPU for a few hundred episodes; --steps bounds it). For --episode of the --test
dataset it prints where the model says each object ends beside where it truly ended, then takes the object that
moved most as a goal (its recorded end position, from the same start) and plans a movement to it with the model
alone (the cross-entropy method over waypoint genomes), executes the plan once in the simulator and prints how
near the object came to its goal.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train", nargs="+", default=None, help="datasets to train on")
    parser.add_argument("--model", default=None, help="a saved model instead of --train")
    parser.add_argument("--test", required=True, help="a dataset of the same scene, seeded apart")
    parser.add_argument("--episode", type=int, default=None, help="[default: the first that moved an object 5 cm]")
    parser.add_argument("--steps", type=int, default=3000, help="training steps at most [default: 3000]")
    parser.add_argument("--save", default=None, help="write the trained model here")
    args = parser.parse_args()
    if (args.train is None) == (args.model is None):
        parser.error("give --train DIR... or --model FILE")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.worldmodel import api
    from babblegen.worldmodel.episodes import object_distance_moved, read_dataset
    from babblegen.worldmodel.planning_cem import CemSettings
    from babblegen.worldmodel.simulator import GraphSettings

    if args.model:
        model = api.load_model(args.model)
    else:
        model = api.train(args.train, GraphSettings(steps=args.steps))
        print(f"trained: {model.trained_steps} steps, {model.train_seconds:.0f} s")
        if args.save:
            print(f"saved: {model.save(args.save)}")
    test = read_dataset(args.test).episodes
    moved = object_distance_moved(test)
    episode = args.episode if args.episode is not None else int(np.argmax(moved.max(axis=1) > 0.05))
    scene = api.scene_of(args.test, episode)
    ends, spread = api.predict(model, scene, scene.actions)
    truth = test.final[episode]
    print(f"episode {episode}: object, start -> predicted end (members' spread) / true end, metres")
    for k, name in enumerate(test.scene.objects):
        start, end, real = scene.poses[k, :2], ends[k, :2], truth[k, :2]
        print(f"  {name:10s} {np.round(start, 3)} -> {np.round(end, 3)} ({spread[k]:.1f} cm) / {np.round(real, 3)}")
    goal_object = int(np.argmax(moved[episode]))
    goal = truth[goal_object, :2]
    plan = api.plan(model, scene, goal_object, tuple(goal), CemSettings(samples=64, iterations=4))
    if plan.genome is None:
        print("plan: the model knows no movement that brings the object nearer its goal")
        return
    print(f"plan: {len(plan.genome)} waypoints, predicted to end {plan.predicted_miss * 100:.1f} cm from the goal")
    final = api.execute(scene, plan.genome)
    if final is None:
        print("executed: infeasible")
    else:
        print(f"executed: the object ends {np.linalg.norm(final[goal_object, :2] - goal) * 100:.1f} cm from the goal")


if __name__ == "__main__":
    main()
    sys.stdout.flush()
    os._exit(0)  # without the interpreter's teardown, where OMPL's binding reports spurious leaks
