"""`RerunSink`: the run's recording, written to DIR/babblegen/rerun/ as one .rrd per commit segment."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import uuid
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from babblegen.dataset.paths import ATTEMPTS, recordings_dir, sidecar_dir
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.interrupts import Interrupted
from babblegen.store import AttemptRecord, Sink, atomic_write

from .attempts import AttemptColumns, Tally
from .columns import MAX_BUFFERED_FRAMES, EpisodeColumns, EpisodeData
from .layout import blueprint, new_recording
from .scene import Scene, log_scene, objects_drawn

if TYPE_CHECKING:
    import rerun as rr

INDEX = "index.json"
SEGMENT = "segment-{:05d}.rrd"
FLUSH_TIMEOUT_S = 30.0  # a segment's flush takes well under a second; only a stuck writer (a full disk) takes this long


def _guarded(method: Callable) -> Callable:
    """Run a sink method; on any error warn once and disable the sink (an interruption still propagates)."""

    @functools.wraps(method)
    def wrapper(self: RerunSink, *args: Any, **kwargs: Any) -> Any:
        if not self.enabled:
            return None
        try:
            return method(self, *args, **kwargs)
        except Exception as e:
            if isinstance(e, Interrupted):
                raise
            self._disable(e)
            return None

    return wrapper


class RerunSink(Sink):
    """Writes a run's Rerun recording to DIR/babblegen/rerun/, one `segment-NNNNN.rrd` per commit segment.

    A segment is opened at the first attempt after a commit point and closed at the next one (`flush`), so a
    crash can only damage the segment in progress. `index.json` lists the closed segments with the number of
    attempts, episodes and frames logged up to their end; `rollback` keeps the segments covered by the last
    commit and deletes the rest. Any error disables the sink with one warning; the run goes on. Its committed
    state is the number of attempts and episodes recorded; building it from that state rolls back to it.
    """

    name = "rerun"

    def __init__(
        self,
        out_dir: Path,
        task: Any,
        joint_names: list[str],
        state: dict[str, int] | None = None,
        frames: str = "all",
    ) -> None:
        # the sink reports its own failures in one warning; the SDK's Rust logger would repeat them (a full disk
        # gives three ERROR lines). RUST_LOG set by the user still wins.
        os.environ.setdefault("RUST_LOG", "off")
        self.out = Path(out_dir)
        self.dir = recordings_dir(self.out)
        self.task = task if isinstance(task, dict) else task.to_dict()
        self.joint_names = list(joint_names)
        self.enabled = True
        self.frames = frames  # each episode's frames logged: "all", or "ends" (`EpisodeColumns`)
        self.scene: Scene | None = None
        self.columns: AttemptColumns | None = None
        self.episodes: EpisodeColumns | None = None
        self._tally = Tally([o["name"] for o in self.task["objects"]])
        self._index: dict[str, Any] | None = None
        self._rec: rr.RecordingStream | None = None
        self._segment: Path | None = None
        self._in_progress = False
        self._fps = 10.0
        self._image_size: tuple[int, int] | None = None
        self._cameras: list[dict[str, Any]] = []  # the run's cameras (run.json), for their frustums
        if state is not None:
            self.rollback(state["episodes"], state.get("attempts"))

    # --- the sink protocol ----------------------------------------------------------------------------------
    def write(self, record: AttemptRecord) -> None:
        self.log(record.row, record.rollout)

    def commit(self, counters: dict[str, int], final: bool = False) -> dict[str, int]:
        self.flush()
        return {"attempts": counters["attempts"], "episodes": counters["executed"]}

    # --- hooks called by the run loop ---------------------------------------------------------------------
    @_guarded
    def log(self, row: dict[str, Any], rollout: Any) -> None:
        """Log one attempt (and its episode when it was executed)."""
        self._open()
        self._in_progress = True
        frames = getattr(rollout, "frames", None)
        if frames is not None and row.get("episode_index") is not None:
            prepared = getattr(rollout, "prepared", {}).get(self.name)  # frames encoded by a worker
            if isinstance(prepared, dict):
                images, views = None, prepared
            else:  # JPEGs of the head camera alone (or nothing prepared)
                images, views = (prepared if prepared is not None else frames.images), frames.views
            ep = EpisodeData(
                episode_index=int(row["episode_index"]),
                state=frames.state,
                ee_pos=frames.ee_pos,
                object_poses=frames.object_poses,
                contacts=frames.contacts,
                images=images,
                views=views,
                fps=self._fps,
                start_index=self.columns.tally.frames,
                attempt=int(row["attempt"]),
                ee_targets=rollout.ee_targets,
                objects=row.get("objects"),
            )
            self.episodes.add(ep)
        self.columns.add(row)
        if self.episodes.n_frames >= MAX_BUFFERED_FRAMES:
            self.episodes.send(self._rec)
        self._in_progress = False

    @_guarded
    def flush(self) -> None:
        """Commit point: close the segment in progress and record it in the index."""
        self._close_segment()

    @_guarded
    def rollback(self, executed_episodes: int, attempts: int | None = None) -> None:
        """Resume: keep the segments covered by the last commit, delete the others. The sidecar table's first
        ``attempts`` rows (all by default) are the committed attempts."""
        rows = read_attempts(self.out) if (sidecar_dir(self.out) / ATTEMPTS).exists() else []
        rows = rows[:attempts] if attempts is not None else rows
        index = self._load_index()
        kept = []
        for seg in index["segments"]:
            if seg["attempts_end"] > len(rows) or seg["episodes_end"] > executed_episodes:
                break
            kept.append(seg)
        keep_files = {seg["file"] for seg in kept}
        if self.dir.exists():
            for p in self.dir.iterdir():
                if p.name != INDEX and p.name not in keep_files and (p.suffix in (".rrd", ".tmp")):
                    p.unlink()
        index["segments"] = kept
        self._write_index()
        self._tally = Tally.from_rows(rows, self._tally.object_names)
        if self.columns is not None:
            self.columns = AttemptColumns(self.scene, self._tally)

    def close(self) -> None:
        """End of the run (or of an interrupted one): close and index the segment in progress."""
        if self.enabled:
            self.flush()

    # --- internals ----------------------------------------------------------------------------------------
    def _disable(self, error: BaseException) -> None:
        self.enabled = False
        warnings.warn(
            f"Rerun recording stopped after an error ({type(error).__name__}: {error}); the run goes on without it",
            RuntimeWarning,
            stacklevel=3,
        )
        if self._rec is not None:
            if _writer_stuck(error):
                _ABANDONED.append(self._rec)
            else:
                with contextlib.suppress(Exception):  # already reporting an error
                    self._rec.disconnect()
            self._rec = None

    def _load_index(self) -> dict[str, Any]:
        if self._index is None:
            path = self.dir / INDEX
            if path.exists():
                self._index = json.loads(path.read_text())
            else:
                self._index = {"recording_id": str(uuid.uuid4()), "segments": []}
        return self._index

    def _write_index(self) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        atomic_write(self.dir / INDEX, json.dumps(self._load_index(), indent=1).encode())

    def _open(self) -> None:
        if self._rec is not None:
            return
        if self.scene is None:
            info = read_run_info(self.out)
            self.scene = Scene(self.task, self.joint_names, drawn=objects_drawn(info))
            world = info.get("config", {}).get("world", {})
            self._fps = float(world.get("fps", self._fps))
            if "camera_height" in world:
                self._image_size = (int(world["camera_height"]), int(world["camera_width"]))
            self._cameras = list(world.get("cameras") or [])
            self.columns = AttemptColumns(self.scene, self._tally)
            # a resumed run's recording may hold episodes already (`EpisodeColumns`'s ``fresh``)
            self.episodes = EpisodeColumns(self.scene, self.frames, fresh=not self._load_index()["segments"])
        index = self._load_index()
        self.dir.mkdir(parents=True, exist_ok=True)
        numbers = [int(p.stem.split("-")[1]) for p in self.dir.glob("segment-*.rrd")]
        numbers += [int(Path(s["file"]).stem.split("-")[1]) for s in index["segments"]]
        self._segment = self.dir / SEGMENT.format(max(numbers, default=-1) + 1)
        rec = new_recording(index["recording_id"])
        rec.save(self._segment, default_blueprint=blueprint(cameras=self._cameras))
        self._rec = rec
        log_scene(rec, self.scene, self._image_size, self._cameras)

    def _close_segment(self) -> None:
        if self._rec is None:
            return
        rec, self._rec = self._rec, None
        try:
            self.episodes.send(rec)
            self.columns.send(rec)
            # bounded: on a full disk the SDK's file writer can stop without the flush ever returning (seen with
            # rerun-sdk 0.41); a timeout raises, and the sink is disabled like for any other error
            rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
            rec.disconnect()
        except Exception as e:
            if _writer_stuck(e):
                _ABANDONED.append(rec)
            else:
                self._rec = rec  # `_disable` closes it
            raise
        tally = self.columns.tally
        self._load_index()["segments"].append(
            {
                "file": self._segment.name,
                "attempts_end": tally.attempts + int(self._in_progress),
                "episodes_end": tally.episodes + int(self._in_progress),
                "frames_end": tally.frames,
            }
        )
        self._write_index()
        self._in_progress = False


# Recording streams whose file writer failed (a full disk): dropping one makes the SDK wait for that writer,
# forever (rerun-sdk 0.41: `RecordingStream.__del__` hung the run), so they are kept until the process exits.
_ABANDONED: list[Any] = []


def _writer_stuck(error: BaseException) -> bool:
    """Whether ``error`` says the recording's file writer is gone or stuck (a full disk, a flush that timed out)."""
    text = str(error)
    return (
        isinstance(error, OSError)
        or "No space left" in text
        or "File-writer" in text
        or "timeout" in text.lower()
        or "timed out" in text.lower()
    )


def recording_files(root: str | Path) -> list[Path]:
    """The run's committed recording segments, in order."""
    d = recordings_dir(root)
    path = d / INDEX
    if not path.exists():
        return []
    return [d / s["file"] for s in json.loads(path.read_text())["segments"] if (d / s["file"]).exists()]
