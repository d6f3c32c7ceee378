"""The evaluation's results as tables (``evaluation.md``), numbers (``evaluation.json``), a figure of each score
against the attempt budget (``budgets.png``) and one of where the models end the moved objects (``ends.png``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from babblegen.worldmodel.episodes import STRATA
from babblegen.worldmodel.experiment import NOTHING
from babblegen.worldmodel.planning import GOAL_STRATA


def _values(results: list[dict], path: tuple[str, ...]) -> np.ndarray:
    out = []
    for r in results:
        v = r
        for key in path:
            v = v.get(key, {}) if isinstance(v, dict) else {}
        out.append(v if isinstance(v, int | float) else math.nan)
    return np.asarray(out, dtype=float)


def cell(values: np.ndarray, digits: int = 3) -> str:
    """mean ± std of the values that are numbers; "-" if none is."""
    v = values[~np.isnan(values)]
    if not len(v):
        return "-"
    return f"{v.mean():.{digits}f} ± {v.std():.{digits}f}" if len(v) > 1 else f"{v.mean():.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def interval(value: float, ci: list[float]) -> str:
    """A rate with its 95 % interval."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.3f} [{ci[0]:.3f}, {ci[1]:.3f}]"


BASELINES = {
    "random": "one random genome",
    "best_of_random": "best of {n} random genomes, executed",
    "replay": "the goal's own movement, replayed",
}


def shape_table(block: dict, test: str) -> list[str]:
    """Per source, F1 and error on each shape's objects of ``test`` alone (none: no table)."""
    results = [r for rs in block["sources"].values() for r in rs]
    shapes = {}  # shape -> its moved objects (the same test set for every source)
    for r in results:
        for shape, sc in r.get("scores", {}).get(test, {}).get("shapes", {}).items():
            shapes.setdefault(shape, sc["moved"])
    if not shapes:
        return []
    header = ["trained on"] + [f"{shape} ({moved} moved): F1 / error" for shape, moved in shapes.items()]
    rows = []
    for name, rs in block["sources"].items():
        row = [name]
        for shape in shapes:
            f1 = cell(_values(rs, ("scores", test, "shapes", shape, "f1")))
            ratio = cell(_values(rs, ("scores", test, "shapes", shape, "ratio")), 2)
            row.append(f"{f1} / {ratio}")
        rows.append(row)
    return [f"By shape on {test} (each shape's objects alone):", ""] + _table(header, rows) + [""]


def _misses(results: list[dict]) -> str:
    """The median distance of the goal object from its goal after the model's choices, over goals and repeats:
    as the model predicted it and as executed ("-" for results made before these were kept)."""
    medians = []
    for key in ("goal_predicted_miss_cm", "goal_miss_cm"):
        values = np.concatenate([np.asarray(r["planning"].get(key, []), dtype=float) for r in results])
        values = values[np.isfinite(values)]
        medians.append(f"{np.median(values):.1f}" if len(values) else "-")
    return " / ".join(medians)


def planning_table(result: dict, block: dict) -> list[str]:
    """Per source (pooled over repeats) and per baseline: success overall and per goal stratum, with 95 %
    intervals over goals; for the cem planner, how often the executed movement differed from the scored one."""
    p = result["planning"]
    strata = list(p.get("strata", {}))
    header = ["planner / baseline", "all"] + [f"{GOAL_STRATA.get(s, s)} ({p['strata'][s]})" for s in strata]
    cem = p.get("planner") == "cem"
    if cem:
        header += ["median miss, predicted / executed (cm)", "executed differs / infeasible"]
        header += ["search s per model (CPU)"]
    rows = []
    for name, pooled in block.get("planning", {}).items():
        row = [f"model trained on {name}", interval(pooled["model"], pooled["ci95"])]
        row += [interval(pooled["strata"][s]["model"], pooled["strata"][s]["ci95"]) for s in strata]
        if cem:
            results = block["sources"][name]
            differs = cell(_values(results, ("planning", "executed", "differs")), 2)
            infeasible = cell(_values(results, ("planning", "executed", "infeasible")), 2)
            wall = cell(_values(results, ("planning", "search_seconds")), 0)
            cpu = cell(_values(results, ("planning", "search_cpu_seconds")), 0)
            row += [_misses(results), f"{differs} / {infeasible}", f"{wall} ({cpu})"]
        rows.append(row)
    if "ceiling" in p:
        c = p["ceiling"]
        n = len(c["goals"])
        for name, pooled in block.get("planning", {}).items():
            if "on_ceiling_goals" in pooled:
                mine = pooled["on_ceiling_goals"]
                label = (
                    f"model trained on {name}, on the ceiling's {n} goals (share of the ceiling {mine['share']:.2f})"
                )
                rows.append([label, interval(mine["model"], mine["ci95"])] + ["-"] * (len(header) - 2))
        rows.append(
            [f"the true simulator as the model (ceiling, {n} goals)", interval(c["rate"], c["ci95"])]
            + ["-"] * (len(header) - 2)
        )
    baselines = p.get("baselines", {})
    for key, label in BASELINES.items():
        if key not in baselines:
            continue
        b = baselines[key]
        row = [label.format(n=baselines.get("random_genomes", "?")), interval(b["rate"], b["ci95"])]
        row += [interval(b["strata"][s]["rate"], b["strata"][s]["ci95"]) for s in strata]
        rows.append(row + (["-", "-"] if cem else []))
    return _table(header, rows)


def _along(block: dict, tests: list[str]) -> list[str]:
    """A line: per test set and source, how far along their true moves the models end the moved objects."""
    key = ("all", "along")
    if not any(np.isfinite(_values(r, ("scores", t, *key))).any() for r in block["sources"].values() for t in tests):
        return []  # an evaluation.json written before it was recorded
    parts = [
        f"{t}: " + ", ".join(f"{n} {cell(_values(r, ('scores', t, *key)), 2)}" for n, r in block["sources"].items())
        for t in tests
    ]
    return [
        "How far along its true move each model ends the moved objects (median; 1: where they ended, 0: where they "
        "started; `ends.png` shows each object): " + "; ".join(parts) + ".",
        "",
    ]


def block_title(block: dict) -> str:
    budget = "the whole datasets" if block["attempts"] is None else f"{block['attempts']:,} attempts"
    sizes = block["sizes"]
    kind = (
        "equal attempts" if block["equal"] == "attempts" else f"equal episodes ({min(sizes)}-{max(sizes)} per source)"
    )
    return f"{budget}, {kind}"


def markdown(result: dict) -> str:
    tests = list(result["tests"])
    lines = ["# What each dataset teaches a world model", ""]
    models = result.get("models", {})
    if models and models["done"] < models["total"]:
        lines += [f"**In progress**: {models['done']} of {models['total']} models trained so far.", ""]
    lines += [
        'Per training source, mean ± std over repeats. F1: of "moves" (over 1 cm) per object and episode. Error: '
        'median error of the predicted final (x, y) of the objects that moved, as a multiple of "nothing moves" '
        "(below 1: better than predicting no motion; cm in evaluation.json). Macro: the mean over the outcome "
        "strata that have moved objects. Planning: goals reached within "
        f"{result['settings']['planning']['success_cm']:g} cm by the candidate the model chose.",
        "",
        "Test sets: "
        + "; ".join(
            f"**{t}** ({info['episodes']} episodes, {info['moved_object_episodes']} moved object-episodes; strata "
            + ", ".join(f"{s} {n}" for s, n in info["strata"].items())
            + ")"
            for t, info in result["tests"].items()
        )
        + ".",
        "",
    ]
    if "planning" in result:
        p = result["planning"]
        if p.get("planner") == "cem":
            ps = p.get("settings", {})
            lines += [
                f"Planning: {p['goals']} goals from {p.get('test', '?')} (an object's end position, from its "
                "episode's start). Each model searches alone, with the cross-entropy method "
                f"({ps.get('cem_samples', '?')} genomes x {ps.get('cem_iterations', '?')} iterations per goal); "
                "its choice is executed once. Success: the goal object ends within "
                f"{ps.get('success_cm', 3.0):g} cm of the goal; [95 % bootstrap interval over goals].",
                "",
            ]
        else:
            lines += [f"Planning (rank): {p['goals']} goals from {p.get('test', '?')}.", ""]
    for block in result["blocks"]:
        lines += [f"## {block_title(block)}", ""]
        header = ["trained on", "episodes"]
        for t in tests:
            header += [f"{t}: F1", f"{t}: error", f"{t}: macro F1"]
        planning = "planning" in result
        rank = planning and result["planning"].get("planner") == "rank"
        if rank:
            header += ["planning: model", "oracle", "random", "share of oracle"]
        elif planning:
            header += ["planning: model"]
        rows = []
        for name, results in block["sources"].items():
            row = [name, cell(_values(results, ("episodes",)), 0)]
            for t in tests:
                row += [
                    cell(_values(results, ("scores", t, "all", "f1"))),
                    cell(_values(results, ("scores", t, "all", "ratio")), 2),
                    cell(_values(results, ("scores", t, "macro", "f1"))),
                ]
            if rank:
                row += [cell(_values(results, ("planning", k)), 2) for k in ("model", "oracle", "random", "share")]
            elif planning:
                pooled = block.get("planning", {}).get(name)
                row.append(interval(pooled["model"], pooled["ci95"]) if pooled else "-")
            rows.append(row)
        nothing = [NOTHING, "-"] + ["0", "1", "0"] * len(tests)
        rows.append(nothing + (["-"] * (4 if rank else 1) if planning else []))
        lines += _table(header, rows) + [""]
        lines += _along(block, tests)
        t0 = tests[0]
        header = ["trained on"] + [f"{s}: F1 / error" for s in STRATA if s != "nothing_moved"]
        header += ["nothing_moved: false moves"]
        rows = []
        for name, results in block["sources"].items():
            row = [name]
            for s in STRATA[1:]:
                f1 = cell(_values(results, ("scores", t0, s, "f1")))
                ratio = cell(_values(results, ("scores", t0, s, "ratio")), 2)
                row.append(f"{f1} / {ratio}")
            row.append(cell(_values(results, ("scores", t0, "nothing_moved", "false_moves"))))
            rows.append(row)
        lines += [f"By outcome on {t0}:", ""] + _table(header, rows) + [""]
        for t in tests:
            lines += shape_table(block, t)
        if planning and "baselines" in result["planning"]:
            lines += ["Planning, by goal stratum:", ""] + planning_table(result, block) + [""]
    return "\n".join(lines)


def figure(result: dict, path: Path) -> bool:
    """Each score against the attempt budget, per source (equal attempts solid, equal episodes dashed); False
    when there is one budget or none, and nothing is drawn."""
    budgets = sorted({b["attempts"] for b in result["blocks"] if b["attempts"] is not None})
    if len(budgets) < 2:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t0 = next(iter(result["tests"]))
    panels = [
        (("scores", t0, "all", "f1"), f"F1 of moves ({t0})"),
        (("scores", t0, "all", "ratio"), f"error / nothing moves ({t0})"),
    ]
    if "planning" in result:
        panels.append((("planning", "model"), "planning success"))
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4), squeeze=False)
    names = list(dict.fromkeys(n for b in result["blocks"] for n in b["sources"]))
    colors = {n: plt.cm.tab10(i % 10) for i, n in enumerate(names)}
    for ax, (key, title) in zip(axes[0], panels, strict=True):
        for equal, style in (("attempts", "-"), ("episodes", "--")):
            for name in names:
                xs, ys, es = [], [], []
                for b in result["blocks"]:
                    if b["equal"] == equal and b["attempts"] in budgets and name in b["sources"]:
                        v = _values(b["sources"][name], key)
                        xs.append(b["attempts"])
                        ys.append(np.nanmean(v))
                        es.append(np.nanstd(v))
                if xs:
                    label = f"{name} (equal {equal})"
                    ax.errorbar(xs, ys, yerr=es, ls=style, marker="o", color=colors[name], label=label, capsize=3)
        ax.set_xlabel("attempts")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def ends_figure(result: dict, path: Path) -> bool:
    """Where each source's model ends the test sets' moved objects, in units of their true displacement (the first
    repeat, at the largest budget, equal attempts): one panel per source and test set, the truth at (1, 0) and
    "nothing moves" at (0, 0), objects beyond the frame at its edge. False when no model recorded its ends, and
    nothing is drawn."""
    blocks = [b for b in result["blocks"] if any(r[0].get("ends") for r in b["sources"].values())]
    if not blocks:
        return False
    block = max(blocks, key=lambda b: (np.inf if b["attempts"] is None else b["attempts"], b["equal"] == "attempts"))
    sources, tests = list(block["sources"]), list(result["tests"])
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(sources), len(tests), figsize=(3.6 * len(tests), 3.2 * len(sources)), squeeze=False)
    for row, name in zip(axes, sources, strict=True):
        ends = block["sources"][name][0].get("ends", {})
        for ax, test in zip(row, tests, strict=True):
            units = np.asarray(ends.get(test, []), dtype=float).reshape(-1, 2)
            ax.axvline(0.0, color="0.7", lw=0.8)
            ax.axvline(1.0, color="0.7", lw=0.8)
            ax.axhline(0.0, color="0.7", lw=0.8)
            ax.scatter(np.clip(units[:, 0], -0.5, 2.0), np.clip(units[:, 1], -1.25, 1.25), s=9, alpha=0.6)
            ax.plot([1.0], [0.0], marker="*", color="tab:green", ms=12, ls="", label="where it ended")
            ax.plot([0.0], [0.0], marker="x", color="tab:red", ms=8, ls="", label="where it started")
            along = f"median {np.median(units[:, 0]):.2f} of the way" if len(units) else "no moved objects"
            ax.set_title(f"{name} on {test}: {along}", fontsize=8)
            ax.set_xlim(-0.5, 2.0)
            ax.set_ylim(-1.25, 1.25)
            ax.set_aspect("equal")
            ax.grid(alpha=0.2)
    axes[0][0].legend(fontsize=7, loc="lower left")
    for ax in axes[-1]:
        ax.set_xlabel("along the true move (1: where it ended)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("across it", fontsize=8)
    budget = "all attempts" if block["attempts"] is None else f"{block['attempts']:,} attempts"
    fig.suptitle(f"Where the models end the moved objects ({budget}, equal {block['equal']}, first repeat)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def write(result: dict, out: Path) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "evaluation.json", out / "evaluation.md"]
    written[0].write_text(json.dumps(result, indent=1, default=float) + "\n")
    written[1].write_text(markdown(result) + "\n")
    if figure(result, out / "budgets.png"):
        written.append(out / "budgets.png")
    if ends_figure(result, out / "ends.png"):
        written.append(out / "ends.png")
    return written
