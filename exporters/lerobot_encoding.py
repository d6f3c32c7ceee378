"""An executed movement made ready for the LeRobot dataset where it was simulated.

The expensive part of writing a LeRobot episode is per-episode work that does not depend on where the episode
lands in the dataset: encoding its video and computing its statistics. `encode_episode` does that as LeRobot's
default recording path does (``encode_video_frames`` with its default RGB settings, ``compute_episode_stats``),
in the worker that ran the rollout, so one coordinator can append the episodes of many workers (see
``exporters/lerobot.py``). The image statistics are computed from pixel-value counts (:func:`image_stats`).
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


# The constant-quality level per codec: LeRobot's default for SVT-AV1; for H.264, x264's own default, at which
# the head-camera video is about as faithful as with LeRobot's AV1 default (PSNR 36.9 against 36.6 dB on the
# default scene, for 1.1x the bytes; benchmarks/bench_codecs.py).
CRF = {"h264": 23, "libsvtav1": 30}
# One encoder thread: episodes are encoded in the workers, one core each. (x264's own threads would compete with
# the other workers' simulations, and for frames this small they cost more CPU in all and give larger files.)
ENCODER_THREADS = 1


def video_encoder(codec: str):
    """The encoder settings for ``codec`` (LeRobot's ``RGBEncoderConfig``: its GOP size and preset, the CRF of
    :data:`CRF`)."""
    from lerobot.configs.video import RGBEncoderConfig

    if codec not in VIDEO_CODECS:
        raise ValueError(f"unknown video codec {codec!r}; choose one of: {', '.join(VIDEO_CODECS)}")
    return RGBEncoderConfig(vcodec=codec, crf=CRF[codec])


def encode_video(images: np.ndarray, fps: int, codec: str = DEFAULT_VIDEO_CODEC) -> tuple[bytes, float]:
    """Encode (T, H, W, 3) uint8 frames as LeRobot's ``encode_video_frames`` does in its recording path (the
    same PyAV calls, :func:`video_encoder`'s settings), from memory instead of PNG files. Returns the mp4 bytes
    and their duration in seconds."""
    _quiet_codecs()
    import av
    from lerobot.datasets.video_utils import get_video_duration_in_s
    from PIL import Image

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
                packet = stream.encode(av.VideoFrame.from_image(Image.fromarray(image)))
                if packet:
                    output.mux(packet)
            packet = stream.encode()
            if packet:
                output.mux(packet)
        return path.read_bytes(), get_video_duration_in_s(path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def image_stats(images: np.ndarray) -> dict[str, np.ndarray]:
    """The episode statistics LeRobot's ``compute_episode_stats`` records for a video feature (its sampled
    frames, per channel, scaled to [0, 1]), computed from per-channel counts of the 256 pixel values.

    LeRobot feeds every sampled pixel to a 5,000-bin running histogram (2-3 ms per 128x128 frame); the same
    histogram, minimum, maximum and quantiles follow exactly from the counts, at a fraction of the cost. The mean
    and standard deviation are computed in float64 (LeRobot accumulates them in float32: they agree to about
    1e-6)."""
    from lerobot.datasets.compute_stats import (
        RunningQuantileStats,
        _reshape_stats_by_axis,
        auto_downsample_height_width,
        sample_indices,
    )

    chw = np.stack([auto_downsample_height_width(images[i].transpose(2, 0, 1)) for i in sample_indices(len(images))])
    values = np.arange(256, dtype=np.float32)
    counts = np.stack([np.bincount(chw[:, c].ravel(), minlength=256) for c in range(chw.shape[1])])
    total = int(counts[0].sum())
    running = RunningQuantileStats()
    running._count = total
    running._min = np.array([values[row > 0][0] for row in counts], dtype=np.float32)
    running._max = np.array([values[row > 0][-1] for row in counts], dtype=np.float32)
    running._mean = (counts @ values.astype(np.float64) / total).astype(np.float32)
    running._mean_of_squares = (counts @ values.astype(np.float64) ** 2 / total).astype(np.float32)
    running._bin_edges = [  # as RunningQuantileStats.update sets them on its first batch
        np.linspace(running._min[c] - 1e-10, running._max[c] + 1e-10, running._num_quantile_bins + 1)
        for c in range(len(counts))
    ]
    running._histograms = [
        np.histogram(values, bins=edges, weights=row)[0] for edges, row in zip(running._bin_edges, counts, strict=True)
    ]
    stats = running.get_statistics()
    stats["count"] = np.array([len(chw)])
    stats = _reshape_stats_by_axis(stats, (0, 2, 3), True, chw.shape)
    return {k: v if k == "count" else np.squeeze(v / 255.0, axis=0) for k, v in stats.items()}


def encode_episode(frames: Frames, fps: int, features: dict, codec: str = DEFAULT_VIDEO_CODEC) -> EncodedEpisode:
    """Video, columns and statistics of one executed movement (``features``: the schema as LeRobot stores
    it, :func:`with_default_features`)."""
    from lerobot.datasets.compute_stats import compute_episode_stats

    columns = frame_columns(frames, fps, features)
    video, duration = encode_video(frames.images, fps, codec)
    stats = compute_episode_stats(columns, features)
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
