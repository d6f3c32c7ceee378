"""What a varied start costs per executed episode: rebuilding the scene (every rollout does), placing the objects
and letting physics settle them, against the fixed scene's rebuild, measured in one process, alternating.

    python benchmarks/bench_starts.py [--rounds 60] [--json]
Also counts the starts not used (still moving when their settling time ran out, or an object off the table).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=60)
    p.add_argument("--task", default="noveb_tabletop")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()

    from babblegen.starts import StartSampler
    from babblegen.tasks import get_task
    from babblegen.world.world import World, WorldSettings

    task = get_task(args.task)
    world = World(task, WorldSettings(), seed=0)
    world.warm_up()
    sampler = StartSampler(task, seed=0)
    fixed, varied, not_used = [], [], 0
    for i in range(args.rounds):
        t = time.perf_counter()
        world.reset()
        fixed.append(time.perf_counter() - t)
        t = time.perf_counter()
        world.reset(sampler.draw(i).layout)
        not_used += bool(world.settle_start())
        varied.append(time.perf_counter() - t)
    world.close()
    result = {
        "rounds": args.rounds,
        "fixed_reset_ms": 1e3 * float(np.median(fixed)),
        "varied_reset_and_settle_ms": 1e3 * float(np.median(varied)),
        "extra_ms_per_episode": 1e3 * float(np.median(np.asarray(varied) - np.asarray(fixed))),
        "starts_not_used": not_used,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(
        f"{args.rounds} rounds, medians: fixed scene rebuilt {result['fixed_reset_ms']:.1f} ms; varied start rebuilt, "
        f"placed and settled {result['varied_reset_and_settle_ms']:.1f} ms "
        f"(+{result['extra_ms_per_episode']:.1f} ms per episode); {not_used} starts not used"
    )


if __name__ == "__main__":
    main()
