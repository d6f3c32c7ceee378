"""What a dataset covers, per episode: the measures behind "why do one explorer's episodes teach a world model less
than another's". From each dataset's sidecar and frames:

- starts: distinct start layouts per 1,000 episodes;
- lineages: the share of episodes whose parent was executed from the same start (a near relative in the data), and
  the mean number of such ancestors above an episode;
- near-duplicates: episodes from one start whose tool paths (the arm's tool point over the episode, resampled to 32
  points) lie within 1 cm of each other on average, as pairs and as the share of episodes that have one;
- trajectory coverage: distinct 4 cm cells (x, y) where the tool passed within 12 cm of the table top (where it can
  push), in all and per 1,000 episodes;
- outcome coverage: distinct changes (object, 2 cm cell of its displacement; the report's measure) per 1,000
  episodes, episodes per outcome stratum, and per object the episodes in which it moved.

    .venv/bin/python benchmarks/dataset_coverage.py noveb=DIR random_waypoints=DIR [--attempts 1200] [--json F]
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from babblegen.dataset.sidecar import read_attempts
from babblegen.exporters.report_measures import diversity
from babblegen.worldmodel.episodes import STRATA, outcomes, read_dataset

NEAR = 0.01  # metres: mean distance between two tool paths that makes them near-duplicates
CELL = 0.04  # metres: the trajectory-coverage grid
LOW = 0.12  # metres above the table top: the tool can push


def tool_paths(states: list[np.ndarray], robot: str, points: int = 32) -> np.ndarray:
    """(E, points, 3) the tool point over each episode, resampled in time."""
    from babblegen.tasks import get_robot
    from babblegen.world.kinematics import ArmKinematics, UrdfModel

    spec = get_robot(robot)
    kin = ArmKinematics(UrdfModel.load(spec.urdf), spec.base_link, spec.tool_link)
    out = []
    for q in states:
        t = np.linspace(0, len(q) - 1, points)
        resampled = np.stack([np.interp(t, np.arange(len(q)), q[:, j]) for j in range(q.shape[1])], axis=1)
        out.append(kin.tool_position(resampled))
    return np.stack(out)


def coverage(root: Path, attempts: int | None) -> dict:
    data = read_dataset(root)
    episodes = data.budget(attempts=attempts)
    rows = [r for r in read_attempts(root) if attempts is None or r["attempt"] < attempts]
    n = len(episodes)
    by_attempt = {r["attempt"]: r for r in rows}
    same_start_parent, depth = 0, []
    for r in (by_attempt[int(a)] for a in episodes.attempt):
        d, row = 0, r
        while row.get("parent") is not None and row["parent"] in by_attempt:
            parent = by_attempt[row["parent"]]
            if not parent.get("feasible") or (parent.get("start") or {}).get("layout") != (row.get("start") or {}).get(
                "layout"
            ):
                break
            d, row = d + 1, parent
        same_start_parent += d > 0
        depth.append(d)
    paths = tool_paths(episodes.states, episodes.scene.robot)
    pairs, has_twin = 0, np.zeros(n, dtype=bool)
    for layout in np.unique(episodes.layout):
        idx = np.flatnonzero(episodes.layout == layout)
        if len(idx) < 2:
            continue
        p = paths[idx]
        for a in range(len(idx) - 1):
            close = np.linalg.norm(p[a + 1 :] - p[a], axis=-1).mean(axis=1) < NEAR
            pairs += int(close.sum())
            if close.any():
                has_twin[idx[a]] = True
                has_twin[idx[a + 1 :][close]] = True
    low = paths[..., 2] < episodes.scene.top + LOW
    cells = {tuple(c) for c in np.floor(paths[low][:, :2] / CELL).astype(int).tolist()}
    moved, stratum = outcomes(episodes)
    measures = diversity(rows, list(episodes.scene.objects))
    per_thousand = 1000 / max(n, 1)
    return {
        "dataset": str(root),
        "explorer": data.run["config"]["explorer"],
        "episodes": n,
        "start_layouts_per_1000": len(set(episodes.layout.tolist())) * per_thousand,
        "same_start_parent_share": same_start_parent / max(n, 1),
        "mean_ancestors_same_start": float(np.mean(depth)) if depth else 0.0,
        "near_duplicate_pairs": pairs,
        "near_duplicate_share": float(has_twin.mean()) if n else 0.0,
        "tool_cells_low": len(cells),
        "tool_cells_low_per_1000": len(cells) * per_thousand,
        "touching_genomes": measures["touching_genomes"],
        "changes": measures["changes"],
        "changes_per_1000": measures["changes"] * per_thousand,
        "strata": {s: int(c) for s, c in zip(STRATA, np.bincount(stratum, minlength=len(STRATA)), strict=True)},
        "moved_per_object": dict(zip(episodes.scene.objects, moved.sum(axis=0).tolist(), strict=True)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("datasets", nargs="+", metavar="NAME=DIR")
    parser.add_argument("--attempts", type=int, default=None, help="each dataset's first N attempts [whole]")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    table: dict[str, list[dict]] = {}
    for item in args.datasets:
        name, _, path = item.partition("=")
        table.setdefault(name, []).append(coverage(Path(path), args.attempts))
    keys = [
        "episodes", "start_layouts_per_1000", "same_start_parent_share", "mean_ancestors_same_start",
        "near_duplicate_share", "tool_cells_low", "tool_cells_low_per_1000", "touching_genomes", "changes",
        "changes_per_1000",
    ]  # fmt: skip
    print("| measure | " + " | ".join(table) + " |")
    print("|---|" + "---|" * len(table))
    for key in keys:
        print(f"| {key} | " + " | ".join(f"{np.mean([r[key] for r in rows]):.3g}" for rows in table.values()) + " |")
    for s in STRATA:
        print(
            f"| stratum {s} | "
            + " | ".join(f"{np.mean([r['strata'][s] for r in rows]):.1f}" for rows in table.values())
            + " |"
        )
    objects = list(next(iter(table.values()))[0]["moved_per_object"])
    for o in objects:
        print(
            f"| moved: {o} | "
            + " | ".join(f"{np.mean([r['moved_per_object'][o] for r in rows]):.1f}" for rows in table.values())
            + " |"
        )
    counts = Counter(len(rows) for rows in table.values())
    print(f"\nmeans over {dict(counts)} dataset(s) per name; --attempts {args.attempts}")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1) + "\n")


if __name__ == "__main__":
    main()
