"""The NovEB paper's figures (Figs. 2 to 5) and the start positions, drawn from runs' sidecar tables (`Run`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .geometry import box_footprint, robot_footprint
from .report_measures import OUT_OF_SCENE, Run

FIGURES = {
    "fig2": "fig2_final_tool_positions.png",
    "fig3": "fig3_final_object_positions.png",
    "fig4": "fig4_accumulated_contacts.png",
    "fig5": "fig5_contacts_per_object.png",
}
START_FIGURE = ("starts", "start_object_positions.png")  # written when the rows record their start poses
TOOL_GREEN = "#22aa33"
TABLE_BROWN = "#8c6647"


# --- figures -------------------------------------------------------------------------------------------------
def _figure(nrows: int, ncols: int, size: tuple[float, float]):
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    return fig, axes


def _top_view_background(ax, run: Run) -> None:
    """Table (brown), robot (white box), static obstacles (gray) and the task's objects where they rest (not in a
    run that draws its objects); x forward is up, the robot's left (+y) is on the left, as in the paper's views
    from above."""
    from matplotlib.patches import Circle, Polygon, Rectangle

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
    for o in [] if run.drawn else run.task["objects"]:  # a run that draws its objects: its slots rest nowhere
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
        lost = 0
        for name in run.object_names:
            p = [r[key][name] for r in run.executed if name in (r.get(key) or {})]
            p = np.array(p, dtype=float).reshape(-1, 7)
            lost += int((p[:, 2] < OUT_OF_SCENE).sum())
            p = p[p[:, 2] >= OUT_OF_SCENE]  # fallen past the floor's edge: counted in the title, not drawn
            pts.append(p)
            ax.scatter(
                p[:, 1], p[:, 0], s=8, color=run.colors[name], edgecolors="0.25", linewidths=0.3, zorder=4, label=name
            )
        n, e = sum(bool(r.get(key)) for r in run.executed), len(run.executed)
        shown = f"{n} executed movements" if n == e else f"{n} of {e} executed movements (the others not recorded)"
        if lost:
            shown += f";\n{lost} objects fell past the floor's edge (not drawn)"
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
