"""Writing executed trajectories as LeRobot v3.0 episodes, segment by segment, at the speed of many workers.

Each episode arrives encoded (``exporters/lerobot_encoding.py``: video, per-frame columns and statistics made
with LeRobot's own code, in the worker that simulated it). The writer keeps the episodes of a *segment* in
memory and writes the segment at a commit point as new files, in LeRobot's layout: one data parquet, one video
made by concatenating the episodes' mp4s (LeRobot's ``concatenate_video_files``, no re-encoding), one
episode-metadata parquet, then ``info.json``, ``stats.json`` (LeRobot's ``aggregate_stats``) and
``tasks.parquet``. Per episode the coordinator does almost nothing; per segment it writes a few files, and never
writes a committed file again (`exporters/lerobot.py` rolls back what came after a commit). LeRobot loads inside
the methods that use it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from babblegen.dataset.lerobot import import_lerobot
from babblegen.dataset.schema import HEAD
from babblegen.exporters.lerobot_codecs import base_codec, feature_encoder
from babblegen.exporters.lerobot_encoding import DEFAULT_VIDEO_CODEC, EncodedEpisode
from babblegen.exporters.lerobot_stats import numeric_stats

SEGMENT_TMP = "tmp-segment-"  # the episodes' mp4s while a segment's video is made (removed by rollback)
MAX_SEGMENT_EPISODES = 2_000  # written early past this, so memory stays bounded whatever the commit interval


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
