"""The NovEB paper's figures and a summary table for one run, optionally against a comparison run.

Every number comes from the sidecar table (DIR/babblegen/attempts.jsonl) and the task in run.json:
    fig2_final_tool_positions.png     final tool positions seen from above (Fig. 2)
    fig3_final_object_positions.png   final object positions seen from above, coloured by object (Fig. 3)
    fig4_accumulated_contacts.png     accumulated contacts vs attempted movements, both runs (Fig. 4)
    fig5_contacts_per_object.png      accumulated contacts per object vs executed movements (Fig. 5)
    start_object_positions.png        the objects' start positions (first frame) from above, drawn like Fig. 3;
                                      only for datasets whose rows record them (``start_poses``)
    summary.md, summary.json          the numbers

A contact is an executed movement in which the arm touched at least one object (the paper's count); per
object, an executed movement in which the arm touched that object.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from .sidecar import CLONES, read_attempts, read_run_info

CELL = 0.02  # metres: the grid of the spread measure
OUTCOME_GRID = 0.01  # metres: two outcomes differ when some object's final xy falls in another 1 cm cell
FIGURES = {
    "fig2": "fig2_final_tool_positions.png",
    "fig3": "fig3_final_object_positions.png",
    "fig4": "fig4_accumulated_contacts.png",
    "fig5": "fig5_contacts_per_object.png",
}
START_FIGURE = ("starts", "start_object_positions.png")  # written when the rows record their start poses
TOOL_GREEN = "#22aa33"
TABLE_BROWN = "#8c6647"


class Run:
    """A dataset's sidecar table and task, as the report reads them."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.info = read_run_info(self.root)
        self.rows = read_attempts(self.root)
        self.task = self.info["task"]
        self.object_names: list[str] = [o["name"] for o in self.task["objects"]]
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
    def has_start_poses(self) -> bool:
        return any(r.get("start_poses") for r in self.executed)

    @property
    def label(self) -> str:
        name = {"noveb": "NovEB", "random": "random babbling"}.get(self.explorer, self.explorer)
        return f"{name} ({self.root.name})"

    def touched(self, row: dict[str, Any], name: str | None = None) -> bool:
        t = row.get("touched") or {}
        return bool(t.get(name)) if name is not None else any(bool(v) for v in t.values())


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
        **diversity(rows, run.object_names),
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
        "contact_ratio_per_object": {
            k: _ratio(v, other["contacts_per_object"].get(k)) for k, v in this["contacts_per_object"].items()
        },
    }


# --- figures -------------------------------------------------------------------------------------------------
def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    return fig, axes


def _top_view_background(ax, run: Run) -> None:
    """Table (brown), robot (white box), static obstacles (gray) and the objects where they rest; x forward is
    up, the robot's left (+y) is on the left, as in the paper's views from above."""
    from matplotlib.patches import Circle, Polygon, Rectangle

    from .geometry import box_footprint, robot_footprint

    t = run.task["table"]
    (cx, cy, _), (hx, hy, _) = t["center"], t["half_extents"]
    ax.add_patch(
        Rectangle((cy - hy, cx - hx), 2 * hy, 2 * hx, facecolor=TABLE_BROWN, alpha=0.35, edgecolor=TABLE_BROWN)
    )
    try:
        foot = robot_footprint(run.task)
    except (OSError, ValueError):  # the robot's URDF is not installed: draw PR2's base
        foot = np.array([[-0.53, -0.33], [0.13, -0.33], [0.13, 0.33], [-0.53, 0.33]])
    (x0, y0), (x1, y1) = foot.min(axis=0), foot.max(axis=0)
    ax.add_patch(Rectangle((y0, x0), y1 - y0, x1 - x0, facecolor="white", edgecolor="black", lw=1.2, zorder=2))
    ax.text((y0 + y1) / 2, (x0 + x1) / 2, "robot", ha="center", va="center", fontsize=8, zorder=3)
    for box in run.task.get("extra_obstacles") or []:
        foot = box_footprint(box)
        ax.add_patch(Polygon(foot[:, ::-1], closed=True, facecolor="0.85", edgecolor="0.4", lw=1.0, zorder=1.5))
    for o in run.task["objects"]:
        (ox, oy), s, color = o["xy"], o["size"], o["color"][:3]
        if o["shape"] == "box":
            patch = Rectangle((oy - s[1], ox - s[0]), 2 * s[1], 2 * s[0], facecolor="none", edgecolor=color, lw=1.5)
        else:
            patch = Circle((oy, ox), s[0], facecolor="none", edgecolor=color, lw=1.5)
        ax.add_patch(patch)
    ax.set_aspect("equal")
    ax.set_xlabel("y (m, robot's left is left)")
    ax.set_ylabel("x (m, forward)")
    ax.invert_xaxis()
    ax.grid(True, lw=0.3, alpha=0.5)


def _set_top_view_limits(axes, runs: list[Run], points: list[np.ndarray]) -> None:
    """One frame for all panels: the table, the robot and every point."""
    xs, ys = [], []
    for run in runs:
        t = run.task["table"]
        (cx, cy, _), (hx, hy, _) = t["center"], t["half_extents"]
        xs += [cx - hx, cx + hx, -0.55]
        ys += [cy - hy, cy + hy]
    for p in points:
        if len(p):
            xs += [float(np.nanmin(p[:, 0])), float(np.nanmax(p[:, 0]))]
            ys += [float(np.nanmin(p[:, 1])), float(np.nanmax(p[:, 1]))]
    pad = 0.08
    for ax in axes:
        ax.set_ylim(min(xs) - pad, max(xs) + pad)
        ax.set_xlim(max(ys) + pad, min(ys) - pad)


def figure_final_tool(runs: list[Run], path: Path) -> Path:
    """Fig. 2: final tool positions from above, one panel per run."""
    fig, axes = _figure(1, len(runs), (5.2 * len(runs), 5.6))
    pts = []
    for ax, run in zip(axes, runs, strict=True):
        p = np.array([r["final_ee_pos"] for r in run.executed if r.get("final_ee_pos")], dtype=float).reshape(-1, 3)
        pts.append(p)
        _top_view_background(ax, run)
        ax.scatter(p[:, 1], p[:, 0], s=6, c=TOOL_GREEN, zorder=4, label="final tool position")
        ax.set_title(f"{run.label}: {len(p)} executed movements", fontsize=10)
        ax.legend(loc="upper right", fontsize=8)
    _set_top_view_limits(axes, runs, pts)
    fig.suptitle("Final tool positions, seen from above")
    fig.savefig(path, dpi=120)
    return path


def _figure_object_positions(runs: list[Run], path: Path, key: str, title: str) -> Path:
    """Object positions from the rows' ``key`` poses seen from above, coloured by object, one panel per run."""
    fig, axes = _figure(1, len(runs), (5.2 * len(runs), 5.6))
    pts = []
    for ax, run in zip(axes, runs, strict=True):
        _top_view_background(ax, run)
        for name in run.object_names:
            p = [r[key][name] for r in run.executed if name in (r.get(key) or {})]
            p = np.array(p, dtype=float).reshape(-1, 7)
            pts.append(p)
            ax.scatter(
                p[:, 1], p[:, 0], s=8, color=run.colors[name], edgecolors="0.25", linewidths=0.3, zorder=4, label=name
            )
        n, e = sum(bool(r.get(key)) for r in run.executed), len(run.executed)
        shown = f"{n} executed movements" if n == e else f"{n} of {e} executed movements (the others not recorded)"
        ax.set_title(f"{run.label}: {shown}", fontsize=10)
        ax.legend(loc="upper right", fontsize=8, markerscale=2)
    _set_top_view_limits(axes, runs, pts)
    fig.suptitle(title)
    fig.savefig(path, dpi=120)
    return path


def figure_final_objects(runs: list[Run], path: Path) -> Path:
    """Fig. 3: final object positions from above, coloured by object, one panel per run."""
    return _figure_object_positions(runs, path, "final_poses", "Final object positions, seen from above")


def figure_start_objects(runs: list[Run], path: Path) -> Path:
    """The objects' start positions (settled, at each episode's first frame) from above, drawn like Fig. 3."""
    starts = ", ".join(f"{r.starts} starts" for r in runs)
    return _figure_object_positions(runs, path, "start_poses", f"Start object positions, seen from above ({starts})")


def figure_accumulated_contacts(runs: list[Run], path: Path) -> Path:
    """Fig. 4: accumulated contacts vs attempted movements, every run on one axis."""
    fig, axes = _figure(1, 1, (7.0, 4.5))
    ax = axes[0]
    peak = 0
    for run, color in zip(runs, ("tab:blue", "tab:orange", "tab:green"), strict=False):
        hits = np.cumsum([int(bool(r.get("feasible")) and run.touched(r)) for r in run.rows])
        ax.plot(np.arange(1, len(hits) + 1), hits, color=color, label=run.label)
        peak = max([peak, *hits[-1:]])
    ax.set_ylim(0, max(peak, 1) * 1.05)
    ax.set_xlabel("attempted movements")
    ax.set_ylabel("accumulated contacts")
    ax.set_title("Accumulated contacts (executed movements touching any object)")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend()
    fig.savefig(path, dpi=120)
    return path


def figure_contacts_per_object(runs: list[Run], path: Path) -> Path:
    """Fig. 5: accumulated contacts per object vs executed movements; this run on top, the comparison below."""
    fig, axes = _figure(len(runs), 1, (7.0, 3.6 * len(runs)))
    for ax, run in zip(axes, runs, strict=True):
        x = np.arange(1, len(run.executed) + 1)
        peak = 0
        for name in run.object_names:
            hits = np.cumsum([int(run.touched(r, name)) for r in run.executed])
            ax.plot(x, hits, color=run.colors[name], label=name)
            peak = max([peak, *hits[-1:]])
        ax.set_ylim(0, max(peak, 1) * 1.05)
        ax.set_xlabel("executed movements")
        ax.set_ylabel("accumulated contacts")
        ax.set_title(run.label, fontsize=10)
        ax.grid(True, lw=0.3, alpha=0.5)
        ax.legend(fontsize=8)
    fig.suptitle("Accumulated contacts per object")
    fig.savefig(path, dpi=120)
    return path


# --- tables --------------------------------------------------------------------------------------------------
def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def markdown(
    summaries: list[dict[str, Any]],
    labels: list[str],
    comparison: dict[str, Any] | None,
    figures: dict[str, str] | None = None,
) -> str:
    """The summary as a Markdown document; ``figures``: the figures written, by key (default: `FIGURES`)."""
    head = "| | " + " | ".join(labels) + " |\n|---|" + "---|" * len(labels) + "\n"

    def row(name: str, values: list[Any]) -> str:
        return f"| {name} | " + " | ".join(_fmt(v) for v in values) + " |\n"

    objects = list(summaries[0]["contacts_per_object"])
    body = ""
    body += row("explorer", [s["explorer"] for s in summaries])
    body += row("starts (fixed: the task's scene; varied: drawn layouts)", [s.get("starts") for s in summaries])
    body += row("attempted movements", [s["attempts"] for s in summaries])
    body += row("executed movements (episodes)", [s["executed"] for s in summaries])
    body += row("feasible fraction", [s["feasible_fraction"] for s in summaries])
    body += row("contacts (executed movements touching any object)", [s["contacts"] for s in summaries])
    body += row("contacts per attempt", [s["contacts_per_attempt"] for s in summaries])
    body += row("clones (children repeating a tried genome; not simulated)", [s.get("clones") for s in summaries])
    body += row("distinct genomes executed", [s.get("distinct_genomes_executed") for s in summaries])
    body += row(
        "duplicate episodes (genome executed before from the same start)",
        [s.get("duplicate_episodes") for s in summaries],
    )
    body += row("distinct start layouts (2 cm grid)", [s.get("start_layouts") for s in summaries])
    body += row("distinct genomes touching any object", [s.get("touching_genomes") for s in summaries])
    for name in objects:
        body += row(
            f"distinct genomes touching {name}",
            [s.get("touching_genomes_per_object", {}).get(name) for s in summaries],
        )
    body += row("moved objects' final positions: occupied 2 cm cells", [s.get("moved_cells") for s in summaries])
    body += row("distinct changes (object, 2 cm cell of its displacement)", [s.get("changes") for s in summaries])
    body += row("executed attempts with novelty > 0", [s.get("novelty_positive_share") for s in summaries])
    body += row("distinct outcomes (final layouts, 1 cm grid)", [s.get("distinct_outcomes") for s in summaries])
    body += row("distinct behaviour descriptors", [s.get("distinct_descriptors") for s in summaries])
    for name in objects:
        body += row(f"contacts with {name}", [s["contacts_per_object"].get(name) for s in summaries])
    for name in objects:
        body += row(f"{name} moved > 1 cm", [s["moved_per_object"].get(name) for s in summaries])
    for name in objects:
        body += row(
            f"{name}: occupied 2 cm cells (final xy)",
            [s["final_object_spread"].get(name, {}).get("cells") for s in summaries],
        )
    for name in objects:
        body += row(
            f"{name}: std of final x / y (m)",
            [
                f"{_fmt(s['final_object_spread'][name]['std_x'])} / {_fmt(s['final_object_spread'][name]['std_y'])}"
                if name in s["final_object_spread"]
                else None
                for s in summaries
            ],
        )
    body += row("final tool positions: occupied 2 cm cells", [s["final_tool_spread"]["cells"] for s in summaries])
    body += row("novelty archive size", [s["archive"] for s in summaries])
    body += row("wall time of the generation loop (s, from the timings)", [s["wall_time_s"] for s in summaries])
    body += row("worker time: movements, rendering, encoding (s)", [s["worker_time_s"] for s in summaries])
    text = "# babblegen report\n\n" + head + body
    text += "\n## Infeasible attempts\n\n"
    reasons = sorted({k for s in summaries for k in s["infeasible_reasons"]})
    if reasons:
        text += head + "".join(row(k, [s["infeasible_reasons"].get(k, 0) for s in summaries]) for k in reasons)
    else:
        text += "none\n"
    if comparison is not None:
        text += "\n## Against the comparison run\n\n"
        text += f"- contact ratio (contacts / comparison's contacts): {_fmt(comparison['contact_ratio'], 2)}\n"
        text += f"- contact rate ratio (per attempt): {_fmt(comparison['contact_rate_ratio'], 2)}\n"
        text += f"- distinct touching genomes ratio: {_fmt(comparison['touching_genomes_ratio'], 2)}\n"
        text += f"- moved objects' 2 cm cells ratio: {_fmt(comparison['moved_cells_ratio'], 2)}\n"
        for name, v in comparison["contact_ratio_per_object"].items():
            text += f"- {name}: {_fmt(v, 2)}\n"
    text += "\n## Figures\n\n" + "".join(f"![{k}]({v})\n" for k, v in (figures or FIGURES).items())
    return text


def write_report(root: str | Path, compare_to: str | Path | None = None, out: str | Path | None = None) -> dict:
    """Write the figures and summaries for `root` (and `compare_to`) into `out` (default ROOT/report).
    Returns the summary written to summary.json."""
    runs = [Run(root)] + ([Run(compare_to)] if compare_to is not None else [])
    out = Path(out) if out is not None else Path(root) / "report"
    out.mkdir(parents=True, exist_ok=True)
    summaries = [summarize(r) for r in runs]
    comparison = compare(summaries[0], summaries[1]) if len(runs) > 1 else None
    figure_final_tool(runs, out / FIGURES["fig2"])
    figure_final_objects(runs, out / FIGURES["fig3"])
    figure_accumulated_contacts(runs, out / FIGURES["fig4"])
    figure_contacts_per_object(runs, out / FIGURES["fig5"])
    figures = dict(FIGURES)
    if any(r.has_start_poses for r in runs):
        figures[START_FIGURE[0]] = figure_start_objects(runs, out / START_FIGURE[1]).name
    result = {"run": summaries[0], "figures": {k: str(out / v) for k, v in figures.items()}}
    if comparison is not None:
        result["compare"] = summaries[1]
        result["comparison"] = comparison
    (out / "summary.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "summary.md").write_text(markdown(summaries, [r.label for r in runs], comparison, figures))
    return result
