"""What a dataset's objects were and which of them its movements touched, pushed and toppled.

Per dataset: distinct object sets, shape kinds, the span of masses and static frictions, and the diversity measures
of `babblegen report` (duplicate episodes, distinct genomes touching an object, 2 cm cells of moved objects' final
places); then per shape kind, and per third of the mass and friction ranges, the share of object-episodes where the
arm touched the object, where it moved over 1 cm (pushed) and where it ended tilted over 30 degrees (toppled).

    .venv/bin/python benchmarks/object_coverage.py DATASET [DATASET ...] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.exporters.report_measures import diversity

MOVED = 0.01  # metres
TOPPLED = np.radians(30)


def tilt(q: list[float]) -> float:
    """Angle between the object's own vertical and the world's, radians."""
    w, x, y, z = q
    return float(np.arccos(np.clip(1 - 2 * (x * x + y * y), -1.0, 1.0)))


def measure(root: Path) -> dict:
    rows = read_attempts(root)
    names = read_run_info(root)["object_names"]
    executed = [r for r in rows if r.get("feasible")]
    sets = {json.dumps(r["objects"]) for r in executed if r.get("objects")}
    objects = [o for r in executed for o in r.get("objects") or []]
    masses = np.array([o["mass"] for o in objects]) if objects else np.zeros(0)
    friction = np.array([o["static_friction"] for o in objects]) if objects else np.zeros(0)
    groups: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
    mass_cuts = np.quantile(masses, [1 / 3, 2 / 3]) if len(masses) else [0, 0]
    friction_cuts = np.quantile(friction, [1 / 3, 2 / 3]) if len(friction) else [0, 0]
    for r in executed:
        for o in r.get("objects") or []:
            n = o["name"]
            touched = bool((r.get("touched") or {}).get(n))
            moved = float((r.get("displacement") or {}).get(n, 0.0)) > MOVED
            toppled = tilt(r["final_poses"][n][3:]) - tilt(r["start_poses"][n][3:]) > TOPPLED
            for key in (
                f"shape={o['shape']}",
                f"mass={['low', 'mid', 'high'][int(np.searchsorted(mass_cuts, o['mass']))]}",
                f"friction={['low', 'mid', 'high'][int(np.searchsorted(friction_cuts, o['static_friction']))]}",
            ):
                g = groups[key]
                g["n"].append(1)
                g["touched"].append(touched)
                g["pushed"].append(moved)
                g["toppled"].append(toppled)
    per_group = {
        k: {"object_episodes": len(g["n"]), **{m: float(np.mean(g[m])) for m in ("touched", "pushed", "toppled")}}
        for k, g in sorted(groups.items())
    }
    return {
        "dataset": str(root),
        "attempts": len(rows),
        "executed": len(executed),
        "object_sets": len(sets),
        "shape_kinds": sorted({o["shape"] for o in objects}),
        "mass_span": float(masses.max() / masses.min()) if len(masses) else None,
        "static_friction_span": float(friction.max() / friction.min()) if len(friction) else None,
        **{k: v for k, v in diversity(rows, names).items() if not isinstance(v, dict)},
        "groups": per_group,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("datasets", nargs="+", type=Path)
    p.add_argument("--json", type=Path, help="write every number here too")
    args = p.parse_args()
    results = [measure(d) for d in args.datasets]
    keys = ["executed", "object_sets", "duplicate_episodes", "touching_genomes", "moved_cells", "changes"]
    print("dataset".ljust(28) + "".join(k[:16].rjust(18) for k in keys))
    for r in results:
        print(Path(r["dataset"]).name.ljust(28) + "".join(str(r[k]).rjust(18) for k in keys))
    for r in results:
        print(f"\n{Path(r['dataset']).name}: shapes {r['shape_kinds']}, mass span {r['mass_span']}, "
              f"static friction span {r['static_friction_span']}")  # fmt: skip
        for k, g in r["groups"].items():
            print(f"  {k:18s} n={g['object_episodes']:5d} touched {g['touched']:.3f} pushed {g['pushed']:.3f} "
                  f"toppled {g['toppled']:.3f}")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
