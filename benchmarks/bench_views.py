"""What each camera and kind of image costs: `generate --workers 2` with one set of views after another, in
alternating rounds (this machine's speed drifts), on the same seed and attempts.

For each set of views: executed episodes per second in the steady state (after the first generation), worker
seconds per episode (the movement and the episode's work after it: rendering, encoding), and bytes per episode
of each image feature (its video files, or its share of the data parquet for masks), from the dataset written.

    python benchmarks/bench_views.py --attempts 240 --rounds 2
    python benchmarks/bench_views.py --side 256 --sets head head+depth+masks
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

# name -> flags; "masks" is --segmentation
SETS = {
    "head": ["--cameras", "head", "--no-depth", "--no-segmentation"],
    "head+masks": ["--cameras", "head", "--no-depth", "--segmentation"],
    "head+depth": ["--cameras", "head", "--depth", "--no-segmentation"],
    "head+depth+masks": ["--cameras", "head", "--depth", "--segmentation"],
    "head+masks, front+masks": ["--cameras", "head,front", "--no-depth", "--segmentation"],
    "head+depth+masks, front": ["--config", "{front_rgb}"],
    "head+depth+masks, front+depth+masks": ["--cameras", "head,front", "--depth", "--segmentation"],
}


def front_colour_only(tmp: Path) -> Path:
    """A config file: the head camera with depth and masks, the front camera's colour alone."""
    path = tmp / "front_rgb.toml"
    path.write_text(
        '[[world.cameras]]\nname = "head"\nmount = "head"\ndepth = true\nsegmentation = true\n\n'
        '[[world.cameras]]\nname = "front"\nmount = "fixed"\neye = [1.75, -0.1, 1.45]\n'
        "target = [0.75, -0.1, 0.62]\nfov = 1.05\n"
    )
    return path


def measure(out: Path) -> dict:
    rows = [json.loads(line) for line in (out / "babblegen" / "attempts.jsonl").read_text().splitlines()]
    first_end = max(i for i, r in enumerate(rows) if r["generation"] == rows[0]["generation"])
    later = rows[first_end + 1 :]
    seconds = later[-1]["timings"]["written_at"] - rows[first_end]["timings"]["written_at"]
    executed = [r for r in rows if r["feasible"]]
    info = json.loads((out / "meta" / "info.json").read_text())
    n = len(executed)
    size = {}
    for key, ft in info["features"].items():
        if ft["dtype"] == "video":
            size[key] = sum(p.stat().st_size for p in (out / "videos" / key).rglob("*.mp4")) / n
    data = sum(p.stat().st_size for p in (out / "data").rglob("*.parquet"))
    masks = [k for k, ft in info["features"].items() if ft["dtype"] == "image"]
    if masks:
        import pyarrow.parquet as pq

        total = {k: 0 for k in masks}
        for p in (out / "data").rglob("*.parquet"):
            meta = pq.ParquetFile(p).metadata
            for g in range(meta.num_row_groups):
                for c in range(meta.num_columns):
                    col = meta.row_group(g).column(c)
                    name = col.path_in_schema.removesuffix(".bytes").removesuffix(".path")
                    if name in total:
                        total[name] += col.total_compressed_size
        size.update({k: v / n for k, v in total.items()})
    size["data parquet (all columns)"] = data / n
    return {
        "episodes_per_s": sum(r["feasible"] for r in later) / seconds,
        "worker_s": float(np.mean([r["timings"]["total"] + r["timings"].get("prepare", 0.0) for r in executed])),
        "render_s": float(np.mean([r["timings"]["render"] for r in executed])),
        "frames": float(np.mean([r["n_frames"] for r in executed])),
        "bytes": size,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--side", type=int, default=128, help="every camera's width and height")
    p.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    results: dict[str, list[dict]] = {name: [] for name in args.sets}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        config = front_colour_only(tmp)
        for r in range(args.rounds):
            order = args.sets if r % 2 == 0 else args.sets[::-1]
            for name in order:
                out = tmp / f"{len(results[name])}-{name.replace(' ', '').replace(',', '_')}"
                flags = [f.format(front_rgb=config) for f in SETS[name]]
                cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--no-progress"]
                cmd += ["--workers", "2", "--max-attempts", str(args.attempts), "--seed", str(args.seed)]
                cmd += ["--width", str(args.side), "--height", str(args.side), *flags]
                subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, "RUST_LOG": "off"})
                results[name].append(measure(out))
                print(f"round {r}: {name}: {results[name][-1]['episodes_per_s']:.2f} episodes/s", flush=True)
                subprocess.run(["rm", "-rf", str(out)], check=True)
    base = np.mean([m["episodes_per_s"] for m in results[args.sets[0]]])
    print(f"\n{args.side}x{args.side}, {args.attempts} attempts, {args.rounds} rounds, `generate --workers 2`")
    header = f"{'views':<38} {'episodes/s':>10} {'vs first':>8} {'worker s/ep':>11} {'render s/ep':>11}"
    print(header + "  bytes per episode")
    for name, ms in results.items():
        eps = np.mean([m["episodes_per_s"] for m in ms])
        sizes = {k: np.mean([m["bytes"][k] for m in ms]) for k in ms[0]["bytes"]}
        shown = ", ".join(f"{k.removeprefix('observation.images.')} {v / 1000:.0f} kB" for k, v in sizes.items())
        worker = np.mean([m["worker_s"] for m in ms])
        render = np.mean([m["render_s"] for m in ms])
        print(f"{name:<38} {eps:>10.2f} {eps / base:>8.2f} {worker:>11.3f} {render:>11.3f}  {shown}")
    (Path(tempfile.gettempdir()) / "bench_views.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
