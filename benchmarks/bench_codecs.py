"""The head camera's video codecs on real episodes, in one run: what encoding costs the workers (CPU and wall
milliseconds per frame), how faithful the decoded frames are (PSNR against the rendered ones), the bytes per
frame left on disk, and what reading frames back costs a training loop (``LeRobotDataset[i]`` at random
indices, which decodes the video).

Each codec is encoded with babblegen's settings for it (``video_encoder``), the same episodes for every codec,
through babblegen's segment writer.

    python benchmarks/bench_codecs.py --episodes 12 --reads 300
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np


def record_episodes(n: int, seed: int):
    """``n`` executed movements of the default task (1-4 random waypoints each), as the workers record them."""
    os.environ.setdefault("LP_NUM_THREADS", "1")
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World

    task = get_task(DEFAULT_TASK)
    world = World(task, seed=seed)
    rng = np.random.default_rng(seed)
    frames = []
    while len(frames) < n:
        genome = rng.uniform(0.1, 0.9, size=(rng.integers(1, 5), 3))
        rollout = world.rollout(Command("ee_waypoints", genome))
        if rollout.feasible:
            frames.append(rollout.frames)
    world.close()
    return task, world.kin.joint_names, frames


def psnr(video: bytes, images: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB) of the decoded video against the frames it encodes."""
    import io

    import av

    with av.open(io.BytesIO(video)) as container:
        decoded = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
    mse = np.mean((decoded.astype(np.float64) - images.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=12)
    p.add_argument("--repeats", type=int, default=3, help="encodings of every episode per codec")
    p.add_argument("--reads", type=int, default=300, help="random frames read back per codec")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()

    from babblegen.config import VIDEO_CODECS
    from babblegen.dataset.lerobot import load_dataset
    from babblegen.dataset.schema import features
    from babblegen.exporters.lerobot_encoding import encode_episode, encode_video
    from babblegen.exporters.lerobot_writer import SegmentWriter

    task, joints, episodes = record_episodes(args.episodes, args.seed)
    n_frames = sum(len(f) for f in episodes)
    h, w = episodes[0].images.shape[1:3]
    print(f"{len(episodes)} episodes, {n_frames} frames of {w}x{h}")
    tmp = Path(tempfile.mkdtemp())
    results = {}
    for codec in VIDEO_CODECS:
        encode_video(episodes[0].images[:2], 10, codec)  # the encoder library loaded
        cpu, wall = time.process_time(), time.perf_counter()
        for _ in range(args.repeats):
            videos = [encode_video(f.images, 10, codec)[0] for f in episodes]
        cpu = (time.process_time() - cpu) / (args.repeats * n_frames) * 1e3
        wall = (time.perf_counter() - wall) / (args.repeats * n_frames) * 1e3
        size = sum(len(v) for v in videos) / n_frames
        fidelity = float(np.mean([psnr(v, f.images) for v, f in zip(videos, episodes, strict=True)]))

        writer = SegmentWriter.create(
            tmp / codec, f"bench/{codec}", 10, features(joints, task.object_names, h, w), "pr2_arm", codec
        )
        for f in episodes:
            writer.add(encode_episode(f, 10, writer.features, codec), "bench")
        writer.flush()
        ds = load_dataset(tmp / codec, f"bench/{codec}")
        rng = np.random.default_rng(args.seed)
        ds[0]
        t = time.perf_counter()
        for i in rng.integers(0, len(ds), args.reads):
            ds[int(i)]
        read = (time.perf_counter() - t) / args.reads * 1e3
        results[codec] = (cpu, wall, size, read)
        print(
            f"{codec:>10}: encode {cpu:.2f} ms CPU, {wall:.2f} ms wall per frame; PSNR {fidelity:.1f} dB; "
            f"{size:.0f} bytes per frame; LeRobotDataset[i] {read:.2f} ms"
        )
    base = results["libsvtav1"]
    for codec, r in results.items():
        if codec == "libsvtav1":
            continue
        print(
            f"{codec:>10} / libsvtav1: encode CPU x{r[0] / base[0]:.2f}, bytes x{r[2] / base[2]:.2f}, "
            f"read x{r[3] / base[3]:.2f}"
        )
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
