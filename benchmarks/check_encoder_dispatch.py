"""Do the video bytes depend on which instruction sets the encoders use? The same rendered episodes (head camera,
colour and depth, the default 128 x 128) encoded by x264 and x265 under instruction sets that CPUs of other kinds
would give them, compared byte for byte with babblegen's own choice.

    python benchmarks/check_encoder_dispatch.py --episodes 12 --side 128

Against babblegen's choice (``lerobot_codecs.X264_ASM``, ``X265_ASM``): each encoder's own choice on this CPU,
AVX2's code (every CPU with AVX2, FMA and BMI2), SSE4.2's (a CPU without AVX) and the plain C code. The settings
name instructions this machine must have (AVX2 at least). Per setting: the episodes whose file differs, and those
whose coded pictures differ (the files' packets with the instruction-set number x265 writes into its
encoder-information message taken out).
"""

from __future__ import annotations

import argparse
import io
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_encoding_repeats import render_episodes, x264  # noqa: E402

X264_SETTINGS: dict[str, str | None] = {
    "x264 own choice": None,
    "AVX2": "SSE2Fast,AVX2",
    "SSE4.2 (no AVX)": "SSE2Fast,SSE4.2",
    "plain C": "0",
}
X265_SETTINGS: dict[str, str | None] = {
    "x265 own choice": None,
    "AVX2": "avx2",
    "SSE4.2 (no AVX)": "sse4.2",
    "plain C": "0",
}


def x265_bytes(depth, asm: str | None) -> bytes:
    from babblegen.exporters import lerobot_codecs
    from babblegen.exporters.lerobot_encoding import encode_depth

    kept, lerobot_codecs.X265_ASM = lerobot_codecs.X265_ASM, asm
    try:
        return encode_depth(depth, 10, "fixed")[0]
    finally:
        lerobot_codecs.X265_ASM = kept


def pictures(mp4: bytes) -> list[bytes]:
    """The coded pictures of an mp4, the encoder-information message's instruction-set number taken out."""
    import av

    with av.open(io.BytesIO(mp4)) as container:
        packets = [bytes(p) for p in container.demux(video=0) if p.size]
    return [re.sub(rb"cpuid=\d+", b"cpuid=", p) for p in packets]


def main() -> None:
    from babblegen.exporters.lerobot_codecs import X264_ASM, X265_ASM

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=12)
    p.add_argument("--side", type=int, default=128)
    p.add_argument("--seed", type=int, default=5)
    args = p.parse_args()
    episodes = render_episodes(args.side, args.episodes, args.seed)
    colour = [e["head"]["rgb"] for e in episodes]
    depth = [e["head"]["depth"] for e in episodes]
    frames = sum(len(c) for c in colour)
    print(f"{len(episodes)} episodes, {frames} frames at {args.side} x {args.side}")
    print(f"babblegen's instruction sets here: x264 {X264_ASM}, x265 {X265_ASM} (None: the encoder's own choice)")
    reference = [x264(X264_ASM)(c) for c in colour]
    print(f"{'encoder':<6} {'instruction sets':<18} {'other bytes':>12} {'other pictures':>15} {'bytes in all':>12}")
    for name, asm in X264_SETTINGS.items():
        got = [x264(asm)(c) for c in colour]
        report("x264", name, got, reference)
    reference = [x265_bytes(d, X265_ASM) for d in depth]
    for name, asm in X265_SETTINGS.items():
        got = [x265_bytes(d, asm) for d in depth]
        report("x265", name, got, reference)


def report(encoder: str, name: str, got: list[bytes], reference: list[bytes]) -> None:
    """One row: episodes whose file bytes differ from the reference, those whose coded pictures differ, bytes."""
    files = sum(a != b for a, b in zip(got, reference, strict=True))
    coded = sum(pictures(a) != pictures(b) for a, b in zip(got, reference, strict=True))
    n = len(got)
    print(f"{encoder:<6} {name:<18} {f'{files} of {n}':>12} {f'{coded} of {n}':>15} {sum(map(len, got)):>12}")


if __name__ == "__main__":
    main()
