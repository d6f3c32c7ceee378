"""Per-attempt scalars (novelty, archived, feasible, accumulated contacts) and the overview of final positions as
Rerun columns on the `attempt` timeline (executed attempts also on `episode_index` and `index`)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .scene import TOOL_COLOR, Scene

if TYPE_CHECKING:
    import rerun as rr


@dataclass
class Tally:
    """Running counts over attempt rows in order: where the next episode starts and accumulated contacts."""

    object_names: list[str]
    attempts: int = 0
    episodes: int = 0
    frames: int = 0
    contacts: int = 0
    per_object: dict[str, int] = field(default_factory=dict)

    def add(self, row: dict[str, Any]) -> None:
        self.attempts += 1
        if row.get("feasible"):
            self.episodes += 1
            self.frames += int(row.get("n_frames") or 0)
            touched = row.get("touched") or {}
            self.contacts += int(any(touched.values()))
            for name in self.object_names:
                self.per_object[name] = self.per_object.get(name, 0) + int(bool(touched.get(name)))

    @classmethod
    def from_rows(cls, rows: Iterable[dict[str, Any]], object_names: list[str]) -> Tally:
        tally = cls(list(object_names))
        for row in rows:
            tally.add(row)
        return tally


class AttemptColumns:
    """Buffers per-attempt scalars and overview points, sent to Rerun as columns in one go."""

    def __init__(self, scene: Scene, tally: Tally | None = None, static_overview: bool = False) -> None:
        self.scene = scene
        self.tally = tally or Tally(scene.object_names)
        self.static_overview = static_overview  # for a finished run: send() is called once with every row
        self._rows: list[dict[str, Any]] = []

    def __len__(self) -> int:
        return len(self._rows)

    def add(self, row: dict[str, Any]) -> None:
        start = self.tally.frames
        self.tally.add(row)
        executed = bool(row.get("feasible")) and row.get("episode_index") is not None
        self._rows.append(
            {
                "attempt": int(row["attempt"]),
                "feasible": float(bool(row.get("feasible"))),
                "archived": float(bool(row.get("archived"))),
                "novelty": np.nan if row.get("novelty") is None else float(row["novelty"]),
                "total": float(self.tally.contacts),
                "per_object": [float(self.tally.per_object.get(n, 0)) for n in self.scene.object_names],
                "episode": int(row["episode_index"]) if executed else -1,
                "last_index": start + max(int(row.get("n_frames") or 1), 1) - 1 if executed else -1,
                "final_ee": row.get("final_ee_pos") if executed else None,
                "final_poses": row.get("final_poses") if executed else None,
                "colors": self.scene.episode_colors(row.get("objects")),
            }
        )

    def send(self, rec: rr.RecordingStream) -> None:
        """Log the buffered rows and clear the buffer."""
        import rerun as rr

        if not self._rows:
            return
        rows, self._rows = self._rows, []
        for executed in (True, False):
            part = [r for r in rows if (r["episode"] >= 0) == executed]
            if not part:
                continue

            def indexes(sel: list[dict[str, Any]], executed: bool = executed) -> list[rr.TimeColumn]:
                idx = [rr.TimeColumn("attempt", sequence=[r["attempt"] for r in sel])]
                if executed:
                    idx.append(rr.TimeColumn("episode_index", sequence=[r["episode"] for r in sel]))
                    idx.append(rr.TimeColumn("index", sequence=[r["last_index"] for r in sel]))
                return idx

            idx = indexes(part)
            for key in ("feasible", "archived", "total"):
                path = "attempts/contacts/total" if key == "total" else f"attempts/{key}"
                rec.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=[r[key] for r in part]))
            n_obj = len(self.scene.object_names)
            rec.send_columns(
                "attempts/contacts/per_object",
                indexes=idx,
                columns=rr.Scalars.columns(scalars=np.ravel([r["per_object"] for r in part])).partition(
                    [n_obj] * len(part)
                ),
            )
            novel = [r for r in part if not np.isnan(r["novelty"])]
            if novel:
                rec.send_columns(
                    "attempts/novelty",
                    indexes=indexes(novel),
                    columns=rr.Scalars.columns(scalars=[r["novelty"] for r in novel]),
                )
            if executed:
                self._send_overview(rec, part, indexes)

    def _send_overview(
        self, rec: rr.RecordingStream, part: list[dict[str, Any]], indexes: Callable[[list], list]
    ) -> None:
        """Final tool and object positions: static when the whole run is known (all points on every timeline),
        else one point per attempt, accumulated by the overview view's visible time range."""
        import rerun as rr

        points = {"overview/final_tool": ([r for r in part if r["final_ee"] is not None], None)}
        for name in self.scene.object_names:
            points[f"overview/final_objects/{name}"] = ([r for r in part if name in (r["final_poses"] or {})], name)
        slot = {name: j for j, name in enumerate(self.scene.object_names)}
        for path, (sel, name) in points.items():
            if not sel:
                continue
            pos = [r["final_ee"] if name is None else r["final_poses"][name][:3] for r in sel]
            # each object in its own colour: the slot's, or in a run that draws them, the episode's
            colors = [TOOL_COLOR if name is None else r["colors"][slot[name]] for r in sel]
            if self.static_overview:
                rec.log(path, rr.Points3D(pos, colors=colors, radii=0.008), static=True)
            else:
                n = len(sel)
                cols = rr.Points3D.columns(positions=pos, colors=colors, radii=[0.008] * n)
                rec.send_columns(path, indexes=indexes(sel), columns=cols)
