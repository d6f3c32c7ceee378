"""Executed trajectories as LeRobot v3.0 episodes, appended in attempt order, crash-safe, at the speed of many
workers.

Each episode arrives encoded (``exporters/lerobot_encoding.py``: video, per-frame columns and statistics made
with LeRobot's own code, in the worker that simulated it). The writer keeps the episodes of a *segment* in
memory and writes the segment at a commit point as new files, in LeRobot's layout: one data parquet, one video
made by concatenating the episodes' mp4s (LeRobot's ``concatenate_video_files``, no re-encoding), one
episode-metadata parquet, then ``info.json``, ``stats.json`` (LeRobot's ``aggregate_stats``) and
``tasks.parquet``. Per episode the coordinator does almost nothing; per segment it writes a few files.

Crash safety: committed files are never written again. A commit records the exact set of data/video/episode
files with their sizes plus the bytes of the small meta files; ``rollback()`` removes whatever came after the
last commit and restores those bytes, however the process ended. ``LeRobotDataset`` reads the result
(tested against datasets written by LeRobot's own ``save_episode``, ``exporters/lerobot_reference.py``).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from babblegen.exporters.lerobot_codecs import base_codec, feature_encoder
from babblegen.exporters.lerobot_encoding import DEFAULT_VIDEO_CODEC, EncodedEpisode, encode_episode
from babblegen.exporters.lerobot_schema import HEAD, features
from babblegen.exporters.lerobot_stats import numeric_stats
from babblegen.store import AttemptRecord, Sink, atomic_write

__all__ = ["HEAD", "features"]  # the schema, re-exported for the sinks' users

ROLLED_META = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")
TRACKED_DIRS = ("data", "videos", "meta/episodes")
SEGMENT_TMP = "tmp-segment-"  # the episodes' mp4s while a segment's video is made (removed by rollback)
MAX_SEGMENT_EPISODES = 2_000  # written early past this, so memory stays bounded whatever the commit interval


def import_lerobot():
    """LeRobot, offline and quiet; returns ``LeRobotDataset``."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
    datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise
    return LeRobotDataset


class SegmentWriter:
    """Appends encoded episodes to the LeRobot dataset at ``root``; :meth:`flush` writes the pending ones.
    ``codec`` is the video codec the episodes are encoded with (one per dataset)."""

    def __init__(self, root: Path, meta, codec: str = DEFAULT_VIDEO_CODEC):
        from lerobot.configs.video import VIDEO_CODECS_ALIASES
        from lerobot.datasets.utils import update_chunk_file_indices

        self.root, self.meta, self.codec = Path(root), meta, codec
        recorded = (meta.features[HEAD].get("info") or {}).get("video.codec")
        if recorded is not None and VIDEO_CODECS_ALIASES.get(recorded, recorded) != base_codec(codec):
            raise ValueError(f"{root} holds {recorded} video; it cannot take episodes encoded with {codec}")
        self.pending: list[tuple[EncodedEpisode, str, dict]] = []
        self.total_frames = meta.total_frames
        last = None if meta.episodes is None or len(meta.episodes) == 0 else meta.episodes[-1]
        self.next_file: dict[str, tuple[int, int]] = {}
        # every video feature's segment files advance together: one index for all
        for kind, key in (("data", "data"), ("video", f"videos/{HEAD}"), ("episodes", "meta/episodes")):
            if last is None:
                self.next_file[kind] = (0, 0)
            else:  # committed files are never appended to: each segment starts new ones
                here = (int(last[f"{key}/chunk_index"]), int(last[f"{key}/file_index"]))
                self.next_file[kind] = update_chunk_file_indices(*here, meta.chunks_size)

    @classmethod
    def create(
        cls, root: Path, repo_id: str, fps: int, feats: dict, robot_type: str, codec: str = DEFAULT_VIDEO_CODEC
    ) -> SegmentWriter:
        import_lerobot()
        from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

        meta = LeRobotDatasetMetadata.create(repo_id, fps, feats, robot_type=robot_type, root=root, use_videos=True)
        return cls(root, meta, codec)

    @classmethod
    def reopen(cls, root: Path, repo_id: str, codec: str = DEFAULT_VIDEO_CODEC) -> SegmentWriter:
        import_lerobot()
        from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata

        return cls(root, LeRobotDatasetMetadata(repo_id, root=root), codec)

    @property
    def features(self) -> dict:
        return self.meta.features

    @property
    def num_episodes(self) -> int:
        return self.meta.total_episodes + len(self.pending)

    def add(self, episode: EncodedEpisode, task: str, columns: dict | None = None) -> int:
        """Queue one episode, with ``columns`` of its own for the episode table (`object_columns`); returns its
        episode index."""
        index = self.num_episodes
        self.pending.append((episode, task, columns or {}))
        if len(self.pending) >= MAX_SEGMENT_EPISODES:
            self.flush()
        return index

    def flush(self) -> None:
        """Write the pending episodes as one segment (new data, video and episode-metadata files)."""
        if not self.pending:
            return
        meta, episodes = self.meta, [e for e, _, _ in self.pending]
        tasks = [t for _, t, _ in self.pending]
        new_tasks = [t for t in dict.fromkeys(tasks) if meta.tasks is None or meta.get_task_index(t) is None]
        if new_tasks:
            meta.save_episode_tasks(new_tasks)
        first_episode, first_frame = meta.total_episodes, self.total_frames
        lengths = [len(e) for e in episodes]
        starts = first_frame + np.concatenate([[0], np.cumsum(lengths)[:-1]])
        positions = [
            {
                "index": np.arange(s, s + n),
                "episode_index": np.full(n, first_episode + i),
                "task_index": np.full(n, meta.get_task_index(t)),
            }
            for i, (s, n, t) in enumerate(zip(starts, lengths, tasks, strict=True))
        ]
        self._write_data(episodes, positions, self.next_file["data"])
        video_starts = self._write_video(episodes, self.next_file["video"])
        extra = [c for _, _, c in self.pending]
        stats = self._write_episode_table(episodes, tasks, positions, video_starts, extra)
        self._write_info_and_stats(episodes, stats, first_episode == 0)
        self.total_frames += sum(lengths)
        self.pending.clear()
        self._advance()

    def _write_episode_table(
        self,
        episodes: list[EncodedEpisode],
        tasks: list[str],
        positions: list[dict],
        video_starts: list[float],
        extra: list[dict],
    ) -> list[dict]:
        """The segment's rows of LeRobot's episode table (same columns, same order, then each episode's own
        ``extra`` columns); returns each episode's complete statistics."""
        from lerobot.datasets.utils import DEFAULT_EPISODES_PATH, flatten_dict

        (data_chunk, data_file), (video_chunk, video_file) = self.next_file["data"], self.next_file["video"]
        rows, all_stats = [], []
        for episode, task, pos, video_start, own in zip(episodes, tasks, positions, video_starts, extra, strict=True):
            # the dataset's own features: a run resumed from a dataset made before a feature existed leaves it out
            own_stats = {k: v for k, v in episode.stats.items() if k in self.meta.features}
            stats = {**own_stats, **numeric_stats(pos, self.meta.features)}
            all_stats.append(stats)
            row = {
                "episode_index": int(pos["episode_index"][0]),
                "tasks": [task],
                "length": len(episode),
                "data/chunk_index": data_chunk,
                "data/file_index": data_file,
                "dataset_from_index": int(pos["index"][0]),
                "dataset_to_index": int(pos["index"][-1]) + 1,
            }
            for key in self.meta.video_keys:
                row[f"videos/{key}/chunk_index"] = video_chunk
                row[f"videos/{key}/file_index"] = video_file
                row[f"videos/{key}/from_timestamp"] = video_start
                row[f"videos/{key}/to_timestamp"] = video_start + episode.duration_s
            row.update(flatten_dict({"stats": stats}))
            row["meta/episodes/chunk_index"], row["meta/episodes/file_index"] = self.next_file["episodes"]
            row.update(own)
            rows.append(row)
        chunk, file = self.next_file["episodes"]
        _write_parquet_rows(rows, self.root / DEFAULT_EPISODES_PATH.format(chunk_index=chunk, file_index=file))
        return all_stats

    def _write_data(self, episodes: list[EncodedEpisode], positions: list[dict], file: tuple[int, int]) -> None:
        import datasets
        import pyarrow.parquet as pq
        from lerobot.datasets.feature_utils import get_hf_features_from_features

        hf_features = get_hf_features_from_features(self.meta.features)
        columns = {}
        for key in hf_features:
            parts = [{**e.columns, **p}[key] for e, p in zip(episodes, positions, strict=True)]
            columns[key] = [v for part in parts for v in part] if isinstance(parts[0], list) else np.concatenate(parts)
        table = arrow_table(columns, hf_features)
        if table is None:  # a feature kind the direct path does not know: Hugging Face's encoder
            table = datasets.Dataset.from_dict(columns, features=hf_features, split="train").with_format("arrow")[:]
        path = self.root / self.meta.data_path.format(chunk_index=file[0], file_index=file[1])
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, path, compression="snappy", use_dictionary=True)

    def _write_video(self, episodes: list[EncodedEpisode], file: tuple[int, int]) -> list[float]:
        """One mp4 per video feature for the segment; returns each episode's start time in them."""
        from lerobot.datasets.video_utils import concatenate_video_files

        for key in self.meta.video_keys:
            path = self.root / self.meta.video_path.format(video_key=key, chunk_index=file[0], file_index=file[1])
            path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(prefix=SEGMENT_TMP, dir=self.root) as tmp:
                parts = []
                for i, e in enumerate(episodes):
                    parts.append(Path(tmp) / f"{i:06d}.mp4")
                    parts[-1].write_bytes(e.videos[key])
                concatenate_video_files(parts, path)
        durations = [e.duration_s for e in episodes]
        return [float(x) for x in np.concatenate([[0.0], np.cumsum(durations)[:-1]])]

    def _write_info_and_stats(self, episodes: list[EncodedEpisode], stats: list[dict], first: bool) -> None:
        from lerobot.datasets.compute_stats import aggregate_stats
        from lerobot.datasets.io_utils import write_info, write_stats

        meta = self.meta
        if first:  # video codec details, read from the first video files as LeRobot's writer does
            for key in meta.video_keys:
                meta.update_video_info(key, video_encoder=feature_encoder(meta.features[key], self.codec))
        meta.info.total_episodes += len(episodes)
        meta.info.total_frames += sum(len(e) for e in episodes)
        meta.info.total_tasks = len(meta.tasks)
        meta.info.splits = {"train": f"0:{meta.info.total_episodes}"}
        write_info(meta.info, meta.root)
        merged = aggregate_stats(([meta.stats] if meta.stats is not None else []) + stats)
        # in the schema's order: LeRobot's aggregate orders the features by a set, so stats.json's bytes varied
        # with each process's string hashing
        meta.stats = {key: merged[key] for key in dict.fromkeys([*meta.features, *merged]) if key in merged}
        write_stats(meta.stats, meta.root)

    def _advance(self) -> None:
        from lerobot.datasets.utils import update_chunk_file_indices

        for kind, here in self.next_file.items():
            self.next_file[kind] = update_chunk_file_indices(*here, self.meta.chunks_size)


def arrow_table(columns: dict[str, np.ndarray], hf_features):
    """The Arrow table ``datasets.Dataset.from_dict(columns, features=hf_features)`` makes, built from the numpy
    columns directly (Hugging Face's encoder walks every value in Python: 3 ms of a 5 ms episode write), and from
    image features given as lists of encoded images (PNG bytes, as Hugging Face stores them); ``None`` when a
    feature is none of these."""
    import datasets
    import pyarrow as pa

    schema = hf_features.arrow_schema
    arrays = []
    for key, feature in hf_features.items():
        if isinstance(feature, datasets.Image) and isinstance(columns[key], list):  # encoded images (PNG bytes)
            images = columns[key]
            arrays.append(
                pa.StructArray.from_arrays(
                    [pa.array(images, type=pa.binary()), pa.array([None] * len(images), type=pa.string())],
                    names=["bytes", "path"],
                )
            )
            continue
        values = np.asarray(columns[key])
        if isinstance(feature, datasets.Value):  # one value a frame (a feature of shape (1,): one object's contacts)
            values = values.reshape(len(values))
            arrays.append(pa.array(values.astype(feature.pa_type.to_pandas_dtype(), copy=False)))
        elif isinstance(feature, datasets.List) and isinstance(feature.feature, datasets.Value) and feature.length > 0:
            flat = values.reshape(len(values), feature.length).astype(feature.feature.pa_type.to_pandas_dtype())
            arrays.append(pa.FixedSizeListArray.from_arrays(pa.array(flat.ravel()), feature.length))
        else:
            return None
    return pa.Table.from_arrays(arrays, schema=schema)


def _write_parquet_rows(rows: list[dict], path: Path) -> None:
    """Episode-metadata rows as LeRobot's metadata writer stores them (numpy values as lists)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns = {k: [r[k].tolist() if isinstance(r[k], np.ndarray) else r[k] for r in rows] for k in rows[0]}
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pydict(columns), path, compression="snappy", use_dictionary=True)


class LeRobotSink(Sink):
    """The executed movements as LeRobot episodes (episode index = the row's ``episode_index``). Its committed
    state is the writer's commit record; building it from one rolls the dataset back to it."""

    name = "lerobot"

    def __init__(
        self,
        state: dict | None,
        root: Path,
        repo_id: str,
        task_text: str,
        create: dict | None = None,
        codec: str = DEFAULT_VIDEO_CODEC,
    ):
        self.root, self.task_text = Path(root), task_text
        if state is None:
            if self.root.exists() and not any(self.root.iterdir()):
                self.root.rmdir()  # LeRobot refuses an existing root, even an empty one
            self.writer = SegmentWriter.create(self.root, repo_id, **(create or {}), codec=codec)
        else:
            rollback(self.root, state)
            self.writer = SegmentWriter.reopen(self.root, repo_id, codec)

    def write(self, record: AttemptRecord) -> None:
        expected = record.row.get("episode_index")
        if expected is None:
            return
        t = time.perf_counter()
        encoded = getattr(record.rollout, "prepared", {}).get(self.name)
        if encoded is None:  # encoded here when no worker did
            writer = self.writer
            encoded = encode_episode(record.rollout.frames, writer.meta.fps, writer.features, writer.codec)
        index = self.writer.add(encoded, self.task_text, object_columns(record.row.get("objects") or []))
        record.row["timings"]["write"] = round(time.perf_counter() - t, 5)
        if index != expected:
            raise RuntimeError(f"the dataset holds {index} episodes where the run expected {expected}")

    def commit(self, counters: dict[str, int], final: bool = False) -> dict:
        self.writer.flush()
        return snapshot(self.root)

    def close(self) -> None:
        self.writer.flush()


FACTORS = ("shape", "size", "mass", "density", "static_friction", "dynamic_friction", "restitution", "color")


def object_columns(objects: list[dict]) -> dict:
    """An episode's objects (a sidecar row's ``objects``) as columns of the episode table:
    ``objects/<slot>/<factor>`` for every factor of `FACTORS` (a hull's points stay in the sidecar)."""
    return {f"objects/{o['name']}/{factor}": o[factor] for o in objects for factor in FACTORS}


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
    # a segment's temporary mp4s; temporary frames or streamed video left by LeRobot's own writer (datasets
    # made before segment writing)
    leftovers = [root / "images", *root.glob(f"{SEGMENT_TMP}*")] + [
        d for d in root.glob("tmp*") if d.is_dir() and all(f.name.endswith("_streaming.mp4") for f in d.iterdir())
    ]
    for d in leftovers:
        if d.is_dir():
            shutil.rmtree(d)
            removed.append(f"{d.name}/")
    return removed


def load_dataset(root: str | Path, repo_id: str = "local/babblegen", **kwargs):
    """Open a finished dataset for reading with LeRobot (offline); ``kwargs`` go to ``LeRobotDataset``
    (``depth_output_unit="m"``: depth maps in metres)."""
    return import_lerobot()(repo_id, root=Path(root), **kwargs)


def episode_frame_range(ds, episode_index: int) -> tuple[int, int]:
    ep = ds.meta.episodes[episode_index]
    return int(ep["dataset_from_index"]), int(ep["dataset_to_index"])


def to_uint8_image(chw: np.ndarray) -> np.ndarray:
    """LeRobot returns images as float CHW in [0, 1]; this gives HWC uint8."""
    arr = np.asarray(chw)
    return np.clip(np.round(arr.transpose(1, 2, 0) * 255), 0, 255).astype(np.uint8)
