"""An executed movement made ready for the LeRobot dataset where it was simulated.

The expensive part of writing a LeRobot episode is per-episode work that does not depend on where the episode
lands in the dataset: encoding its video and computing its statistics. `encode_episode` does that as LeRobot's
recording path does (``encode_video_frames`` with the run's codec, :func:`video_encoder`; ``compute_episode_stats``),
in the worker that ran the rollout, so one coordinator can append the episodes of many workers (see
``exporters/lerobot_writer.py``). The statistics are LeRobot's, computed for less (``exporters/lerobot_stats.py``).
What depends on the position (frame and episode indexes) is left to the coordinator.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from babblegen.config import RunConfig
from babblegen.dataset.schema import HEAD, OBJECT_CONTACTS, image_sources
from babblegen.exporters.lerobot_codecs import depth_encoder, encoder_options, video_encoder
from babblegen.exporters.lerobot_stats import image_stats, numeric_stats
from babblegen.world.rollout import Frames

DEFAULT_VIDEO_CODEC = RunConfig.video_codec  # each codec with LeRobot's own settings for it (`video_encoder`)
# Columns computed here; index, episode_index and task_index depend on the dataset and are added when written.
POSITION_COLUMNS = ("index", "episode_index", "task_index")


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
    if OBJECT_CONTACTS in features:  # a dataset written before the pairs' impulses were recorded has none
        recorded[OBJECT_CONTACTS] = frames.object_contacts
    for key in features:
        if key.startswith("observation.cam2world."):
            recorded[key] = frames.camera_poses[key.removeprefix("observation.cam2world.")].reshape(n, 16)
    columns = {k: np.asarray(v, dtype=features[k]["dtype"]) for k, v in recorded.items()}
    columns["timestamp"] = np.arange(n) / fps
    columns["frame_index"] = np.arange(n)
    return columns


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
            stream = output.add_stream(encoder.vcodec, fps, options=encoder_options(encoder))
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
