"""NovEB against random motor babbling over the same number of attempted movements (the paper's Fig. 4).

Runs the real explorer -> world -> descriptor loop (no LeRobot encoding, which does not change what is
explored) for each explorer and seed, and reports contacts per attempt, per object, and how widely the
objects' final positions spread. Per-attempt rows go to OUT/<explorer>-<seed>.jsonl.

    python benchmarks/compare_explorers.py --attempts 2000 --seeds 0 1 2 --jobs 2 --out runs/compare
"""

from __future__ import annotations

import argparse
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np


def run_one(explorer_name: str, seed: int, attempts: int, out: str) -> dict:
    from babblegen.config import RunConfig
    from babblegen.descriptors import make_descriptor
    from babblegen.evaluation import LocalEvaluator
    from babblegen.explorers import make_explorer
    from babblegen.run import command_for
    from babblegen.tasks import get_task

    cfg = RunConfig(explorer=explorer_name, seed=seed)
    task = get_task(cfg.task)
    ev = LocalEvaluator(task, cfg.world, seed)
    w = ev.world
    gens = math.ceil(attempts / cfg.noveb.population)
    ecfg = (
        {**cfg.noveb.__dict__, "generations": gens}
        if explorer_name == "noveb"
        else {"population": cfg.noveb.population, "generations": gens, "k": cfg.noveb.k}
    )
    ex = make_explorer(explorer_name, ecfg, rng_seed=seed, joint_limits=w.kin.limits, start_norm=w.start_norm)
    desc = make_descriptor("phash")
    names = task.object_names
    path = Path(out) / f"{explorer_name}-{seed}.jsonl"
    t0 = time.perf_counter()
    with open(path, "w") as f:
        while not ex.done:
            cands = ex.ask()
            rollouts = ev.evaluate([command_for(c) for c in cands], [c.index for c in cands])
            codes = [desc(r.after_image) if r.feasible else None for r in rollouts]
            evals = ex.tell(cands, codes)
            for c, r, e in zip(cands, rollouts, evals, strict=True):
                row = {"attempt": c.index, "feasible": r.feasible, "reason": r.reason, "novelty": e.novelty}
                if r.feasible:
                    row["touched"] = dict(zip(names, map(bool, r.touched), strict=True))
                    row["final_xy"] = dict(zip(names, np.round(r.final_poses[:, :2], 4).tolist(), strict=True))
                f.write(json.dumps(row) + "\n")
    ev.close()
    return summarise(path, names) | {"explorer": explorer_name, "seed": seed, "seconds": time.perf_counter() - t0}


def summarise(path: Path, names: list[str], limit: int | None = None) -> dict:
    rows = [json.loads(line) for line in path.read_text().splitlines()][:limit]
    ex = [r for r in rows if r["feasible"]]
    contacts = sum(any(r["touched"].values()) for r in ex)
    per_object = {n: sum(r["touched"][n] for r in ex) for n in names}
    cells = {n: len({tuple(np.floor(np.array(r["final_xy"][n]) / 0.02).astype(int)) for r in ex}) for n in names}
    return {
        "attempts": len(rows),
        "executed": len(ex),
        "contacts": contacts,
        "contacts_per_attempt": contacts / len(rows),
        "per_object": per_object,
        "occupied_2cm_cells": cells,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=2000)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="runs/compare")
    p.add_argument(
        "--summarise",
        type=int,
        metavar="N",
        default=None,
        help="do not run: summarise the first N attempts of every run already in --out (runs still in progress too)",
    )
    args = p.parse_args()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    jobs = [(e, s) for s in args.seeds for e in ("noveb", "random")]
    if args.summarise:
        from babblegen.tasks import get_task

        names = get_task("noveb_tabletop").object_names
        results = [
            summarise(Path(args.out) / f"{e}-{s}.jsonl", names, args.summarise) | {"explorer": e, "seed": s}
            for e, s in jobs
        ]
    else:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(
                pool.map(run_one, *zip(*jobs, strict=True), [args.attempts] * len(jobs), [args.out] * len(jobs))
            )
    (Path(args.out) / "summary.json").write_text(json.dumps(results, indent=2))
    print(f"{'explorer':>8} {'seed':>4} {'attempts':>8} {'executed':>8} {'contacts':>8} {'per att.':>8}  per object")
    for r in results:
        print(
            f"{r['explorer']:>8} {r['seed']:>4} {r['attempts']:>8} {r['executed']:>8} {r['contacts']:>8} "
            f"{r['contacts_per_attempt']:>8.3f}  {r['per_object']}  cells {r['occupied_2cm_cells']}"
        )
    for e in ("noveb", "random"):
        c = [r["contacts_per_attempt"] for r in results if r["explorer"] == e]
        print(f"{e}: contacts per attempt {np.mean(c):.3f} +- {np.std(c):.3f} over {len(c)} seeds")
    nov = np.mean([r["contacts"] for r in results if r["explorer"] == "noveb"])
    ran = np.mean([r["contacts"] for r in results if r["explorer"] == "random"])
    print(f"ratio NovEB / random contacts: {nov / max(ran, 1e-9):.1f}")


if __name__ == "__main__":
    main()
