"""NovEB against random motor babbling over the same number of attempted movements (the paper's Fig. 4), and
the behaviour-descriptor variants the default was chosen from.

Runs the real explorer -> world -> descriptor loop (no LeRobot encoding, which does not change what is
explored) for each explorer and seed, stopping after ``--attempts`` attempted movements (clones, children
repeating a tried genome, reuse its outcome and are not attempts), and reports the dataset measures of
``babblegen report``: distinct genomes executed, duplicate episodes, distinct genomes touching each object,
the moved objects' final positions in 2 cm cells, and the share of executed attempts with novelty > 0.
Per-attempt rows (sidecar layout) go to OUT/<label>.jsonl.

    python benchmarks/compare_explorers.py --attempts 1200 --seeds 0 1 2 --jobs 2 --out runs/compare
    python benchmarks/compare_explorers.py --explorers noveb --descriptor phash --crop none --out runs/full-frame
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np


def run_one(explorer_name: str, seed: int, attempts: int, out: str, options: dict[str, Any]) -> dict:
    from babblegen.assembly import build_descriptor, build_explorer
    from babblegen.config import RunConfig
    from babblegen.evaluation import LocalEvaluator, arm_info
    from babblegen.exporters.report import diversity
    from babblegen.run import command_for
    from babblegen.tasks import get_task
    from babblegen.world.world import WorldSettings

    cfg = RunConfig(explorer=explorer_name, seed=seed)
    task = get_task(cfg.task)
    world = WorldSettings(**{**cfg.world.to_dict(), **options.get("world", {})})
    ev = LocalEvaluator(task, world, seed)
    ex = build_explorer(cfg, arm_info(task), options.get("explorer"))
    desc = build_descriptor(cfg, options.get("descriptor"))
    names = task.object_names
    label = f"{options.get('label', explorer_name)}-{seed}"
    path = Path(out) / f"{label}.jsonl"
    t0, clones = time.perf_counter(), 0
    with open(path, "w") as f:
        while ex.attempts_asked < attempts:
            cands = ex.ask(max_new=attempts - ex.attempts_asked)
            rollouts = ev.evaluate([command_for(c) for c in cands], [c.index for c in cands])
            codes = [desc(r.after_image) if r.feasible else None for r in rollouts]
            evals = ex.tell(cands, codes)
            clones += len(ex.last_clones)
            for c, r, e, code in zip(cands, rollouts, evals, codes, strict=True):
                row = {
                    "attempt": c.index,
                    "generation": c.generation,
                    "kind": c.kind,
                    "genome": np.asarray(c.genome).tolist(),
                    "feasible": r.feasible,
                    "reason": r.reason,
                    "novelty": e.novelty,
                    "archived": e.archived,
                }
                if r.feasible:
                    row["descriptor"] = desc.hex(code) if hasattr(desc, "hex") else None
                    row["touched"] = dict(zip(names, map(bool, r.touched), strict=True))
                    row["displacement"] = dict(zip(names, np.round(r.displacement, 6).tolist(), strict=True))
                    row["final_poses"] = dict(zip(names, np.round(r.final_poses, 6).tolist(), strict=True))
                f.write(json.dumps(row) + "\n")
    ev.close()
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    return {
        "label": label,
        "explorer": explorer_name,
        "seed": seed,
        "attempts": len(rows),
        "executed": sum(bool(r["feasible"]) for r in rows),
        "contacts": sum(any((r.get("touched") or {}).values()) for r in rows),
        "clones": clones,
        "seconds": time.perf_counter() - t0,
        **diversity(rows, names),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=1200)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--explorers", nargs="+", default=["noveb", "random"], choices=["noveb", "random"])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="runs/compare")
    p.add_argument("--label", default=None, help="name prefix of the rows files (default: the explorer)")
    p.add_argument("--descriptor", default=None, help="descriptor name (default: the run default)")
    p.add_argument("--hash-size", type=int, default=None)
    p.add_argument("--crop", default=None, help="x0,y0,x1,y1 fractions, or 'none' for the full frame")
    p.add_argument("--camera", type=int, default=None, help="square camera resolution in pixels")
    p.add_argument("--literal", action="store_true", help="the paper's literal procedure (clones re-simulated)")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an explorer option, e.g. tie_break=oldest or reuse_clones=false (repeatable)",
    )
    args = p.parse_args()
    options: dict[str, Any] = {"descriptor": {}, "world": {}, "explorer": {}}
    if args.descriptor:
        options["descriptor"]["name"] = args.descriptor
    if args.hash_size:
        options["descriptor"]["hash_size"] = args.hash_size
    if args.crop:
        options["descriptor"]["crop"] = None if args.crop == "none" else [float(v) for v in args.crop.split(",")]
    if args.camera:
        options["world"] = {"camera_width": args.camera, "camera_height": args.camera}
    if args.literal:
        options["explorer"] = {"reuse_clones": False, "tie_break": "oldest", "archive_policy": "most_novel"}
    for item in args.set:
        key, _, value = item.partition("=")
        options["explorer"][key] = json.loads(value) if value in ("true", "false") or value[:1].isdigit() else value
    Path(args.out).mkdir(parents=True, exist_ok=True)
    jobs = [(e, s) for s in args.seeds for e in args.explorers]
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = []
        for e, s in jobs:
            opts = {**options, "label": f"{args.label}-{e}" if args.label else e}
            futures.append(pool.submit(run_one, e, s, args.attempts, args.out, opts))
        results = [f.result() for f in futures]
    (Path(args.out) / f"summary-{args.label or 'compare'}.json").write_text(json.dumps(results, indent=2))
    keys = (
        "attempts",
        "executed",
        "clones",
        "duplicate_episodes",
        "contacts",
        "touching_genomes",
        "moved_cells",
        "novelty_positive_share",
    )
    print(f"{'run':>24} " + " ".join(f"{k[:12]:>12}" for k in keys))
    for r in results:
        print(f"{r['label']:>24} " + " ".join(f"{r[k]:>12.3g}" if r[k] is not None else "n/a" for k in keys))
    for e in args.explorers:
        sub = [r for r in results if r["explorer"] == e]
        for k in ("touching_genomes", "moved_cells"):
            v = [r[k] for r in sub]
            print(f"{e}: {k} {np.mean(v):.1f} +- {np.std(v):.1f} over {len(v)} seeds")


if __name__ == "__main__":
    main()
