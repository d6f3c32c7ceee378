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


def test_both_encoders_run_avx2_code_on_every_cpu_that_has_it(tmp_path):
    """The same instruction sets on every CPU kind with AVX2: x264's AVX-512 code, where the CPU has it, never
    runs, and x265 writes the same instruction-set number into its files."""

    def cpu(flags: str) -> tuple[str | None, str | None]:
        path = tmp_path / "cpuinfo"
        path.write_text(f"processor\t: 0\nflags\t\t: {flags}\n\nprocessor\t: 1\nflags\t\t: {flags}\n")
        return lerobot_codecs.encoder_instruction_sets(str(path))

    haswell = "fpu sse sse2 ssse3 sse4_1 sse4_2 avx fma abm bmi1 bmi2 avx2"
    pinned = ("SSE2Fast,AVX2", "avx2")
    assert cpu(haswell) == pinned
    assert cpu(haswell + " avx512f avx512dq avx512cd avx512bw avx512vl avx512vbmi") == pinned
    assert cpu(haswell.replace(" avx2", "")) == (None, None)  # an AVX2 pin would be an illegal instruction here
    assert cpu("fpu sse sse2 ssse3 sse4_1 sse4_2") == (None, None)
    assert lerobot_codecs.encoder_instruction_sets(str(tmp_path / "missing")) == (None, None)


def test_the_pinned_instruction_sets_reach_the_encoders():
    from babblegen.exporters.lerobot_codecs import depth_encoder, encoder_options, video_encoder

    colour, depth = encoder_options(video_encoder("h264")), encoder_options(depth_encoder("fixed", 128, 128))
    assert "mbtree=0" in colour["x264-params"].split(":")  # its SIMD code divides approximately
    if lerobot_codecs.X264_ASM is None:
        assert "asm=" not in colour["x264-params"] and "asm=" not in depth["x265-params"]
    else:
        assert colour["x264-params"].endswith(f"asm={lerobot_codecs.X264_ASM}")
        assert depth["x265-params"] == f"{x265_depth_params(128, 128)}:asm={lerobot_codecs.X265_ASM}"
