"""LeRobot's own per-episode writer (``add_frame`` + ``save_episode``, its default settings but for the video
encoder's), kept as the reference.

babblegen writes its datasets with the segment writer in ``exporters/lerobot_writer.py``, which appends episodes
encoded in the workers. This module writes the same frames the way LeRobot's recording tools do; the tests
require both to give the same dataset, and ``benchmarks/bench_writer.py`` compares their cost.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from babblegen.dataset.lerobot import import_lerobot
from babblegen.dataset.schema import image_sources
from babblegen.exporters.lerobot_codecs import ENCODER_THREADS, depth_encoder, video_encoder
from babblegen.exporters.lerobot_encoding import DEFAULT_VIDEO_CODEC, camera_images
from babblegen.world.rollout import Frames


def _image_size(feats: dict) -> tuple[int, int]:
    """The height and width of the first video feature (LeRobot takes one depth encoder for every depth map)."""
    return next(tuple(ft["shape"][:2]) for ft in feats.values() if ft["dtype"] == "video")


class ReferenceWriter:
    """Appends episodes to a new LeRobot dataset at `root` through ``LeRobotDataset.save_episode``."""

    def __init__(self, root: Path, repo_id: str, dataset):
        self.root, self.repo_id, self.ds = Path(root), repo_id, dataset

    @classmethod
    def create(
        cls, root: Path, repo_id: str, fps: int, feats: dict, robot_type: str, codec: str = DEFAULT_VIDEO_CODEC
    ) -> ReferenceWriter:
        lerobot_dataset = import_lerobot()
        ds = lerobot_dataset.create(
            repo_id=repo_id,
            fps=fps,
            features=feats,
            root=root,
            robot_type=robot_type,
            use_videos=True,
            rgb_encoder=video_encoder(codec),
            depth_encoder=depth_encoder("fixed", *_image_size(feats)),
            encoder_threads=ENCODER_THREADS,
        )
        return cls(root, repo_id, ds)

    def add_episode(self, frames: Frames, task: str) -> int:
        """Write one executed trajectory; returns its episode index."""
        index = self.ds.meta.total_episodes
        n_obj = frames.object_poses.shape[1]
        env_state = frames.object_poses.reshape(len(frames), 7 * n_obj)
        images = {}
        for key, (camera, kind) in image_sources(self.ds.meta.features).items():
            got = camera_images(frames, camera, kind)
            images[key] = got if kind == "rgb" else got[..., None].astype(np.uint16)
        for t in range(len(frames)):
            self.ds.add_frame(
                {
                    **{key: value[t] for key, value in images.items()},
                    "observation.state": frames.state[t],
                    "action": frames.action[t],
                    "observation.ee_pos": frames.ee_pos[t],
                    "observation.environment_state": env_state[t],
                    "observation.contacts": frames.contacts[t],
                    "observation.object_contacts": frames.object_contacts[t],
                    "task": task,
                }
            )
        # LeRobot's SuppressProgressBars (used when it loads metadata) turns the `datasets` bars back on when it
        # exits, and save_episode would then print a "Map" bar per episode
        import datasets

        datasets.disable_progress_bars()
        self.ds.save_episode()
        return index

    def finalize(self) -> None:
        """Close every open file so the dataset loads (idempotent)."""
        if not getattr(self.ds, "_is_finalized", False):
            self.ds.finalize()
