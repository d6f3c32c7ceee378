"""What drawn objects cost a rollout: seconds per executed episode with ``--objects varied`` against ``paper``
(both from varied starts), the same movements, interleaved in one process so the machine's noise falls on both.

    .venv/bin/python benchmarks/bench_objects.py [--movements 60] [--objects 4]

Each movement is drawn as `random_waypoints` draws (1 to 4 waypoints in the workspace box) and runs once from a
paper start and once from a varied-objects start drawn for the same attempt; rendering every frame included.
Prints the seconds per executed episode of each and their ratio, and the scene rebuild's share.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from babblegen.objects import ObjectSampler
from babblegen.starts import StartSampler
from babblegen.tasks import get_task
from babblegen.world.rollout import Command
from babblegen.world.settings import WorldSettings
from babblegen.world.world import World


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--movements", type=int, default=60)
    p.add_argument("--objects", type=int, default=4, help="objects per varied start")
    args = p.parse_args()
    task = get_task("noveb_tabletop")
    worlds, samplers = {}, {}
    for name, objects, count in (("paper", "paper", 4), ("varied", "varied", args.objects)):
        world = World(task, WorldSettings(objects=objects, num_objects=count), seed=0)
        world.warm_up()
        worlds[name] = world
        drawn = None if objects == "paper" else ObjectSampler(objects, count, 1)
        samplers[name] = StartSampler(world.task, 1, drawn)
    rng = np.random.default_rng(0)
    seconds = {n: [] for n in worlds}
    resets = {n: [] for n in worlds}
    frames = {n: [] for n in worlds}
    for i in range(args.movements):
        genome = rng.uniform(0, 1, (int(rng.integers(1, 5)), 3))
        for name in ("paper", "varied") if i % 2 == 0 else ("varied", "paper"):
            start = samplers[name].draw(i)
            t = time.perf_counter()
            rollout = worlds[name].rollout(Command("ee_waypoints", genome, start.placement, start.objects))
            if rollout.feasible:
                seconds[name].append(time.perf_counter() - t)
                resets[name].append(rollout.timings.get("reset", 0.0))
                frames[name].append(len(rollout.frames))
    for name in worlds:
        s = np.array(seconds[name])
        ms = s.sum() / sum(frames[name]) * 1000
        print(f"{name:7s} {len(s):3d} executed: {s.mean():.3f} s per episode (median {np.median(s):.3f}), "
              f"{ms:.1f} ms per frame, reset {np.mean(resets[name]):.3f} s")  # fmt: skip
    ratio = np.mean(seconds["varied"]) / np.mean(seconds["paper"])
    print(f"varied / paper seconds per executed episode: {ratio:.2f}x")
    per_frame = (np.sum(seconds["varied"]) / sum(frames["varied"])) / (np.sum(seconds["paper"]) / sum(frames["paper"]))
    print(f"varied / paper seconds per frame: {per_frame:.2f}x")
    for world in worlds.values():
        world.close()


if __name__ == "__main__":
    main()
