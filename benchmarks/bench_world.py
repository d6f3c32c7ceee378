"""Time the simulated world on a batch of random commands: feasibility, where the time goes, frames per episode.

Waypoint mode (default): one end-effector waypoint per command, uniform in the normalised workspace [0, 1]^3.
Joint mode (``--joint``): one joint target per command, uniform within the joint limits.
The first rollout of a process compiles the renderer's shaders; it is timed separately and not counted.
Run: ``python benchmarks/bench_world.py [--n 40] [--joint] [--seed 0] [--task noveb_tabletop]``.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from babblegen.tasks import DEFAULT_TASK, get_task
from babblegen.world.rollout import REASONS, Command, Rollout
from babblegen.world.world import World, WorldSettings

PARTS = ("ik", "plan", "sim", "render", "total")


def random_commands(world: World, n: int, joint: bool, rng: np.random.Generator) -> list[Command]:
    if joint:
        return [Command("joint_target", rng.uniform(world.kin.lower, world.kin.upper)) for _ in range(n)]
    return [Command("ee_waypoints", rng.uniform(0.0, 1.0, (1, 3))) for _ in range(n)]


def mean_timings(rollouts: list[Rollout]) -> dict[str, float]:
    if not rollouts:
        return dict.fromkeys(PARTS, float("nan"))
    return {k: float(np.mean([r.timings.get(k, 0.0) for r in rollouts])) for k in PARTS}


def report(world: World, rollouts: list[Rollout], warmup: tuple[Rollout, float], wall: float) -> str:
    n = len(rollouts)
    done = [r for r in rollouts if r.feasible]
    reasons = Counter(r.reason for r in rollouts if not r.feasible)
    planners = Counter(r.planner for r in done)
    lines = [
        f"device: CPU physics + CPU render, {world.settings.camera_width}x{world.settings.camera_height} "
        f"head camera, {world.settings.fps} fps",
        f"warm-up rollout (first render, shader compile): {warmup[1]:.2f} s "
        f"({'feasible' if warmup[0].feasible else warmup[0].reason})",
        f"commands: {n}, wall {wall:.2f} s ({wall / max(n, 1):.3f} s per command)",
        f"feasible: {len(done)}/{n} = {len(done) / max(n, 1):.0%}",
    ]
    for reason in REASONS:
        if reasons[reason]:
            lines.append(f"  {reason:<20} {reasons[reason]:>4}  {reasons[reason] / n:.0%}")
    lines.append("planner (executed): " + ", ".join(f"{p} {planners[p]}" for p in ("direct", "rrtconnect")))
    header = f"{'mean seconds':<24}" + "".join(f"{k:>9}" for k in PARTS)
    lines += [header, "-" * len(header)]
    for label, subset in (("per attempted", rollouts), ("per executed", done)):
        t = mean_timings(subset)
        lines.append(f"{label:<24}" + "".join(f"{t[k]:>9.4f}" for k in PARTS))
    if done:
        frames = np.array([len(r.frames) for r in done])
        per_frame = np.mean([r.timings["render"] / len(r.frames) for r in done])
        moved = np.array([r.displacement for r in done])
        touched = np.array([r.touched for r in done])
        off_table = np.array([(r.final_poses[:, 2] < world.task.table_top - 0.02).any() for r in done])
        lines += [
            f"frames per episode: mean {frames.mean():.1f}, min {frames.min()}, max {frames.max()}"
            f" ({frames.mean() / world.settings.fps:.1f} s simulated)",
            f"render per frame: {per_frame * 1000:.1f} ms",
            f"episodes touching an object: {touched.any(axis=1).sum()}, moving one > 5 mm: "
            f"{(moved > 0.005).any(axis=1).sum()}, knocking one off the table: {off_table.sum()}",
        ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=40, help="number of random commands")
    parser.add_argument("--joint", action="store_true", help="random joint targets instead of waypoints")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--task", default=DEFAULT_TASK)
    args = parser.parse_args()

    t0 = time.perf_counter()
    world = World(get_task(args.task), WorldSettings(), seed=args.seed)
    print(f"World construction: {time.perf_counter() - t0:.2f} s")
    t0 = time.perf_counter()
    # a short move from home (1.5 cm down); render directly should the task make it infeasible
    warm = world.rollout(Command("ee_waypoints", world.start_norm[None] + [[0.0, 0.0, -0.05]]))
    if not warm.feasible:
        world._render()
    warmup = (warm, time.perf_counter() - t0)

    rng = np.random.default_rng(args.seed)
    commands = random_commands(world, args.n, args.joint, rng)
    t0 = time.perf_counter()
    rollouts = [world.rollout(c) for c in commands]
    wall = time.perf_counter() - t0
    print(f"mode: {'joint targets' if args.joint else 'end-effector waypoints'}, task {args.task}")
    print(report(world, rollouts, warmup, wall))
    world.close()


if __name__ == "__main__":
    main()
