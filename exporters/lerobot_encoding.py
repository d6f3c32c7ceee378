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


def features(joint_names: list[str], object_names: list[str], height: int, width: int) -> dict:
    """The dataset schema (see DESIGN.md): head video, joints, commanded joints, tool point, objects, contacts."""
    pose_fields = ("x", "y", "z", "qw", "qx", "qy", "qz")
    return {
        HEAD: {"dtype": "video", "shape": (height, width, 3), "names": ["height", "width", "channels"]},
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
    """One episode ready to append: its per-frame columns, its head-camera video (mp4 bytes) and the episode
    statistics of everything but the position columns, as LeRobot's writer computes them."""

    columns: dict[str, np.ndarray]
    video: bytes
    duration_s: float
    stats: dict[str, dict[str, np.ndarray]]

    def __len__(self) -> int:
        return len(self.columns["frame_index"])


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


def video_encoder(codec: str):
    """The encoder settings for ``codec`` (LeRobot's ``RGBEncoderConfig``: its GOP size, the CRF and preset of
    :data:`CRF` and :data:`PRESET`)."""
    from lerobot.configs.video import RGBEncoderConfig

    if codec not in VIDEO_CODECS:
        raise ValueError(f"unknown video codec {codec!r}; choose one of: {', '.join(VIDEO_CODECS)}")
    return RGBEncoderConfig(vcodec=codec, crf=CRF[codec], preset=PRESET.get(codec))


def encode_video(images: np.ndarray, fps: int, codec: str = DEFAULT_VIDEO_CODEC) -> tuple[bytes, float]:
    """Encode (T, H, W, 3) uint8 frames as LeRobot's ``encode_video_frames`` does in its recording path (the
    same PyAV calls, :func:`video_encoder`'s settings), from memory instead of PNG files: each frame goes to PyAV
    as an array rather than a PIL image (the same bytes, less copying). Returns the mp4 bytes and their duration
    in seconds."""
    _quiet_codecs()
    import av
    from lerobot.datasets.video_utils import get_video_duration_in_s

    encoder = video_encoder(codec)
    tmp = Path(tempfile.mkdtemp(prefix="babblegen-video-"))
    path = tmp / "episode.mp4"
    try:
        with av.open(str(path), "w") as output:
            options = encoder.get_codec_options(ENCODER_THREADS, as_strings=True)
            stream = output.add_stream(encoder.vcodec, fps, options=options)
            stream.pix_fmt = encoder.pix_fmt
            stream.height, stream.width = images.shape[1:3]
            for image in images:
                packet = stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24"))
                if packet:
                    output.mux(packet)
            packet = stream.encode()
            if packet:
                output.mux(packet)
        return path.read_bytes(), get_video_duration_in_s(path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def encode_episode(frames: Frames, fps: int, features: dict, codec: str = DEFAULT_VIDEO_CODEC) -> EncodedEpisode:
    """Video, columns and statistics of one executed movement (``features``: the schema as LeRobot stores
    it, :func:`with_default_features`)."""
    columns = frame_columns(frames, fps, features)
    video, duration = encode_video(frames.images, fps, codec)
    stats = numeric_stats(columns, features)
    stats[HEAD] = image_stats(frames.images)
    return EncodedEpisode(columns, video, duration, stats)


class EpisodeEncoder:
    """``encode_episode`` as a picklable step for the worker-side preparers (``babblegen.evaluation.Preparers``)."""

    def __init__(self, fps: int, features: dict, codec: str = DEFAULT_VIDEO_CODEC):
        self.fps, self.features, self.codec = fps, features, codec

    def __call__(self, frames: Frames) -> EncodedEpisode:
        return encode_episode(frames, self.fps, self.features, self.codec)

    def warm_up(self) -> None:
        """Import LeRobot and start the encoder once (seconds), so that no attempt's timing includes it."""
        height, width = self.features[HEAD]["shape"][:2]
        encode_video(np.zeros((2, height, width, 3), dtype=np.uint8), self.fps, self.codec)


def _quiet_codecs() -> None:
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
