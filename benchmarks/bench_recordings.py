"""What a run's Rerun recordings cost: bytes per dataset frame and the run's speed, for each `--rerun-frames`
mode against no recordings, with `generate --workers 2` on the same seed and attempts, in alternating rounds (this
machine's speed drifts). The dataset is the same in every mode; only the recordings differ.

Bytes per frame: the recordings' bytes over the frames of the episodes they cover (the dataset's frames). The
share of the run's time: 1 - (executed episodes/s with recordings) / (without), in the steady state.

    python benchmarks/bench_recordings.py --attempts 240 --rounds 2
    python benchmarks/bench_recordings.py --existing runs/base8000     # a finished run's recordings and dataset
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

sys.path.insert(0, str(Path(__file__).parent))
from bench_views import measure  # noqa: E402  (a sibling script, not a package)

MODES = {
    "none": ["--no-rerun"],
    "ends": ["--rerun", "--rerun-frames", "ends"],
    "all": ["--rerun", "--rerun-frames", "all"],
}


def sizes(out: Path) -> dict[str, float]:
    """Bytes of a run's recordings and of its dataset's data and videos, frames and episodes."""
    info = json.loads((out / "meta" / "info.json").read_text())
    recordings = sum(p.stat().st_size for p in (out / "babblegen" / "rerun").glob("*.rrd"))
    dataset = sum(p.stat().st_size for d in ("data", "videos") for p in (out / d).rglob("*") if p.is_file())
    frames, episodes = int(info["total_frames"]), int(info["total_episodes"])
    return {
        "recording_bytes": recordings,
        "dataset_bytes": dataset,
        "frames": frames,
        "episodes": episodes,
        "bytes_per_frame": recordings / max(1, frames),
        "bytes_per_episode": recordings / max(1, episodes),
        "recordings_vs_dataset": recordings / max(1, dataset),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    p.add_argument("--existing", type=Path, help="report a finished run's recordings instead of running")
    args = p.parse_args()
    if args.existing:
        print(json.dumps(sizes(args.existing), indent=1))
        return
    results: dict[str, list[dict]] = {m: [] for m in args.modes}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for mode in args.modes if r % 2 == 0 else args.modes[::-1]:
                out = Path(tmp) / f"{mode}-{r}"
                cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--no-progress"]
                cmd += ["--workers", "2", "--max-attempts", str(args.attempts), "--seed", str(args.seed), *MODES[mode]]
                subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, "RUST_LOG": "off"})
                m = {**measure(out), **sizes(out)}
                results[mode].append(m)
                print(f"round {r}: {mode}: {m['episodes_per_s']:.2f} episodes/s, {m['bytes_per_frame']:.0f} B/frame")
                subprocess.run(["rm", "-rf", str(out)], check=True)
    base = np.mean([m["episodes_per_s"] for m in results[args.modes[0]]])
    print(f"\n{args.attempts} attempts, seed {args.seed}, {args.rounds} rounds, `generate --workers 2`")
    print(
        f"{'mode':<6} {'episodes/s':>10} {'vs ' + args.modes[0]:>8} {'B/frame':>8} {'B/episode':>10} {'vs dataset':>10}"
    )
    for mode, ms in results.items():
        eps = np.mean([m["episodes_per_s"] for m in ms])
        per_frame = np.mean([m["bytes_per_frame"] for m in ms])
        per_episode = np.mean([m["bytes_per_episode"] for m in ms])
        share = np.mean([m["recordings_vs_dataset"] for m in ms])
        print(f"{mode:<6} {eps:>10.2f} {eps / base:>8.3f} {per_frame:>8.0f} {per_episode:>10.0f} {share:>10.3f}")
    (Path(tempfile.gettempdir()) / "bench_recordings.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
