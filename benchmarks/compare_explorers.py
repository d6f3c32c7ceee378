"""NovEB against random motor babbling over the same number of attempted movements (the paper's Fig. 4), and
the behaviour-descriptor variants the default was chosen from.

Runs the real explorer -> world -> descriptor loop, asking and telling in the run loop's order (so lagged
generations explore as in `generate`), without LeRobot encoding and rendering only the behaviour image (neither
changes what is explored), for each explorer and seed, stopping after ``--attempts`` attempted movements (clones,
children repeating a tried genome, reuse its outcome and are not attempts), and reports the dataset measures of
``babblegen report``: distinct genomes executed, duplicate episodes, distinct genomes touching each object, the
moved objects' final positions in 2 cm cells, the share of executed attempts with novelty > 0, and how many
movements the search leaves available to run at once (the attempts of every open generation after each tell).
Per-attempt rows (sidecar layout) go to OUT/<label>.jsonl.

    python benchmarks/compare_explorers.py --attempts 1200 --seeds 0 1 2 --jobs 2 --out runs/compare
    python benchmarks/compare_explorers.py --starts varied --explorers noveb random random_waypoints --seeds 1 2 3

With ``--starts varied`` every row also records its start (the settled poses at the first frame), and the summary
counts distinct start layouts, distinct changes (object, 2 cm cell of its displacement from its own start), the
largest move of an untouched object between the first two frames, and starts with an object off the table.
    python benchmarks/compare_explorers.py --explorers noveb --descriptor phash --crop none --out runs/full-frame
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np


def cpu_seconds() -> float:
    """User + system CPU seconds of this process so far, all its threads."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run_one(explorer_name: str, seed: int, attempts: int, out: str, options: dict[str, Any]) -> dict:
    from collections import deque

    from babblegen.assembly import arm_info, build_descriptor, build_explorer
    from babblegen.config import RunConfig
    from babblegen.descriptors import describe_rollout
    from babblegen.evaluation import seeded_rollout, warm_up
    from babblegen.explorers.base import ask_while_possible
    from babblegen.exporters.report import diversity
    from babblegen.exporters.sidecar import start_entry
    from babblegen.run import command_for
    from babblegen.tasks import get_task
    from babblegen.world.world import World, WorldSettings

    cfg = RunConfig.from_dict({"explorer": explorer_name, "seed": seed, "world": {"starts": options["starts"]}})
    task = get_task(cfg.task)
    settings = WorldSettings(**{**cfg.world.to_dict(), **options.get("world", {})})
    world = World(task, settings, seed=seed)
    warm_up(world, None)
    ex = build_explorer(cfg, arm_info(task), options.get("explorer"))
    desc = build_descriptor(cfg, options.get("descriptor"))
    names = task.object_names
    label = f"{options.get('label', explorer_name)}-{options['starts']}-{seed}"
    path = Path(out) / f"{label}.jsonl"
    t0, cpu0, clones, available = time.perf_counter(), cpu_seconds(), 0, []
    # the run loop's order of asks and tells (`Run._loop`), so that this explores exactly as `generate` does
    open_batches = deque(ask_while_possible(ex, attempts, cfg.noveb.generations))
    with open(path, "w") as f:
        while open_batches:
            cands = open_batches.popleft()
            # only the behaviour image is rendered: the frames in between change nothing the search sees
            rollouts = [seeded_rollout(world, command_for(c), seed, c.index, defer_render=True) for c in cands]
            codes = [describe_rollout(desc, r) if r.feasible else None for r in rollouts]
            evals = ex.tell(cands, codes)
            clones += len(ex.last_clones)
            open_batches.extend(ask_while_possible(ex, attempts, cfg.noveb.generations))
            available.append(sum(len(b) for b in open_batches))
            for c, r, e, code in zip(cands, rollouts, evals, codes, strict=True):
                row = {
                    "attempt": c.index,
                    "generation": c.generation,
                    "kind": c.kind,
                    "genome": np.asarray(c.genome).tolist(),
                    "start": start_entry(c),
                    "feasible": r.feasible,
                    "reason": r.reason,
                    "novelty": e.novelty,
                    "archived": e.archived,
                    "timings": {k: round(v, 4) for k, v in r.timings.items()},
                }
                if r.feasible:
                    row["descriptor"] = desc.hex(code) if hasattr(desc, "hex") else None
                    row["n_frames"] = len(r.frames)
                    row["touched"] = dict(zip(names, map(bool, r.touched), strict=True))
                    row["displacement"] = dict(zip(names, np.round(r.displacement, 6).tolist(), strict=True))
                    row["final_poses"] = dict(zip(names, np.round(r.final_poses, 6).tolist(), strict=True))
                    row["start_poses"] = dict(zip(names, np.round(r.start_poses, 6).tolist(), strict=True))
                    first = r.frames.object_poses[:2, :, :3]  # an untouched object's move between frames 0 and 1
                    step = np.linalg.norm(first[-1] - first[0], axis=1)[~r.frames.contacts[:2].any(axis=0)]
                    row["first_step_untouched_m"] = round(float(step.max(initial=0.0)), 6)
                f.write(json.dumps(row) + "\n")
    world.close()
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    executed = [r for r in rows if r["feasible"]]
    t = task.table
    off_table = sum(
        any(
            abs(p[0] - t.center[0]) > t.half_extents[0]
            or abs(p[1] - t.center[1]) > t.half_extents[1]
            or p[2] < task.table_top
            for p in r["start_poses"].values()
        )
        for r in executed
    )
    return {
        "label": label,
        "explorer": explorer_name,
        "starts": options["starts"],
        "starts_not_used": sum(r["reason"].startswith("start_") for r in rows),
        "starts_off_table": off_table,
        "first_step_untouched_max_m": max((r["first_step_untouched_m"] for r in executed), default=0.0),
        "seconds_per_executed": (time.perf_counter() - t0) / max(1, len(executed)),
        "seed": seed,
        "attempts": len(rows),
        "executed": len(executed),
        "feasible_share": len(executed) / max(1, len(rows)),
        "contacts": sum(any((r.get("touched") or {}).values()) for r in rows),
        "clones": clones,
        "generations": ex.generation,
        "attempts_per_generation": len(rows) / max(1, ex.generation),
        # movements that could run at once: the attempts of every open generation, after each tell
        "available_mean": float(np.mean(available[1:] or [0])),
        "available_p10": float(np.percentile(available[1:] or [0], 10)),
        "frames_per_episode": float(np.mean([r["n_frames"] for r in executed] or [0])),
        "waypoints_per_episode": float(
            np.mean([len(r["genome"]) for r in executed if r["kind"] == "ee_waypoints"] or [1])
        ),
        "seconds": time.perf_counter() - t0,
        # CPU seconds of this process (rendering threads included): comparable when jobs share the cores
        "cpu_seconds": cpu_seconds() - cpu0,
        **diversity(rows, names),
    }


def _value(text: str) -> Any:
    """A --set/--world value: a JSON literal (number, true, false, null), else the string."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=1200)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument(
        "--explorers", nargs="+", default=["noveb", "random"], choices=["noveb", "random", "random_waypoints"]
    )
    p.add_argument("--starts", default="fixed", choices=["fixed", "varied"])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default="runs/compare")
    p.add_argument("--label", default=None, help="name prefix of the rows files (default: the explorer)")
    p.add_argument("--descriptor", default=None, help="descriptor name (default: the run default)")
    p.add_argument("--hash-size", type=int, default=None)
    p.add_argument("--crop", default=None, help="x0,y0,x1,y1 fractions, or 'none' for the full frame")
    p.add_argument("--camera", type=int, default=None, help="square camera resolution in pixels")
    p.add_argument("--literal", action="store_true", help="the paper's literal procedure (clones re-simulated)")
    p.add_argument(
        "--world",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a world setting, e.g. max_joint_speed=2.1 (repeatable)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an explorer option, e.g. tie_break=oldest or reuse_clones=false (repeatable)",
    )
    args = p.parse_args()
    options: dict[str, Any] = {"descriptor": {}, "world": {}, "explorer": {}, "starts": args.starts}
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
        options["explorer"][key] = _value(value)
    for item in args.world:
        key, _, value = item.partition("=")
        options["world"][key] = _value(value)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    jobs = [(e, s) for s in args.seeds for e in args.explorers]
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = []
        for e, s in jobs:
            opts = {**options, "label": f"{args.label}-{e}" if args.label else e}
            futures.append(pool.submit(run_one, e, s, args.attempts, args.out, opts))
        results = [f.result() for f in futures]
    summary = f"summary-{args.label or 'compare'}-{args.starts}.json"
    (Path(args.out) / summary).write_text(json.dumps(results, indent=2))
    keys = (
        "attempts",
        "executed",
        "clones",
        "duplicate_episodes",
        "contacts",
        "touching_genomes",
        "moved_cells",
        "novelty_positive_share",
        "changes",
        "start_layouts",
        "starts_not_used",
        "starts_off_table",
        "first_step_untouched_max_m",
        "seconds_per_executed",
        "feasible_share",
        "attempts_per_generation",
        "available_mean",
        "available_p10",
        "waypoints_per_episode",
        "frames_per_episode",
        "cpu_seconds",
    )
    print(f"{'run':>24} " + " ".join(f"{k[:12]:>12}" for k in keys))
    for r in results:
        print(f"{r['label']:>24} " + " ".join(f"{r[k]:>12.3g}" if r[k] is not None else "n/a" for k in keys))
    for e in args.explorers:
        sub = [r for r in results if r["explorer"] == e]
        for k in ("touching_genomes", "moved_cells", "changes", "start_layouts"):
            v = [r[k] for r in sub if r[k] is not None]
            if v:
                print(f"{e}: {k} {np.mean(v):.1f} +- {np.std(v):.1f} over {len(v)} seeds")


if __name__ == "__main__":
    main()
