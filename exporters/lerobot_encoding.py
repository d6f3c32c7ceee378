"""An executed movement made ready for the LeRobot dataset where it was simulated.

The expensive part of writing a LeRobot episode is per-episode work that does not depend on where the episode
lands in the dataset: encoding its video and computing its statistics. `encode_episode` does that as LeRobot's
recording path does (``encode_video_frames`` with the run's codec, :func:`video_encoder`; ``compute_episode_stats``),
in the worker that ran the rollout, so one coordinator can append the episodes of many workers (see
``exporters/lerobot.py``). The statistics are LeRobot's, computed for less (``exporters/lerobot_stats.py``).
What depends on the position (frame and episode indexes) is left to the coordinator.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from babblegen.config import VIDEO_CODECS, RunConfig
from babblegen.exporters.lerobot_stats import image_stats, numeric_stats
from babblegen.world.rollout import Frames

HEAD = "observation.images.head"
DEFAULT_VIDEO_CODEC = RunConfig.video_codec  # each codec with LeRobot's own settings for it (`video_encoder`)
# Columns computed here; index, episode_index and task_index depend on the dataset and are added when written.
POSITION_COLUMNS = ("index", "episode_index", "task_index")
KINDS = ("rgb", "depth", "segmentation")
IMAGE_NAMES = ["height", "width", "channels"]
# Depth maps: LeRobot's 12-bit lossless HEVC, quantized linearly over 4.095 m from a near limit, so that each code
# is one of the renderer's millimetres: the depth comes back exactly as rendered from the near limit to 4.095 m
# beyond it (fixed cameras: 0.2 to 4.295 m; the wrist camera, which sees the gripper up close: 0.02 to 4.115 m).
# Nearer reads as the near limit, farther (and where nothing is seen) as the far one.
DEPTH_NEAR_M = {"fixed": 0.2, "head": 0.2, "wrist": 0.02}


def image_key(camera: str, kind: str = "rgb") -> str:
    """The feature of one camera's images: ``observation.images.<camera>``, ``..._depth`` (LeRobot's
    convention for depth maps), ``..._segmentation``."""
    return f"observation.images.{camera}" + ("" if kind == "rgb" else f"_{kind}")


def pose_key(camera: str) -> str:
    """The per-frame pose of a moving camera."""
    return f"observation.cam2world.{camera}"


def camera_features(cameras, task, settings) -> dict:
    """The image features of ``cameras`` (`WorldSettings.cameras`): each camera's colour video, depth video
    (LeRobot's ``is_depth_map``, in millimetres) and instance masks (16-bit PNG, an ``ids`` map from id to name),
    each with the camera's ``intrinsics`` (3x3, pixels) and, for a camera that does not move, ``cam2world``
    (4x4, OpenCV axes: x right, y down, z forward, in the world frame); a moving camera's pose per frame."""
    from babblegen.world.cameras import task_instance_names, view_parameters

    out: dict = {}
    ids = dict(enumerate(task_instance_names(task)))
    for view in cameras:
        height, width = view.size(settings)
        params = view_parameters(view, task, (height, width))
        info = {"intrinsics": params["intrinsics"].tolist(), "camera.mount": view.mount}
        if params["cam2world"] is not None:
            info["cam2world"] = params["cam2world"].tolist()
        out[image_key(view.name)] = {"dtype": "video", "shape": (height, width, 3), "names": IMAGE_NAMES, "info": info}
        if view.depth:
            depth_info = {**info, "is_depth_map": True, "depth_unit": "mm"}
            out[image_key(view.name, "depth")] = {
                "dtype": "video",
                "shape": (height, width, 1),
                "names": IMAGE_NAMES,
                "info": depth_info,
            }
        if view.segmentation:
            seg_info = {**info, "ids": {str(k): v for k, v in ids.items()}}
            out[image_key(view.name, "segmentation")] = {
                "dtype": "image",
                "shape": (height, width, 1),
                "names": IMAGE_NAMES,
                "info": seg_info,
            }
        if params["cam2world"] is None:
            out[pose_key(view.name)] = {
                "dtype": "float32",
                "shape": (16,),
                "names": [f"m{r}{c}" for r in range(4) for c in range(4)],
            }
    return out


def image_sources(features: dict) -> dict[str, tuple[str, str]]:
    """Each image feature's (camera, kind) by :func:`image_key`'s naming."""
    out = {}
    for key, ft in features.items():
        if ft["dtype"] not in ("video", "image") or not key.startswith("observation.images."):
            continue
        camera = key.removeprefix("observation.images.")
        kind = next((k for k in KINDS[1:] if camera.endswith(f"_{k}")), "rgb")
        out[key] = (camera.removesuffix(f"_{kind}") if kind != "rgb" else camera, kind)
    return out


def features(
    joint_names: list[str], object_names: list[str], height: int, width: int, cameras=None, task=None, settings=None
) -> dict:
    """The dataset schema (see DESIGN.md): the cameras' images (:func:`camera_features`; without ``cameras``, the
    head camera's colour video alone, as runs stored before cameras were a setting), joints, commanded joints,
    tool point, objects, contacts."""
    pose_fields = ("x", "y", "z", "qw", "qx", "qy", "qz")
    if cameras is None:
        images = {HEAD: {"dtype": "video", "shape": (height, width, 3), "names": IMAGE_NAMES}}
    else:
        images = camera_features(cameras, task, settings)
    poses = {k: v for k, v in images.items() if k.startswith("observation.cam2world.")}
    images = {k: v for k, v in images.items() if k not in poses}
    return {
        **images,
        **poses,
        "observation.state": {"dtype": "float32", "shape": (len(joint_names),), "names": list(joint_names)},
        "action": {"dtype": "float32", "shape": (len(joint_names),), "names": list(joint_names)},
        "observation.ee_pos": {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
        "observation.environment_state": {
            "dtype": "float32",
            "shape": (7 * len(object_names),),
            "names": [f"{o}.{f}" for o in object_names for f in pose_fields],
        },
        "observation.contacts": {
            "dtype": "float32",
            "shape": (len(object_names),),
            "names": list(object_names),
        },
    }


def with_default_features(feats: dict) -> dict:
    """The schema as LeRobot stores it: ours plus its own per-frame columns (timestamp, indexes)."""
    from lerobot.utils.constants import DEFAULT_FEATURES

    return {**feats, **DEFAULT_FEATURES}


@dataclass
class EncodedEpisode:
    """One episode ready to append: its per-frame columns (an image feature's as PNG bytes per frame), its
    videos (mp4 bytes per video feature), their duration and the episode statistics of everything but the
    position columns, as LeRobot's writer computes them."""

    columns: dict[str, np.ndarray | list[bytes]]
    videos: dict[str, bytes]
    duration_s: float
    stats: dict[str, dict[str, np.ndarray]]

    def __len__(self) -> int:
        return len(self.columns["frame_index"])


def camera_images(frames: Frames, camera: str, kind: str) -> np.ndarray:
    """One camera's images of one kind: (T, H, W, 3) uint8 colour, (T, H, W) uint16 mm depth or uint8 ids."""
    if camera == "head" and kind == "rgb":
        return frames.images
    return frames.views[camera][kind]


def frame_columns(frames: Frames, fps: int, features: dict) -> dict[str, np.ndarray]:
    """The episode's per-frame values under their feature names, as LeRobot's ``add_frame`` collects them:
    recordings in their feature dtypes, timestamps as float64 seconds (stored as float32)."""
    n = len(frames)
    recorded = {
        "observation.state": frames.state,
        "action": frames.action,
        "observation.ee_pos": frames.ee_pos,
        "observation.environment_state": frames.object_poses.reshape(n, -1),
        "observation.contacts": frames.contacts,
    }
    for key in features:
        if key.startswith("observation.cam2world."):
            recorded[key] = frames.camera_poses[key.removeprefix("observation.cam2world.")].reshape(n, 16)
    columns = {k: np.asarray(v, dtype=features[k]["dtype"]) for k, v in recorded.items()}
    columns["timestamp"] = np.arange(n) / fps
    columns["frame_index"] = np.arange(n)
    return columns


# The constant-quality level and speed preset per codec: LeRobot's defaults for SVT-AV1; for H.264, x264's
# "veryfast" preset at CRF 22, as faithful to the head camera as x264's defaults (medium, CRF 23) for about half
# the CPU and 1.04x the bytes, and about as faithful as LeRobot's AV1 default (benchmarks/bench_codecs.py).
CRF = {"h264": 22, "libsvtav1": 30}
PRESET = {"h264": "veryfast"}  # SVT-AV1: LeRobot's own preset
# One encoder thread: episodes are encoded in the workers, one core each. (x264's own threads would compete with
# the other workers' simulations, and for frames this small they cost more CPU in all and give larger files.)
ENCODER_THREADS = 1


def _x264_asm_below_avx512(cpuinfo: str = "/proc/cpuinfo") -> str | None:
    """x264's instruction sets for this CPU without AVX-512, where it has AVX-512 (else None: x264's own choice).

    x264's AVX-512 code for macroblock-tree rate control gave different bytes from encode to encode of the same
    frames in one process, one thread, at widths that are not a multiple of 128 pixels (64, 96, 160, 192
    measured; 128 and 256 not), as if it read memory nothing wrote; its AVX2 code gives the same bytes every
    time, and the same bytes as the AVX-512 code where that one is stable (128x128: the default's files are
    unchanged). Passed to the encoder but not recorded in the dataset: it chooses x264's code, not its output.
    x264 detects AVX-512 as these five extensions; every such CPU has everything up to AVX2 and fast SSE2."""
    try:
        with open(cpuinfo) as lines:
            flags = next((line.split(":", 1)[1].split() for line in lines if line.startswith("flags")), [])
    except OSError:
        return None
    avx512 = {"avx512f", "avx512dq", "avx512cd", "avx512bw", "avx512vl"}
    return "SSE2Fast,AVX2" if avx512 <= set(flags) else None


X264_ASM = _x264_asm_below_avx512()


def video_encoder(codec: str):
    """The encoder settings for ``codec`` (LeRobot's ``RGBEncoderConfig``: its GOP size, the CRF and preset of
    :data:`CRF` and :data:`PRESET`)."""
    from lerobot.configs.video import RGBEncoderConfig

    if codec not in VIDEO_CODECS:
        raise ValueError(f"unknown video codec {codec!r}; choose one of: {', '.join(VIDEO_CODECS)}")
    return RGBEncoderConfig(vcodec=codec, crf=CRF[codec], preset=PRESET.get(codec))


def depth_encoder(mount: str = "fixed", height: int = 128, width: int = 128):
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


def encode_depth(depth_mm: np.ndarray, fps: int, mount: str = "fixed") -> tuple[bytes, float]:
    """Encode (T, H, W) uint16 millimetre depth maps as LeRobot's ``encode_video_frames`` does a depth stream
    (its ``quantize_depth``, :func:`depth_encoder`'s settings), from memory. Returns mp4 bytes and duration."""
    from lerobot.datasets.depth_utils import quantize_depth

    encoder = depth_encoder(mount, *depth_mm.shape[1:3])

    def frame(image: np.ndarray):
        return quantize_depth(
            np.ascontiguousarray(image, dtype=np.uint16),
            depth_min=encoder.depth_min,
            depth_max=encoder.depth_max,
            shift=encoder.shift,
            use_log=encoder.use_log,
            pix_fmt=encoder.pix_fmt,
            video_backend="pyav",
        )

    return _encode(depth_mm, fps, encoder, frame)


def encode_png(images: np.ndarray) -> list[bytes]:
    """(T, H, W) integer images (instance ids; Rerun's depth maps in millimetres) as 16-bit grey PNG bytes, as
    LeRobot's image writer saves a single-channel image feature's frames (it takes uint16 or float32 for those);
    ``LeRobotDataset`` reads them back as the ids."""
    import io

    from PIL import Image

    out = []
    for image in images:
        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(image, dtype=np.uint16)).save(buf, format="PNG", compress_level=1)
        out.append(buf.getvalue())
    return out


def as_lerobot_reads_for_stats(ids: np.ndarray) -> np.ndarray:
    """(T, H, W) ids as LeRobot's statistics read a 16-bit grey PNG frame: converted to RGB by PIL (so the
    masks' statistics are LeRobot's own, though they say little: an id is a name, not a brightness)."""
    from PIL import Image

    return np.stack([np.asarray(Image.fromarray(f.astype(np.uint16)).convert("RGB")) for f in ids])


def encode_video(images: np.ndarray, fps: int, codec: str = DEFAULT_VIDEO_CODEC) -> tuple[bytes, float]:
    """Encode (T, H, W, 3) uint8 frames as LeRobot's ``encode_video_frames`` does in its recording path (the
    same PyAV calls, :func:`video_encoder`'s settings), from memory instead of PNG files: each frame goes to PyAV
    as an array rather than a PIL image (the same bytes, less copying). Returns the mp4 bytes and their duration
    in seconds."""
    import av

    return _encode(
        images,
        fps,
        video_encoder(codec),
        lambda image: av.VideoFrame.from_ndarray(np.ascontiguousarray(image), "rgb24"),
    )


def _encode(images: np.ndarray, fps: int, encoder, to_frame) -> tuple[bytes, float]:
    _quiet_codecs()
    import av
    from lerobot.datasets.video_utils import get_video_duration_in_s

    tmp = Path(tempfile.mkdtemp(prefix="babblegen-video-"))
    path = tmp / "episode.mp4"
    try:
        with av.open(str(path), "w") as output:
            options = encoder.get_codec_options(ENCODER_THREADS, as_strings=True)
            if encoder.vcodec in ("h264", "libx264") and X264_ASM is not None:
                options["x264-params"] = ":".join(filter(None, (options.get("x264-params"), f"asm={X264_ASM}")))
            stream = output.add_stream(encoder.vcodec, fps, options=options)
            stream.pix_fmt = encoder.pix_fmt
            stream.height, stream.width = images.shape[1:3]
            for image in images:
                packet = stream.encode(to_frame(image))
                if packet:
                    output.mux(packet)
            packet = stream.encode()
            if packet:
                output.mux(packet)
        return path.read_bytes(), get_video_duration_in_s(path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def encode_episode(frames: Frames, fps: int, features: dict, codec: str = DEFAULT_VIDEO_CODEC) -> EncodedEpisode:
    """Videos, columns and statistics of one executed movement (``features``: the schema as LeRobot stores
    it, :func:`with_default_features`)."""
    columns = frame_columns(frames, fps, features)
    stats = numeric_stats(columns, features)
    videos, duration = {}, None
    for key, (camera, kind) in image_sources(features).items():
        images = camera_images(frames, camera, kind)
        if kind == "rgb":
            videos[key], duration = encode_video(images, fps, codec)
            stats[key] = image_stats(images)
        elif kind == "depth":
            videos[key], _ = encode_depth(images, fps, features[key]["info"].get("camera.mount", "fixed"))
            stats[key] = image_stats(images[..., None], scale=1.0)
        else:
            columns[key] = encode_png(images)
            stats[key] = image_stats(as_lerobot_reads_for_stats(images))
    return EncodedEpisode(columns, videos, duration, stats)


class EpisodeEncoder:
    """``encode_episode`` as a picklable step for the worker-side preparers (``babblegen.evaluation.Preparers``)."""

    def __init__(self, fps: int, features: dict, codec: str = DEFAULT_VIDEO_CODEC):
        self.fps, self.features, self.codec = fps, features, codec

    def __call__(self, frames: Frames) -> EncodedEpisode:
        return encode_episode(frames, self.fps, self.features, self.codec)

    def warm_up(self) -> None:
        """Import LeRobot and start the encoders once (seconds), so that no attempt's timing includes it."""
        height, width = self.features[HEAD]["shape"][:2]
        encode_video(np.zeros((2, height, width, 3), dtype=np.uint8), self.fps, self.codec)
        if any(kind == "depth" for _, kind in image_sources(self.features).values()):
            encode_depth(np.zeros((2, height, width), dtype=np.uint16), self.fps)


def _quiet_codecs() -> None:
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
