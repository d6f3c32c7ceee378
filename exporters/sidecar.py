"""Writing the sidecar beside LeRobot's meta/: one JSON line per attempted movement, infeasible ones included.

Append-only and flushed per row, so it survives a crash up to the last complete line; the run's commit
record stores the byte offset it agrees with, and resume truncates to it. Fields are documented in
docs/dataset.md ("The sidecar table"); `babblegen.dataset.sidecar` reads them back.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.contact_events import contact_events
from babblegen.dataset.paths import ATTEMPTS, CLONES, sidecar_dir
from babblegen.store import AttemptRecord, Sink


class AttemptLog:
    """Append-only JSON-lines table of attempts."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "ab")  # noqa: SIM115  (kept open for the whole run)

    def append(self, row: dict[str, Any]) -> None:
        self._f.write(json.dumps(row, separators=(",", ":")).encode() + b"\n")
        self._f.flush()

    def offset(self) -> int:
        """Byte length of the complete rows written so far (synced to disk)."""
        self._f.flush()
        os.fsync(self._f.fileno())
        return self._f.tell()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    @staticmethod
    def truncate(path: Path, offset: int) -> None:
        with open(path, "a+b") as f:
            f.truncate(offset)


class SidecarSink(Sink):
    """``attempts.jsonl`` and ``clones.jsonl``; its committed state is their byte lengths, and building it
    from that state truncates whatever a crash left after them."""

    name = "sidecar"

    def __init__(self, state: dict[str, int] | None, root: str | Path):
        sdir = sidecar_dir(root)
        if state is not None:
            AttemptLog.truncate(sdir / ATTEMPTS, state["attempts"])
            AttemptLog.truncate(sdir / CLONES, state.get("clones", 0))
        self.attempts = AttemptLog(sdir / ATTEMPTS)
        self.clones = AttemptLog(sdir / CLONES)

    def write(self, record: AttemptRecord) -> None:
        record.row["timings"]["written_at"] = round(time.time(), 3)  # after its episode went to the dataset
        self.attempts.append(record.row)

    def write_clones(self, rows: list[dict[str, Any]]) -> None:
        for row in rows:
            self.clones.append(row)

    def commit(self, counters: dict[str, int], final: bool = False) -> dict[str, int]:
        return {"attempts": self.attempts.offset(), "clones": self.clones.offset()}

    def close(self) -> None:
        self.attempts.close()
        self.clones.close()


def attempt_row(
    cand: Any,
    rollout: Any,
    descriptor_hex: str | None,
    evaluation: Any,
    episode: int | None,
    explorer: str,
    task: Any,
) -> dict[str, Any]:
    """The sidecar row of one attempted movement (fields documented in docs/dataset.md, "The sidecar table");
    ``task`` is the run's (`babblegen.assembly.build_task`)."""
    object_names = task.object_names
    row: dict[str, Any] = {
        "attempt": cand.index,
        "generation": cand.generation,
        "explorer": explorer,
        "kind": cand.kind,
        "genome": np.asarray(cand.genome).tolist(),
        "parent": cand.parent,
        "feasible": rollout.feasible,
        "reason": rollout.reason,
        "episode_index": episode,
        "descriptor": descriptor_hex,
        "novelty": evaluation.novelty,
        "archived": evaluation.archived,
        "ee_targets": None if rollout.ee_targets is None else np.round(rollout.ee_targets, 5).tolist(),
        "planner": rollout.planner,
        "start": start_entry(cand),
        "objects": start_objects(cand, task),
    }
    if rollout.feasible:
        names = object_names
        contact_frames = rollout.frames.contacts.sum(axis=0)
        row.update(
            n_frames=len(rollout.frames),
            touched={n: bool(t) for n, t in zip(names, rollout.touched, strict=True)},
            contact_frames={n: int(c) for n, c in zip(names, contact_frames, strict=True)},
            start_poses=dict(zip(names, recorded_poses(rollout.start_poses), strict=True)),
            displacement={n: round(float(d), 6) for n, d in zip(names, rollout.displacement, strict=True)},
            final_poses=dict(zip(names, recorded_poses(rollout.final_poses), strict=True)),
            final_ee_pos=_final_tool_point(rollout),
        )
        if rollout.frames.object_contacts is not None:  # the pairs whose contact began during the episode
            row["object_contacts"] = contact_events(rollout.frames.object_contacts, names)
    return row


def start_objects(item: Any, task: Any) -> list[dict[str, Any]]:
    """The objects an attempt started with, one per slot, as factors of variation (`ObjectSpec.factors`): those its
    start drew, or the task's own."""
    start = item.start
    objects = task.objects if start is None or start.objects is None else start.objects
    return [o.factors() for o in objects]


def recorded_poses(poses: np.ndarray) -> list[list[float]]:
    """Object poses (n_objects, 7) as a row records them: rounded to 6 decimals in their own precision."""
    return np.round(np.asarray(poses), 6).tolist()


def start_entry(item: Any) -> dict[str, Any]:
    """Where an attempt (or clone) started: ``{"source": "task"}`` (the task's fixed scene), or a varied start:
    ``"drawn"`` whole for this attempt, ``"moved"`` (its parent's start with one object placed anew, for this
    attempt), ``"made"`` (the scene attempt ``made_from`` left, every object's pose in ``poses``) or
    ``"inherited"`` from its parent, with the attempt index it was drawn for (``drawn_at``) and its layout (x, y,
    yaw per object, before settling)."""
    start = item.start
    if start is None:
        return {"source": "task"}
    drawn = start.drawn_at == getattr(item, "index", None)
    entry = {
        "source": start.origin if drawn else "inherited",
        "drawn_at": start.drawn_at,
        "layout": np.asarray(start.layout).tolist(),
    }
    if start.poses is not None:  # a scene an earlier movement made: where it came from, and every object's pose
        entry.update(made_from=start.made_from, poses=np.asarray(start.poses).tolist())
    return entry


def _final_tool_point(rollout: Any) -> list[float]:
    """The tool position at the trajectory's final waypoint (the paper's Fig. 2 point)."""
    if rollout.ee_targets is not None:
        return np.round(rollout.ee_targets[-1], 5).tolist()
    ee = rollout.frames.ee_pos
    far = int(np.argmax(np.linalg.norm(ee - ee[0], axis=1)))
    return np.round(ee[far], 5).tolist()


def clone_row(clone: Any) -> dict[str, Any]:
    """The row of a child that reused an earlier attempt's outcome (``DIR/babblegen/clones.jsonl``)."""
    return {
        "generation": clone.generation,
        "kind": clone.kind,
        "genome": np.asarray(clone.genome).tolist(),
        "parent": clone.parent,
        "source": clone.source,
        "start": start_entry(clone),
        "novelty": clone.novelty,
        "survived": clone.survived,
    }
