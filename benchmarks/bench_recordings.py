"""What a run's Rerun recordings cost: bytes per dataset frame and the run's speed, for each `--rerun-frames`
mode against no recordings, with `generate --workers 2` on the same seed and attempts, in alternating rounds (this
machine's speed drifts). The dataset is the same in every mode; only the recordings differ.

Bytes per frame: the recordings' bytes over the frames of the episodes they cover (the dataset's frames). The
share of the run's time: 1 - (executed episodes/s with recordings) / (without), in the steady state.

    python benchmarks/bench_recordings.py --attempts 240 --rounds 2
    python benchmarks/bench_recordings.py --existing runs/base8000     # a finished run's recordings and dataset
    python benchmarks/bench_recordings.py --sink-cost runs/final8000 --episodes 200

``--sink-cost DIR``: the recording's own work per episode, timed alone on a finished run's episodes (read back from
its dataset): the worker's JPEG encoding of the logged frames and the coordinator's columns and file writing, for
each mode, against the run's wall seconds per executed episode (its sidecar's write times): the recordings' share
of the run's time, without the noise of timing whole runs. Opening the recording and its final flush are counted,
spread over the episodes timed, as a run spreads them over a commit segment's (about 300 episodes in a
paper-sized run): time 150 or more, on an otherwise idle machine.
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


def sink_cost(root: Path, n_episodes: int) -> None:
    """Time the recording's work on ``n_episodes`` episodes of a finished run, per mode."""
    import time
    import uuid
    from types import SimpleNamespace

    from babblegen.dataset.lerobot import column, episode_images, load_dataset
    from babblegen.dataset.sidecar import read_attempts, read_run_info
    from babblegen.exporters.rerun.columns import EpisodeColumns, JpegFrames
    from babblegen.exporters.rerun.layout import new_recording
    from babblegen.exporters.rerun.scene import Scene
    from babblegen.exporters.rerun.view import episode_data

    info, rows = read_run_info(root), read_attempts(root)
    ds = load_dataset(root, info["repo_id"])
    scene = Scene(info["task"], info.get("joint_names"))
    table = ds.hf_dataset.with_format("arrow")[:]
    names = ("observation.state", "observation.ee_pos", "observation.environment_state", "observation.contacts")
    data = {k: column(table, k) for k in (*names, "timestamp", "index")}
    total = ds.meta.total_episodes
    episodes = np.linspace(0, total - 1, min(n_episodes, total)).astype(int)
    loaded = []
    for e in episodes:
        meta = ds.meta.episodes[int(e)]
        a, b = int(meta["dataset_from_index"]), int(meta["dataset_to_index"])
        views = episode_images(ds, table, int(e), slice(a, b), data["timestamp"][a:b])
        loaded.append((int(e), a, b, views))
    executed = [r for r in rows if r["feasible"]]
    run_s = (rows[-1]["timings"]["written_at"] - rows[0]["timings"]["written_at"]) / max(1, len(executed))
    frames = sum(b - a for _, a, b, _ in loaded)
    print(f"{len(loaded)} episodes, {frames} frames; the run took {run_s * 1000:.0f} ms of wall time per episode")
    n_obj = len(scene.object_names)
    for mode in ("ends", "all"):
        jpeg = JpegFrames(frames=mode)
        with tempfile.TemporaryDirectory() as tmp:
            rec = new_recording(f"bench-{uuid.uuid4()}")
            rec.save(Path(tmp) / "bench.rrd")
            columns = EpisodeColumns(scene, mode)
            t_prepare = t_log = 0.0
            for e, a, b, views in loaded:
                head = views["head"]
                t0 = time.perf_counter()

                # what a worker prepares from: the episode's images by camera and kind
                others = {
                    c: {k: v for k, v in kinds.items() if (c, k) != ("head", "rgb")} for c, kinds in views.items()
                }
                prepared = jpeg(SimpleNamespace(images=head["rgb"], views=others))
                t_prepare += time.perf_counter() - t0
                t0 = time.perf_counter()
                columns.add(episode_data(data, e, slice(a, b), n_obj, float(ds.fps), prepared))
                t_log += time.perf_counter() - t0
            t0 = time.perf_counter()
            columns.send(rec)
            rec.flush()
            rec.disconnect()
            t_log += time.perf_counter() - t0
            size = (Path(tmp) / "bench.rrd").stat().st_size
        per = (t_prepare + t_log) / len(loaded)
        print(
            f"{mode}: {t_prepare / len(loaded) * 1000:.1f} ms JPEGs (worker) + {t_log / len(loaded) * 1000:.1f} ms "
            f"columns and file (coordinator) per episode = {per / run_s:.1%} of the run's time per episode; "
            f"{size / frames:.0f} B/frame"
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=240)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    p.add_argument("--existing", type=Path, help="report a finished run's recordings instead of running")
    p.add_argument("--sink-cost", type=Path, help="time the recording's work on a finished run's episodes")
    p.add_argument("--episodes", type=int, default=200, help="episodes for --sink-cost")
    args = p.parse_args()
    if args.sink_cost:
        sink_cost(args.sink_cost, args.episodes)
        return
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
