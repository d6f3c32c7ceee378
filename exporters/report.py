"""The NovEB paper's figures and a summary table for one run, optionally against a comparison run.

Every number comes from the sidecar table (DIR/babblegen/attempts.jsonl) and the task in run.json; objects are
named by slot (the paper's names, or object_0 ... in a run that draws its objects, each slot in a colour of its own):
    fig2_final_tool_positions.png     final tool positions seen from above (Fig. 2)
    fig3_final_object_positions.png   final object positions seen from above, coloured by object (Fig. 3)
    fig4_accumulated_contacts.png     accumulated contacts vs attempted movements, both runs (Fig. 4)
    fig5_contacts_per_object.png      accumulated contacts per object vs executed movements (Fig. 5)
    start_object_positions.png        the objects' start positions (first frame) from above, drawn like Fig. 3;
                                      only for datasets whose rows record them (``start_poses``)
    summary.md, summary.json          the numbers

The numbers are `report_measures.py`'s, the figures `report_figures.py`'s; this module writes both, with the
summary as a Markdown table.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .report_figures import (
    FIGURES,
    START_FIGURE,
    figure_accumulated_contacts,
    figure_contacts_per_object,
    figure_final_objects,
    figure_final_tool,
    figure_start_objects,
)
from .report_measures import Run, compare, diversity, moved_object_ends, summarize

__all__ = [
    "FIGURES",
    "START_FIGURE",
    "Run",
    "compare",
    "diversity",
    "markdown",
    "moved_object_ends",
    "summarize",
    "write_report",
]


# --- tables --------------------------------------------------------------------------------------------------
def _fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def _touched_of(per_shape: dict[str, dict[str, int]] | None, shape: str) -> str | None:
    counts = (per_shape or {}).get(shape)
    return None if counts is None else f"{counts['touched']} / {counts['objects']}"


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

    objects = list(dict.fromkeys(name for s in summaries for name in s["contacts_per_object"]))  # every run's
    body = ""
    body += row("explorer", [s["explorer"] for s in summaries])
    body += row("starts (fixed: the task's scene; varied: drawn layouts)", [s.get("starts") for s in summaries])
    body += row(
        "objects (paper: the task's; varied, heldout: drawn per start into slots)",
        [f"{s.get('objects', 'paper')}, {s.get('num_objects', len(s['contacts_per_object']))}" for s in summaries],
    )
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
    body += row(
        "moved objects ending on the table / on the floor / past the floor's edge (out of the scene)",
        [
            None if "moved_on_table" not in s
            else f"{s['moved_on_table']} / {s['moved_on_floor']} / {s['moved_out_of_scene']}"
            for s in summaries
        ],
    )  # fmt: skip
    body += row(
        "moved objects' final positions on the table: occupied 2 cm cells",
        [s.get("moved_cells_on_table") for s in summaries],
    )
    body += row("episodes losing an object out of the scene", [s.get("episodes_losing_an_object") for s in summaries])
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
    shapes = sorted({k for s in summaries for k in s.get("contacts_per_shape") or {}})
    for shape in shapes:
        body += row(
            f"{shape} objects touched / started with (in executed movements)",
            [_touched_of(s.get("contacts_per_shape"), shape) for s in summaries],
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
        on_table = _fmt(comparison.get("moved_cells_on_table_ratio"), 2)
        text += f"- the same, on the table alone: {on_table}\n"
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
