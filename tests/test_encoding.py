"""Episode videos are a function of their frames: the same frames give the same bytes however many episodes the
process encoded before (a worker's encoder sees a different history with 1 worker than with 2)."""

from __future__ import annotations

import numpy as np

from babblegen.exporters import lerobot_codecs
from babblegen.exporters.lerobot_codecs import x265_depth_params
from babblegen.exporters.lerobot_encoding import encode_depth, encode_video


def camera_like(side: int, n: int, seed: int) -> np.ndarray:
    """Colour frames of a square moving over a noisy ramp."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:side, 0:side]
    frames = []
    for t in range(n):
        image = np.stack([(xx * 3 + yy) % 256, (yy * 2 + 40) % 256, np.full_like(xx, 90)], -1)
        image = np.clip(image + rng.integers(-6, 7, image.shape), 0, 255).astype(np.uint8)
        image[side // 3 : side // 3 + 12, 4 + 2 * t : 16 + 2 * t] = (200, 30, 30)
        frames.append(image)
    return np.stack(frames)


def test_the_same_frames_give_the_same_video_whatever_was_encoded_before():
    """x264's AVX-512 code gave a different encoding of these frames at 96 pixels nearly every time (12 of 12
    episodes without `lerobot_codecs.X264_ASM`); each of 4 episodes encoded twice, another in between. (Depth
    maps: a picture one coding unit high did the same, on rendered maps only; tests/test_parallel.py.)"""
    episodes = [camera_like(96, 12 + seed, seed) for seed in range(4)]
    for frames in episodes:
        videos = set()
        for other in (1, 2):
            videos.add(encode_video(frames, 10)[0])
            encode_video(episodes[-other], 10)  # what a worker encodes between two episodes
            encode_depth(np.full((4, 96, 96), 900, dtype=np.uint16), 10)
        assert len(videos) == 1


def test_depth_maps_take_the_largest_coding_unit_smaller_than_both_sides():
    def ctu(height: int, width: int) -> str:
        return next(p for p in x265_depth_params(height, width).split(":") if p.startswith("ctu="))

    assert ctu(128, 128) == "ctu=64"  # x265's own, as LeRobot encodes
    assert ctu(256, 192) == "ctu=64"
    assert ctu(64, 64) == ctu(128, 64) == ctu(64, 96) == "ctu=32"
    assert ctu(32, 32) == ctu(48, 32) == "ctu=16"
    assert x265_depth_params(128, 128).startswith("lossless=1:")


def test_x264_is_kept_below_avx512_only_where_the_cpu_has_it(tmp_path):
    def cpu(flags: str) -> str | None:
        path = tmp_path / "cpuinfo"
        path.write_text(f"processor\t: 0\nflags\t\t: {flags}\n\nprocessor\t: 1\nflags\t\t: {flags}\n")
        return lerobot_codecs._x264_asm_below_avx512(str(path))

    avx2 = "fpu sse sse2 ssse3 sse4_1 sse4_2 avx fma bmi1 bmi2 avx2"
    assert cpu(avx2 + " avx512f avx512dq avx512cd avx512bw avx512vl avx512vbmi") == "SSE2Fast,AVX2"
    assert cpu(avx2) is None
    assert cpu(avx2 + " avx512f avx512cd") is None  # x264 uses AVX-512 only with all five
    assert lerobot_codecs._x264_asm_below_avx512(str(tmp_path / "missing")) is None
