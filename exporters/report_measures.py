"""The numbers of a run's report, from its sidecar table (DIR/babblegen/attempts.jsonl) and the task in run.json:
`Run` (the table as read), `summarize` (one run's summary), `diversity` (the dataset measures) and `compare`.

A contact is an executed movement in which the arm touched at least one object (the paper's count); per
object, an executed movement in which the arm touched that object. An object contact is an executed movement with
a contact event between two objects (one pushed into another; `babblegen.contact_events`), recorded by the world.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.contact_events import had_object_contact
from babblegen.dataset.paths import CLONES
from babblegen.dataset.sidecar import read_attempts, read_run_info

from .geometry import table_top
from .rerun.scene import SLOT_COLORS

CELL = 0.02  # metres: the grid of the spread measure
ON_TABLE = 0.05  # metres: a moved object whose centre ends no lower than this under the table top stayed on it
OUT_OF_SCENE = -0.1  # metres: an object whose centre ends this far under the floor's top fell past its edge
OUTCOME_GRID = 0.01  # metres: two outcomes differ when some object's final xy falls in another 1 cm cell


class Run:
    """A dataset's sidecar table and task, as the report reads them."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.info = read_run_info(self.root)
        self.rows = read_attempts(self.root)
        self.task = self.info["task"]
        self.object_names: list[str] = [o["name"] for o in self.task["objects"]]
        if self.drawn:  # the task's objects are the slots' gray stand-ins: each slot gets a colour of its own
            self.colors = {n: _slot_color(i) for i, n in enumerate(self.object_names)}
        else:
            self.colors = {o["name"]: tuple(o["color"][:3]) for o in self.task["objects"]}
        self.executed = [r for r in self.rows if r.get("feasible")]
        self.clones = read_attempts(self.root, CLONES)

    @property
    def explorer(self) -> str:
        return str(self.info.get("config", {}).get("explorer") or (self.rows[0]["explorer"] if self.rows else "?"))

    @property
    def starts(self) -> str:
        """How the run drew its starts (run.json's ``world.starts``; "fixed" for runs made before starts varied)."""
        return str((self.info.get("config", {}).get("world") or {}).get("starts") or "fixed")

    @property
    def objects(self) -> str:
        """Which objects stood on the table (run.json's ``world.objects``): ``paper``, the task's own every episode
        (also for runs made before objects were drawn), or ``varied`` / ``heldout``, drawn per start."""
        return str((self.info.get("config", {}).get("world") or {}).get("objects") or "paper")

    @property
    def drawn(self) -> bool:
        """Whether each start drew its own objects (the task then holds stand-ins for the slots)."""
        return self.objects != "paper"

    @property
    def table_top(self) -> float:
        """The table top's height (m), from the task's table box."""
        return table_top(self.task)

    @property
    def has_start_poses(self) -> bool:
        return any(r.get("start_poses") for r in self.executed)

    @property
    def label(self) -> str:
        name = {"noveb": "NovEB", "random": "random babbling"}.get(self.explorer, self.explorer)
        return f"{name} ({self.root.name})"

    def touched(self, row: dict[str, Any], name: str | None = None) -> bool:
        t = row.get("touched") or {}
        return bool(t.get(name)) if name is not None else any(bool(v) for v in t.values())


def _slot_color(i: int) -> tuple[float, float, float]:
    """A slot's colour in a run that draws its objects: the one the Rerun recordings give it."""
    return tuple(c / 255 for c in SLOT_COLORS[i % len(SLOT_COLORS)][:3])  # type: ignore[return-value]


def shape_contacts(run: Run) -> dict[str, dict[str, int]] | None:
    """In a run that draws its objects: per shape, how many objects of it executed movements started with
    (``objects``) and how many of those the arm touched (``touched``); None for the paper's objects."""
    if not run.drawn:
        return None
    out: dict[str, dict[str, int]] = {}
    for r in run.executed:
        for o in r.get("objects") or []:
            counts = out.setdefault(o["shape"], {"objects": 0, "touched": 0})
            counts["objects"] += 1
            counts["touched"] += int(run.touched(r, o["name"]))
    return dict(sorted(out.items()))


# --- numbers -------------------------------------------------------------------------------------------------
def _spread(points: list[list[float]]) -> dict[str, Any]:
    if not points:
        return {"cells": 0, "std_x": None, "std_y": None}
    xy = np.asarray(points, dtype=np.float64)[:, :2]
    cells = {(math.floor(x / CELL), math.floor(y / CELL)) for x, y in xy}
    return {"cells": len(cells), "std_x": float(xy[:, 0].std()), "std_y": float(xy[:, 1].std())}


BATCH_KEYS = ("wait_for_batch", "evaluate_batch")  # per-generation timings, repeated on each of its rows


def _wall_time(rows: list[dict[str, Any]]) -> float:
    """Seconds of the generation loop, estimated from the timings: per generation, the time spent waiting for
    its batch of rollouts (counted once), plus describing and writing each attempt. Rows without a batch
    timing count their own rollout time."""
    total, seen = 0.0, set()
    for r in rows:
        t = r.get("timings") or {}
        key = next((k for k in BATCH_KEYS if k in t), None)
        if key is None:
            total += float(t.get("total", 0.0))
        elif r.get("generation") not in seen:
            seen.add(r.get("generation"))
            total += float(t[key])
        total += float(t.get("descriptor", 0.0)) + float(t.get("write", 0.0))
    return total


def _worker_seconds(row: dict[str, Any]) -> float:
    """A worker's seconds on an attempt: the movement as returned (``total``) and the episode's work after it
    (``prepare``: encoding, and the rendering a worker process defers)."""
    t = row.get("timings") or {}
    return float(t.get("total", 0.0)) + float(t.get("prepare", 0.0))


def _genome_key(row: dict[str, Any]) -> str:
    return f"{row.get('kind', '')}:{json.dumps(row.get('genome'))}"


def _episode_key(row: dict[str, Any]) -> str:
    """The same movement from the same start (a varied start's layout; fixed starts are all one)."""
    return f"{_genome_key(row)}@{json.dumps((row.get('start') or {}).get('layout'))}"


def _cell(v: float) -> int:
    return math.floor(v / CELL)


def diversity(rows: list[dict[str, Any]], object_names: list[str]) -> dict[str, Any]:
    """How many distinct interactions a run's rows hold, the measures a dataset is worth judging by.

    ``duplicate_episodes``: executed rows whose genome was executed before from the same start.
    ``touching_genomes``: distinct genomes whose movement touched any object (per object in
    ``touching_genomes_per_object``). ``moved_cells``: distinct (object, 2 cm cell) pairs of the final positions of
    objects displaced by more than 1 cm. ``changes``: distinct (object, 2 cm cell of its displacement from the
    episode's own start) pairs of those objects. ``start_layouts``: distinct start layouts (every object's start
    xy on a 2 cm grid).
    ``novelty_positive_share``: executed rows with novelty > 0. ``distinct_outcomes``: distinct final layouts
    (every object's final xy on a 1 cm grid), beside ``distinct_descriptors``, how many the descriptor told apart.
    """
    executed = [r for r in rows if r.get("feasible")]
    seen: set[str] = set()
    duplicates = 0
    touching: dict[str, set[str]] = {name: set() for name in object_names}
    cells: dict[str, set[tuple[int, int]]] = {name: set() for name in object_names}
    episodes: set[str] = set()
    changes: set[tuple[str, int, int]] = set()
    layouts: set[tuple[int, ...]] = set()
    for r in executed:
        key = _genome_key(r)
        duplicates += _episode_key(r) in episodes
        episodes.add(_episode_key(r))
        seen.add(key)
        touched = r.get("touched") or {}
        displacement = r.get("displacement") or {}
        final = r.get("final_poses") or {}
        start = r.get("start_poses") or {}
        if set(object_names) <= set(start):
            layouts.add(tuple(_cell(v) for name in object_names for v in start[name][:2]))
        for name in object_names:
            if touched.get(name):
                touching[name].add(key)
            if float(displacement.get(name, 0.0)) > CELL / 2 and name in final:
                x, y = final[name][:2]
                cells[name].add((_cell(x), _cell(y)))
                if name in start:
                    changes.add((name, _cell(x - start[name][0]), _cell(y - start[name][1])))
    positive = sum(float(r.get("novelty") or 0.0) > 0 for r in executed)
    outcomes = {
        tuple(math.floor(v / OUTCOME_GRID) for name in object_names for v in r["final_poses"][name][:2])
        for r in executed
        if set(object_names) <= set(r.get("final_poses") or {})
    }
    descriptors = {r["descriptor"] for r in executed if r.get("descriptor")}
    return {
        "distinct_genomes_executed": len(seen),
        "duplicate_episodes": duplicates,
        "touching_genomes": len(set().union(*touching.values())),
        "touching_genomes_per_object": {name: len(v) for name, v in touching.items()},
        "moved_cells": sum(len(v) for v in cells.values()),
        "moved_cells_per_object": {name: len(v) for name, v in cells.items()},
        "changes": len(changes) if layouts else None,
        "start_layouts": len(layouts) if layouts else None,
        "novelty_positive_share": positive / len(executed) if executed else None,
        "distinct_outcomes": len(outcomes),
        "distinct_descriptors": len(descriptors) if descriptors else None,
    }


def moved_object_ends(rows: list[dict[str, Any]], object_names: list[str], table_top: float) -> dict[str, Any]:
    """Where the objects displaced by more than 1 cm end, per executed row: on the table (``moved_on_table``), under
    it on the floor (``moved_on_floor``), or past the floor's edge, out of the scene (``moved_out_of_scene``; the
    floor reaches ``babblegen.scene.FLOOR_HALF_EXTENT`` each way). ``moved_cells_on_table``: distinct (object, 2 cm
    cell) pairs of the final positions of those that stayed on the table. ``episodes_losing_an_object``: executed
    rows in which some object ends out of the scene."""
    ends = {"moved_on_table": 0, "moved_on_floor": 0, "moved_out_of_scene": 0}
    cells: set[tuple[str, int, int]] = set()
    losing = 0
    for r in rows:
        if not r.get("feasible"):
            continue
        displacement, final = r.get("displacement") or {}, r.get("final_poses") or {}
        losing += any(final[name][2] < OUT_OF_SCENE for name in object_names if name in final)
        for name in object_names:
            if float(displacement.get(name, 0.0)) <= CELL / 2 or name not in final:
                continue
            x, y, z = final[name][:3]
            if z >= table_top - ON_TABLE:
                ends["moved_on_table"] += 1
                cells.add((name, _cell(x), _cell(y)))
            elif z < OUT_OF_SCENE:
                ends["moved_out_of_scene"] += 1
            else:
                ends["moved_on_floor"] += 1
    return {**ends, "moved_cells_on_table": len(cells), "episodes_losing_an_object": losing}


def object_contacts(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The executed rows' recorded contact events: ``object_contact_episodes``, those with a contact event between
    two objects (one object pushing another), and ``contact_events_per_pair``, per pair (with the table or the
    floor too) the episodes in which its contact began. None for runs made before contact events were recorded."""
    recorded = [r for r in rows if r.get("feasible") and had_object_contact(r) is not None]
    if not recorded:
        return {"object_contact_episodes": None, "contact_events_per_pair": None}
    pairs = Counter(name for r in recorded for name in r["object_contacts"])
    return {
        "object_contact_episodes": sum(bool(had_object_contact(r)) for r in recorded),
        "contact_events_per_pair": dict(sorted(pairs.items())),
    }


def summarize(run: Run) -> dict[str, Any]:
    """The summary numbers of one run."""
    rows, executed = run.rows, run.executed
    n, e = len(rows), len(executed)
    contacts = sum(run.touched(r) for r in executed)
    per_object = {name: sum(run.touched(r, name) for r in executed) for name in run.object_names}
    moved = {
        name: sum(float((r.get("displacement") or {}).get(name, 0.0)) > CELL / 2 for r in executed)
        for name in run.object_names
    }
    spread = {
        name: _spread([r["final_poses"][name] for r in executed if name in (r.get("final_poses") or {})])
        for name in run.object_names
    }
    tool = _spread([r["final_ee_pos"] for r in executed if r.get("final_ee_pos")])
    reasons = Counter(r.get("reason") or "unknown" for r in rows if not r.get("feasible"))
    return {
        "dataset": str(run.root),
        "explorer": run.explorer,
        "starts": run.starts,
        "objects": run.objects,
        "num_objects": len(run.object_names),
        "contacts_per_shape": shape_contacts(run),
        "attempts": n,
        "executed": e,
        "generations": len({r.get("generation") for r in rows}),
        "feasible_fraction": e / n if n else None,
        "contacts": contacts,
        "contacts_per_object": per_object,
        "contacts_per_attempt": contacts / n if n else None,
        "contacts_per_executed": contacts / e if e else None,
        "moved_per_object": moved,
        "final_object_spread": spread,
        "final_tool_spread": tool,
        "archive": sum(bool(r.get("archived")) for r in rows),
        "wall_time_s": _wall_time(rows),
        "worker_time_s": sum(_worker_seconds(r) for r in rows),  # all workers
        "infeasible_reasons": dict(sorted(reasons.items(), key=lambda kv: -kv[1])),
        "clones": len(run.clones),
        **object_contacts(executed),
        **diversity(rows, run.object_names),
        **moved_object_ends(rows, run.object_names, run.table_top),
    }


def _ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or not b else a / b


def compare(this: dict[str, Any], other: dict[str, Any]) -> dict[str, Any]:
    """How this run's contacts relate to the comparison run's (None where the comparison has none)."""
    return {
        "contact_ratio": _ratio(this["contacts"], other["contacts"]),
        "contact_rate_ratio": _ratio(this["contacts_per_attempt"], other["contacts_per_attempt"]),
        "touching_genomes_ratio": _ratio(this.get("touching_genomes"), other.get("touching_genomes")),
        "moved_cells_ratio": _ratio(this.get("moved_cells"), other.get("moved_cells")),
        "moved_cells_on_table_ratio": _ratio(this.get("moved_cells_on_table"), other.get("moved_cells_on_table")),
        "contact_ratio_per_object": {
            k: _ratio(v, other["contacts_per_object"].get(k)) for k, v in this["contacts_per_object"].items()
        },
    }
