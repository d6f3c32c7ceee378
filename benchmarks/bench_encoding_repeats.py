"""Do the same rendered frames always encode to the same bytes? Each episode of every camera is encoded several
times in one process, with other episodes encoded in between (as a worker does, whose history differs with 1
worker and with 2), under each encoder setting; the table shows how many episodes came out as more than one
byte string, the bytes and the encoding milliseconds per frame.

Colour (x264): x264's own choice of instruction sets (AVX-512 where the CPU has it) against babblegen's
(``lerobot_codecs.X264_ASM``). Depth (x265, lossless): coding-tree units of 64 (x265's default), 32 and 16
pixels, against babblegen's choice for the size (``x265_depth_params``).

    python benchmarks/bench_encoding_repeats.py --sides 64 96 128 --episodes 9 --repeats 4
"""

from __future__ import annotations

import argparse
import os
import re
import time
from dataclasses import replace

import numpy as np


def render_episodes(side: int, n: int, seed: int) -> list[dict[str, dict[str, np.ndarray]]]:
    """``n`` executed movements seen by the head, front and wrist cameras, colour and depth."""
    os.environ.setdefault("LP_NUM_THREADS", "1")
    from babblegen.camera_views import CAMERA_PRESETS
    from babblegen.tasks import DEFAULT_TASK, get_task
    from babblegen.world.rollout import Command
    from babblegen.world.settings import WorldSettings
    from babblegen.world.world import World

    cameras = tuple(replace(CAMERA_PRESETS[name], depth=True) for name in ("head", "front", "wrist"))
    world = World(get_task(DEFAULT_TASK), WorldSettings(cameras=cameras, camera_width=side, camera_height=side))
    rng = np.random.default_rng(seed)
    episodes = []
    while len(episodes) < n:
        rollout = world.rollout(Command("ee_waypoints", rng.uniform(0.1, 0.9, size=(rng.integers(1, 4), 3))))
        if rollout.feasible:
            views = rollout.frames.views
            views["head"]["rgb"] = rollout.frames.images
            episodes.append(views)
    world.close()
    return episodes


def x264(asm: str | None):
    """Encode colour with x264 given these instruction sets (None: x264's own choice)."""
    from babblegen.exporters import lerobot_codecs
    from babblegen.exporters.lerobot_encoding import encode_video

    def encode(images: np.ndarray) -> bytes:
        kept, lerobot_codecs.X264_ASM = lerobot_codecs.X264_ASM, asm
        try:
            return encode_video(images, 10)[0]
        finally:
            lerobot_codecs.X264_ASM = kept

    return encode


def x265(ctu: int | None, mount: str):
    """Encode millimetre depth with x265 with this coding-tree unit (None: babblegen's choice for the size)."""
    from babblegen.exporters import lerobot_codecs
    from babblegen.exporters.lerobot_encoding import encode_depth

    def encode(depth: np.ndarray) -> bytes:
        chosen = lerobot_codecs.x265_depth_params
        if ctu is not None:
            lerobot_codecs.x265_depth_params = lambda h, w: re.sub(r"ctu=\d+", f"ctu={ctu}", chosen(h, w))
        try:
            return encode_depth(depth, 10, mount)[0]
        finally:
            lerobot_codecs.x265_depth_params = chosen

    return encode


def repeats(episodes: list[np.ndarray], encode, n: int) -> tuple[int, float, float]:
    """Episodes with more than one encoding among ``n``, mean bytes per episode, milliseconds per frame."""
    from babblegen.exporters.lerobot_encoding import encode_png

    varying, size, seconds, frames = 0, 0, 0.0, 0
    for i, images in enumerate(episodes):
        got = set()
        for r in range(n):
            t0 = time.perf_counter()
            got.add(encode(images))
            seconds += time.perf_counter() - t0
            frames += len(images)
            other = episodes[(i + r + 1) % len(episodes)]
            encode(other)  # another episode in between, as on a worker
            encode_png(np.zeros((2, *images.shape[1:3]), dtype=np.uint16))
        varying += len(got) > 1
        size += len(next(iter(got)))
    return varying, size / len(episodes), 1000 * seconds / frames


def main() -> None:
    from babblegen.exporters.lerobot_codecs import X264_ASM, x265_depth_params

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sides", type=int, nargs="+", default=[64, 96, 128])
    p.add_argument("--episodes", type=int, default=9)
    p.add_argument("--repeats", type=int, default=4)
    p.add_argument("--seed", type=int, default=5)
    args = p.parse_args()
    print(f"x264 instruction sets chosen here: {X264_ASM or 'x264 own (no AVX-512 on this CPU)'}")
    print(f"{'side':>4} {'camera':<6} {'kind':<6} {'setting':<28} {'varying':>9} {'kB/episode':>10} {'ms/frame':>8}")
    for side in args.sides:
        episodes = render_episodes(side, args.episodes, args.seed)
        x264(None)(episodes[0]["head"]["rgb"]), x265(None, "fixed")(episodes[0]["head"]["depth"])  # warm up
        for camera in ("head", "front", "wrist"):
            settings = [("x264 own", x264(None)), (f"babblegen ({X264_ASM or 'x264 own'})", x264(X264_ASM))]
            colour = [e[camera]["rgb"] for e in episodes]
            rows = [("rgb", name, repeats(colour, enc, args.repeats)) for name, enc in settings]
            ctu = x265_depth_params(side, side).split("ctu=")[1].split(":")[0]
            mount = "wrist" if camera == "wrist" else "fixed"
            depth_settings = [(f"ctu={c}", x265(c, mount)) for c in (64, 32, 16)]
            depth_settings.append((f"babblegen (ctu={ctu})", x265(None, mount)))
            depth = [e[camera]["depth"] for e in episodes]
            rows += [("depth", name, repeats(depth, enc, args.repeats)) for name, enc in depth_settings]
            for kind, name, (varying, size, ms) in rows:
                shown = f"{varying}/{len(episodes)}"
                print(f"{side:>4} {camera:<6} {kind:<6} {name:<28} {shown:>9} {size / 1000:>10.1f} {ms:>8.2f}")


if __name__ == "__main__":
    main()
