"""Seconds per physics substep of a rollout: the world's own stepping against ManiSkill's controller and the
name-based contact scan it replaced (`babblegen.world.reference.ManiSkillDrivenWorld`), on the same commands,
alternating, with the frames checked identical. Rendering is deferred (not measured).

    python benchmarks/bench_substeps.py --n 30
"""

from __future__ import annotations

import argparse

import numpy as np

from babblegen.evaluation import seeded_rollout, warm_up
from babblegen.tasks import DEFAULT_TASK, get_task
from babblegen.world.reference import ManiSkillDrivenWorld
from babblegen.world.rollout import Command
from babblegen.world.world import World


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n", type=int, default=30, help="commands (1 to 3 waypoints, low over the table)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    task = get_task(DEFAULT_TASK)
    worlds = {"world": World(task, seed=args.seed), "ManiSkill controller": ManiSkillDrivenWorld(task, seed=args.seed)}
    for w in worlds.values():
        warm_up(w, None)
    rng = np.random.default_rng(args.seed)
    commands = []
    for _ in range(args.n):
        points = rng.uniform(0, 1, (int(rng.integers(1, 4)), 3))
        points[:, 2] *= 0.3  # near the table top, where contacts happen
        commands.append(Command("ee_waypoints", points))
    seconds = {name: 0.0 for name in worlds}
    settings = worlds["world"].settings
    per_frame = settings.sim_freq // settings.fps
    substeps, touching, executed = 0, 0, 0
    for i, command in enumerate(commands):
        order = list(worlds.items()) if i % 2 == 0 else list(worlds.items())[::-1]
        out = {}
        for name, w in order:
            out[name] = r = seeded_rollout(w, command, args.seed, i, defer_render=True)
            if r.feasible:
                seconds[name] += r.timings["sim"]
        a, b = out.values()
        if not a.feasible:
            continue
        for field in ("state", "object_poses", "contacts", "end_images"):
            if not np.array_equal(getattr(a.frames, field), getattr(b.frames, field)):
                raise SystemExit(f"command {i}: {field} differ")
        substeps += (len(a.frames) - 1) * per_frame
        touching += bool(a.touched.any())
        executed += 1
    print(f"{len(commands)} commands, {executed} executed, {touching} touching an object; identical frames in each")
    for name, sec in seconds.items():
        print(f"{name:>22}: {sec / max(substeps, 1) * 1e6:6.1f} us per substep (simulation loop, recording)")
    print(f"ratio: {seconds['world'] / seconds['ManiSkill controller']:.2f}")
    for w in worlds.values():
        w.close()


if __name__ == "__main__":
    main()
