"""The video encoders and their settings, as LeRobot's encoder configurations (``RGBEncoderConfig``,
``DepthEncoderConfig``): the colour codec's quality and preset, the depth maps' quantization and lossless HEVC,
and what makes both give the same bytes for the same frames in any process."""

from __future__ import annotations

from babblegen.config import VIDEO_CODECS

# Depth maps: LeRobot's 12-bit lossless HEVC, quantized linearly over 4.095 m from a near limit, so that each code
# is one of the renderer's millimetres: the depth comes back exactly as rendered from the near limit to 4.095 m
# beyond it (fixed cameras: 0.2 to 4.295 m; the wrist camera, which sees the gripper up close: 0.02 to 4.115 m).
# Nearer reads as the near limit, farther (and where nothing is seen) as the far one.
DEPTH_NEAR_M = {"fixed": 0.2, "head": 0.2, "wrist": 0.02}


# The constant-quality level and speed preset per codec: LeRobot's defaults for SVT-AV1; for H.264, x264's
# "veryfast" preset without macroblock-tree rate control (X264_PARAMS) at CRF 27: as many bytes as x264 with it at
# CRF 22 (1.01x on 12 head-camera episodes) and as faithful (PSNR 36.85 against 36.66 dB), about as faithful as
# LeRobot's AV1 default (benchmarks/bench_codecs.py).
CRF = {"h264": 27, "libsvtav1": 30, "h264_mbtree": 22}  # h264_mbtree: x264 as runs made before, at CRF 22
PRESET = {"h264": "veryfast", "h264_mbtree": "veryfast"}  # SVT-AV1: LeRobot's own preset
# x264's macroblock-tree rate control off. Its cost propagation (mbtree_propagate_cost) divides with an approximate
# reciprocal (rcpps, one Newton step) in every SIMD version, whose result is the CPU maker's own: the same frames
# could code differently on Intel and AMD (benchmarks/count_vendor_instructions.py counted 2,632 executions in 20
# attempts; none with it off). Its plain C code divides exactly and codes other pictures.
X264_PARAMS = "mbtree=0"
# One encoder thread: episodes are encoded in the workers, one core each. (x264's own threads would compete with
# the other workers' simulations, and for frames this small they cost more CPU in all and give larger files.)
ENCODER_THREADS = 1


# What a CPU needs for x264's and x265's AVX2 code (Linux's names; "abm" is LZCNT): every Intel core since Haswell,
# every AMD core since Zen.
AVX2_LEVEL = frozenset({"sse4_2", "avx", "avx2", "fma", "bmi1", "bmi2", "abm"})


def _cpu_flags(cpuinfo: str) -> set[str]:
    """The first processor's flags in ``cpuinfo`` (empty where it cannot be read)."""
    try:
        with open(cpuinfo) as lines:
            return set(next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), []))
    except OSError:
        return set()


def encoder_instruction_sets(cpuinfo: str = "/proc/cpuinfo") -> tuple[str | None, str | None]:
    """x264's and x265's instruction sets: AVX2's on every CPU that has them, else (None, None), the encoders'
    own choice.

    Pinned so that the bytes do not depend on the CPU's kind. x264's AVX-512 code for macroblock-tree rate control
    gave different bytes from encode to encode of the same frames in one process, one thread, at widths that are
    not a multiple of 128 pixels (64, 96, 160, 192 measured; 128 and 256 not), as if it read memory nothing wrote;
    its AVX2 code gives the same bytes every time, and the same bytes as the AVX-512 code where that one is
    stable; its plain C code gives other bytes (benchmarks/check_encoder_dispatch.py). x265 writes the instruction
    sets it detected, a number that differs between CPU kinds, into every file's encoder-information message; its
    pictures are the same bytes with AVX2, SSE4.2 or C code. Passed to the encoders but not recorded in the
    dataset: they choose code, not output."""
    if not _cpu_flags(cpuinfo) >= AVX2_LEVEL:
        return None, None
    return "SSE2Fast,AVX2", "avx2"


X264_ASM, X265_ASM = encoder_instruction_sets()


def video_encoder(codec: str):
    """The encoder settings for ``codec`` (LeRobot's ``RGBEncoderConfig``: its GOP size, the CRF and preset of
    :data:`CRF` and :data:`PRESET`, x264's :data:`X264_PARAMS`; LeRobot records them in the dataset's info)."""
    from lerobot.configs.video import RGBEncoderConfig

    if codec not in VIDEO_CODECS:
        raise ValueError(f"unknown video codec {codec!r}; choose one of: {', '.join(VIDEO_CODECS)}")
    extra = {"x264-params": X264_PARAMS} if codec == "h264" else {}
    return RGBEncoderConfig(vcodec=base_codec(codec), crf=CRF[codec], preset=PRESET.get(codec), extra_options=extra)


def base_codec(codec: str) -> str:
    """The encoder a codec setting runs: ``h264_mbtree`` is x264 (``h264``) with other options."""
    return "h264" if codec == "h264_mbtree" else codec


def depth_encoder(mount: str, height: int, width: int):
    """LeRobot's depth-map encoder (12-bit lossless HEVC) over the range of :data:`DEPTH_NEAR_M`, for maps of
    ``height`` x ``width`` (:func:`x265_depth_params`)."""
    from lerobot.configs.video import DEPTH_QMAX, DepthEncoderConfig

    near = DEPTH_NEAR_M[mount]
    return DepthEncoderConfig(
        depth_min=near,
        depth_max=round(near + DEPTH_QMAX / 1000.0, 6),
        use_log=False,
        extra_options={"x265-params": x265_depth_params(height, width)},
    )


def x265_depth_params(height: int, width: int) -> str:
    """LeRobot's lossless 12-bit HEVC, with four changes:

    - a closed GOP: with x265's default open GOP, LeRobot's seeking decoder skipped frames after an episode
      boundary in a concatenated file (FrameTimestampError), on the files of LeRobot's own writer too;
    - the largest coding-tree unit (64, 32 or 16 pixels) smaller than both sides: a picture exactly one unit
      high or wide (64x64, 128x64 with x265's default of 64; 32x32 with 32) came out as different, equally
      lossless bytes from encode to encode of the same maps, in one process, threads or not; at 128x128 it
      stays x265's 64, so those files are unchanged (benchmarks/bench_encoding_repeats.py);
    - one thread (the workers have a core each);
    - no x265 info lines on the console.

    x265's "ultrafast" preset encoded 128x128 depth maps in a third of the time but took 2.5x the bytes, and
    gained nothing measurable in a run's episodes per second (benchmarks/bench_views.py): LeRobot's preset stays.
    """
    ctu = next((size for size in (64, 32) if min(height, width) > size), 16)
    return f"lossless=1:open-gop=0:ctu={ctu}:pools=1:frame-threads=1:log-level=error"


def feature_encoder(feature: dict, codec: str):
    """The encoder settings LeRobot records for a video feature: its depth encoder for a depth map (by the
    camera's mount), else the run's colour codec's."""
    info = feature.get("info") or {}
    if not info.get("is_depth_map"):
        return video_encoder(codec)
    return depth_encoder(info.get("camera.mount", "fixed"), *feature["shape"][:2])


def encoder_options(encoder) -> dict[str, str]:
    """The options an episode's encoder opens with: LeRobot's for ``encoder`` with :data:`ENCODER_THREADS`, and
    the instruction sets of :data:`X264_ASM` and :data:`X265_ASM`."""
    options = encoder.get_codec_options(ENCODER_THREADS, as_strings=True)
    for codecs, key, asm in (
        (("h264", "libx264"), "x264-params", X264_ASM),
        (("hevc", "libx265"), "x265-params", X265_ASM),
    ):
        if encoder.vcodec in codecs and asm is not None:
            options[key] = ":".join(filter(None, (options.get(key), f"asm={asm}")))
    return options
