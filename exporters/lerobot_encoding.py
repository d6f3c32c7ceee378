"""An executed movement made ready for the LeRobot dataset where it was simulated.

The expensive part of writing a LeRobot episode is per-episode work that does not depend on where the episode
lands in the dataset: encoding its video and computing its statistics. `encode_episode` does that with LeRobot's
own code (its streaming video encoder, with its default RGB settings, and `compute_episode_stats`), in the
worker that ran the rollout, so one coordinator can append the episodes of many workers (see
``exporters/lerobot.py``). What depends on the position (frame and episode indexes) is left to the coordinator.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from babblegen.world.rollout import Frames

HEAD = "observation.images.head"
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


def encode_video(images: np.ndarray, fps: int) -> tuple[bytes, float, dict[str, np.ndarray] | None]:
    """Encode (T, H, W, 3) uint8 frames with LeRobot's streaming encoder (default RGB settings). Returns the
    mp4 bytes, its duration in seconds, and the image statistics LeRobot records for the episode."""
    _quiet_codecs()
    from lerobot.datasets.video_utils import StreamingVideoEncoder, get_video_duration_in_s

    encoder = StreamingVideoEncoder(fps, queue_maxsize=len(images) + 1)  # never drops a frame
    tmp = Path(tempfile.mkdtemp(prefix="babblegen-video-"))
    try:
        encoder.start_episode([HEAD], tmp)
        for image in images:
            encoder.feed_frame(HEAD, image)
        path, video_stats = encoder.finish_episode()[HEAD]
        data = path.read_bytes()
        duration = get_video_duration_in_s(path)
    finally:
        encoder.close()
        shutil.rmtree(tmp, ignore_errors=True)
    if video_stats is not None:  # per channel, scaled to [0, 1], as LeRobot's save_episode stores them
        video_stats = {
            k: v if k == "count" else np.squeeze(v.reshape(1, -1, 1, 1) / 255.0, axis=0) for k, v in video_stats.items()
        }
    return data, duration, video_stats


def encode_episode(frames: Frames, fps: int, features: dict) -> EncodedEpisode:
    """Video, columns and statistics of one executed movement (``features``: the schema as LeRobot stores
    it, :func:`with_default_features`)."""
    from lerobot.datasets.compute_stats import compute_episode_stats

    columns = frame_columns(frames, fps, features)
    video, duration, video_stats = encode_video(frames.images, fps)
    stats = compute_episode_stats(columns, features)
    if video_stats is not None:
        stats[HEAD] = video_stats
    return EncodedEpisode(columns, video, duration, stats)


class EpisodeEncoder:
    """``encode_episode`` as a picklable step for the worker-side preparers (``babblegen.evaluation.Preparers``)."""

    def __init__(self, fps: int, features: dict):
        self.fps, self.features = fps, features

    def __call__(self, frames: Frames) -> EncodedEpisode:
        return encode_episode(frames, self.fps, self.features)

    def warm_up(self) -> None:
        """Import LeRobot and start the encoder once (seconds), so that no attempt's timing includes it."""
        height, width = self.features[HEAD]["shape"][:2]
        encode_video(np.zeros((2, height, width, 3), dtype=np.uint8), self.fps)


def _quiet_codecs() -> None:
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
