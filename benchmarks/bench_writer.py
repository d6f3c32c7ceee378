"""Cost of saving one episode as the dataset grows (it must stay flat), and the writer's memory.

Writes N copies of a real rollout's frames through babblegen's EpisodeWriter (LeRobot's own writer with
commit points every `--commit-every` episodes) and reports the mean save time and the process RSS over the
first and last windows of episodes.

    python benchmarks/bench_writer.py --episodes 1000 --commit-every 120
"""

from __future__ import annotations

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--commit-every", type=int, default=120, help="episodes per commit (10 generations of 12)")
    p.add_argument("--window", type=int, default=50)
    args = p.parse_args()

    from babblegen.exporters.lerobot import EpisodeWriter, features
    from babblegen.tasks import get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World

    task = get_task("noveb_tabletop")
    world = World(task)
    rollout = world.rollout(Command("ee_waypoints", task.workspace.to_norm(np.array([[0.72, -0.08, 0.76]]))))
    frames = rollout.frames
    world.close()
    h, w = frames.images.shape[1:3]
    print(f"episode: {len(frames)} frames of {w}x{h}")

    root = Path(tempfile.mkdtemp()) / "ds"
    feats = features(world.kin.joint_names, task.object_names, h, w)
    writer = EpisodeWriter.create(root, "bench/writer", 10, feats, "pr2_like_arm")
    save, mem, commits = [], [], []
    for i in range(args.episodes):
        t = time.perf_counter()
        writer.add_episode(frames, "bench")
        save.append(time.perf_counter() - t)
        mem.append(rss_mb())
        if (i + 1) % args.commit_every == 0:
            t = time.perf_counter()
            writer.commit()
            commits.append(time.perf_counter() - t)
    writer.finalize()
    n = args.window
    first, last = np.mean(save[:n]), np.mean(save[-n:])
    print(
        f"save per episode, episodes 0-{n - 1}: {first * 1e3:.0f} ms, "
        f"last {n}: {last * 1e3:.0f} ms (x{last / first:.2f})"
    )
    print(f"RSS after {n} episodes: {mem[n - 1]:.0f} MB, after {len(mem)}: {mem[-1]:.0f} MB")
    if commits:
        print(f"commit point (finalize + reopen): {np.mean(commits) * 1e3:.0f} ms on average over {len(commits)}")
    files = sum(1 for _ in root.rglob("*") if _.is_file())
    size = sum(f.stat().st_size for f in root.rglob("*") if f.is_file()) / 1e6
    print(f"dataset: {args.episodes} episodes, {files} files, {size:.1f} MB")
    shutil.rmtree(root.parent)


if __name__ == "__main__":
    main()
