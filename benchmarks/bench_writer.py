"""What writing one episode costs the coordinator: LeRobot's own writer against babblegen's segment writer, in
one run, on the same real rollout's frames; and whether the cost stays flat as the dataset grows.

- reference: ``add_frame`` + ``save_episode`` per episode (LeRobot's recording path), all in the coordinator.
- segments: the worker encodes the episode (video, statistics: ``encode_episode``), the coordinator appends it
  and writes a segment every ``--commit-every`` episodes (``SegmentWriter``). Reported apart: the worker's
  seconds and the coordinator's (append + its share of the segment writes), over the first and last windows.

    python benchmarks/bench_writer.py --episodes 1000 --reference-episodes 60 --commit-every 40
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
    p.add_argument("--episodes", type=int, default=1000, help="episodes through the segment writer")
    p.add_argument("--reference-episodes", type=int, default=60, help="episodes through LeRobot's writer")
    p.add_argument("--commit-every", type=int, default=40, help="episodes per segment (about 10 generations)")
    p.add_argument("--window", type=int, default=200)
    args = p.parse_args()

    from babblegen.dataset.schema import features
    from babblegen.exporters.lerobot_encoding import encode_episode
    from babblegen.exporters.lerobot_reference import ReferenceWriter
    from babblegen.exporters.lerobot_writer import SegmentWriter
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
    tmp = Path(tempfile.mkdtemp())
    feats = features(world.kin.joint_names, task.object_names, h, w)

    reference = ReferenceWriter.create(tmp / "reference", "bench/reference", 10, feats, "pr2_arm")
    ref = []
    for _ in range(args.reference_episodes):
        t = time.perf_counter()
        reference.add_episode(frames, "bench")
        ref.append(time.perf_counter() - t)
    reference.finalize()

    writer = SegmentWriter.create(tmp / "segments", "bench/segments", 10, feats, "pr2_arm")
    worker, coordinator, mem = [], [], []
    for i in range(args.episodes):
        t = time.perf_counter()
        encoded = encode_episode(frames, 10, writer.features)
        worker.append(time.perf_counter() - t)
        t = time.perf_counter()
        writer.add(encoded, "bench")
        if (i + 1) % args.commit_every == 0:
            writer.flush()
        coordinator.append(time.perf_counter() - t)
        mem.append(rss_mb())
    writer.flush()

    n = min(args.window, args.episodes // 2)
    ms = 1e3
    print(f"LeRobot's writer, coordinator per episode: {np.mean(ref[5:]) * ms:.1f} ms (mean of episodes 5+)")
    first, last = np.mean(coordinator[:n]), np.mean(coordinator[-n:])
    print(
        f"segment writer, coordinator per episode: first {n} {first * ms:.1f} ms, last {n} {last * ms:.1f} ms "
        f"(x{last / first:.2f}); worker per episode {np.mean(worker) * ms:.1f} ms"
    )
    print(f"coordinator speed-up: x{np.mean(ref[5:]) / np.mean(coordinator):.0f}")
    print(f"RSS after {n} episodes: {mem[n - 1]:.0f} MB, after {len(mem)}: {mem[-1]:.0f} MB")
    for name in ("reference", "segments"):
        files = [f for f in (tmp / name).rglob("*") if f.is_file()]
        print(f"{name}: {len(files)} files, {sum(f.stat().st_size for f in files) / 1e6:.1f} MB")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
