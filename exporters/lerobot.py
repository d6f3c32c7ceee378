"""Executed trajectories as LeRobot v3.0 episodes, written with lerobot's own writer, crash-safe.

LeRobot keeps parquet footers open until `finalize()`, rewrites meta/info.json and meta/stats.json after every
episode, and grows one video file per chunk by concatenation. A process killed between two finalizes leaves
files no reader can open. So the writer works in *segments*: at each commit point it finalizes, records the
exact set of data/video/episode-meta files with their sizes plus a copy of the small meta files, and reopens
the dataset with `LeRobotDataset.resume`, which always starts new files. Committed files are never written
again; `rollback()` removes whatever came after the last commit, however the process ended. Per-episode save
cost stays flat because no file grows past one segment.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np

from babblegen.store import AttemptRecord, Sink, atomic_write
from babblegen.world.rollout import Frames

HEAD = "observation.images.head"
ROLLED_META = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")
TRACKED_DIRS = ("data", "videos", "meta/episodes")
# Frames go straight to an encoder thread (no PNG round trip, image stats computed while encoding): measured
# 290 -> 238 ms per 24-frame 128x128 episode. LeRobot drops frames when this queue is full, and an episode's
# frames arrive at once, so it holds any episode.
STREAMING = {"streaming_encoding": True, "encoder_queue_maxsize": 100_000}


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


def datasets_progress_bars_off() -> None:
    import datasets

    datasets.disable_progress_bars()


def _import_lerobot():
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
    datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise

    return LeRobotDataset


class EpisodeWriter:
    """Appends episodes to a LeRobot dataset at `root`, with commit points for crash-safe resume."""

    def __init__(self, root: Path, repo_id: str, dataset):
        self.root, self.repo_id, self.ds = Path(root), repo_id, dataset

    @classmethod
    def create(cls, root: Path, repo_id: str, fps: int, feats: dict, robot_type: str) -> EpisodeWriter:
        lerobot_dataset = _import_lerobot()
        ds = lerobot_dataset.create(
            repo_id=repo_id, fps=fps, features=feats, root=root, robot_type=robot_type, use_videos=True, **STREAMING
        )
        return cls(root, repo_id, ds)

    @classmethod
    def reopen(cls, root: Path, repo_id: str) -> EpisodeWriter:
        lerobot_dataset = _import_lerobot()
        return cls(root, repo_id, lerobot_dataset.resume(repo_id, root=root, **STREAMING))

    @property
    def num_episodes(self) -> int:
        return self.ds.meta.total_episodes

    def add_episode(self, frames: Frames, task: str) -> int:
        """Write one executed trajectory; returns its episode index."""
        index = self.ds.meta.total_episodes
        n_obj = frames.object_poses.shape[1]
        env_state = frames.object_poses.reshape(len(frames), 7 * n_obj)
        for t in range(len(frames)):
            self.ds.add_frame(
                {
                    HEAD: frames.images[t],
                    "observation.state": frames.state[t],
                    "action": frames.action[t],
                    "observation.ee_pos": frames.ee_pos[t],
                    "observation.environment_state": env_state[t],
                    "observation.contacts": frames.contacts[t],
                    "task": task,
                }
            )
        # LeRobot's SuppressProgressBars (used when it loads metadata) turns the `datasets` bars back on when it
        # exits, and save_episode would then print a "Map" bar per episode
        datasets_progress_bars_off()
        self.ds.save_episode()
        return index

    def finalize(self) -> None:
        """Close every open file so the dataset loads (idempotent)."""
        if not getattr(self.ds, "_is_finalized", False):
            self.ds.finalize()

    def commit(self) -> dict:
        """Finalize, describe the committed state, and reopen for appending. Returns the commit record."""
        self.finalize()
        record = snapshot(self.root)
        self.ds = _import_lerobot().resume(self.repo_id, root=self.root, **STREAMING)
        return record


class LeRobotSink(Sink):
    """The executed movements as LeRobot episodes (episode index = the row's ``episode_index``). Its committed
    state is the writer's commit record; building it from one rolls the dataset back to it."""

    name = "lerobot"

    def __init__(self, state: dict | None, root: Path, repo_id: str, task_text: str, create: dict | None = None):
        self.root, self.task_text = Path(root), task_text
        if state is None:
            if self.root.exists() and not any(self.root.iterdir()):
                self.root.rmdir()  # LeRobot refuses an existing root, even an empty one
            self.writer = EpisodeWriter.create(self.root, repo_id, **(create or {}))
        else:
            rollback(self.root, state)
            self.writer = EpisodeWriter.reopen(self.root, repo_id)

    def write(self, record: AttemptRecord) -> None:
        expected = record.row.get("episode_index")
        if expected is None:
            return
        t = time.perf_counter()
        index = self.writer.add_episode(record.rollout.frames, self.task_text)
        record.row["timings"]["write"] = round(time.perf_counter() - t, 5)
        if index != expected:
            raise RuntimeError(f"the dataset holds {index} episodes where the run expected {expected}")

    def commit(self, counters: dict[str, int], final: bool = False) -> dict:
        if final:
            self.writer.finalize()
            return snapshot(self.root)
        return self.writer.commit()

    def close(self) -> None:
        self.writer.finalize()


def snapshot(root: Path) -> dict:
    """Sizes of every tracked file and the bytes of the small meta files LeRobot rewrites in place."""
    files = {}
    for d in TRACKED_DIRS:
        base = root / d
        if base.exists():
            for p in sorted(base.rglob("*")):
                if p.is_file():
                    files[str(p.relative_to(root))] = p.stat().st_size
    meta = {name: (root / name).read_bytes() for name in ROLLED_META if (root / name).exists()}
    return {"files": files, "meta": meta}


def rollback(root: Path, record: dict) -> list[str]:
    """Restore the dataset at `root` to a commit record. Returns the paths it removed.

    Raises RuntimeError if a committed file is missing or changed size (the dataset was altered by something
    other than this writer, and silently continuing would corrupt it).
    """
    removed = []
    committed = record["files"]
    for d in TRACKED_DIRS:
        base = root / d
        if not base.exists():
            continue
        for p in sorted(base.rglob("*"), reverse=True):
            rel = str(p.relative_to(root))
            if p.is_file() and rel not in committed:
                p.unlink()
                removed.append(rel)
            elif p.is_dir() and not any(p.iterdir()):
                p.rmdir()
    for rel, size in committed.items():
        p = root / rel
        if not p.exists() or p.stat().st_size != size:
            raise RuntimeError(f"committed file {rel} is missing or changed; the dataset cannot be resumed safely")
    for name, data in record["meta"].items():
        atomic_write(root / name, data)
    for name in ROLLED_META:
        if name not in record["meta"] and (root / name).exists():
            (root / name).unlink()
            removed.append(name)
    # temporary frames or streamed video LeRobot kept for an episode that was never saved
    leftovers = [root / "images"] + [
        d for d in root.glob("tmp*") if d.is_dir() and all(f.name.endswith("_streaming.mp4") for f in d.iterdir())
    ]
    for d in leftovers:
        if d.is_dir():
            shutil.rmtree(d)
            removed.append(f"{d.name}/")
    return removed


def load_dataset(root: str | Path, repo_id: str = "local/babblegen"):
    """Open a finished dataset for reading with LeRobot (offline)."""
    return _import_lerobot()(repo_id, root=Path(root))


def episode_frame_range(ds, episode_index: int) -> tuple[int, int]:
    ep = ds.meta.episodes[episode_index]
    return int(ep["dataset_from_index"]), int(ep["dataset_to_index"])


def to_uint8_image(chw: np.ndarray) -> np.ndarray:
    """LeRobot returns images as float CHW in [0, 1]; this gives HWC uint8."""
    arr = np.asarray(chw)
    return np.clip(np.round(arr.transpose(1, 2, 0) * 255), 0, 255).astype(np.uint8)
