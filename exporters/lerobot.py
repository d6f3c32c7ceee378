"""The LeRobot sink: executed trajectories as LeRobot v3.0 episodes, appended in attempt order by the segment writer
(`exporters/lerobot_writer.py`), crash-safe.

Committed files are never written again. A commit records the exact set of data/video/episode files with their
sizes plus the bytes of the small meta files (`snapshot`); ``rollback()`` removes whatever came after the last
commit and restores those bytes, however the process ended. ``LeRobotDataset`` reads the result (tested against
datasets written by LeRobot's own ``save_episode``, ``exporters/lerobot_reference.py``); reading it back is
`babblegen.dataset.lerobot`'s.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from babblegen.dataset.schema import object_columns
from babblegen.exporters.lerobot_encoding import DEFAULT_VIDEO_CODEC, encode_episode
from babblegen.exporters.lerobot_writer import SEGMENT_TMP, SegmentWriter
from babblegen.store import AttemptRecord, Sink, atomic_write

ROLLED_META = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet")
TRACKED_DIRS = ("data", "videos", "meta/episodes")


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
