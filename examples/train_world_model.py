"""Train a small world model on babbling data and ask which data trains it best: from the commanded joint
trajectory and the scene it starts from, predict which objects move and where each one ends up.

    python examples/train_world_model.py \\
        --train noveb_fixed=d/nf1,d/nf2,d/nf3 --train noveb_varied=d/nv1,d/nv2,d/nv3 \\
        --train random_varied=d/rv1,d/rv2,d/rv3 \\
        --test varied=d/test_nv,d/test_rv --test fixed=d/test_nf [--start masks|poses|none] [--json out.json]
    python examples/train_world_model.py --train noveb=d/nv1 --test varied=d/test_nv --epochs 50 --start poses
    python examples/train_world_model.py --train noveb=d/nv1 --test varied=d/test_nv --model objects --epochs 200

Per episode the input is the `action` column (commanded joints) resampled to --steps time steps, plus the start:
with --start masks (default), the head camera's instance masks of the first frame as one binary occupancy map
per object (mask == the object's id, from the feature's `info.ids`), area-averaged to --grid x --grid; with
--start poses, each object's first-frame x, y and yaw (as cos and sin, so it does not wrap) from
`observation.environment_state`, an upper bound; with --start none, the trajectory alone. Targets, from
`observation.environment_state`: each object's (dx, dy), last frame minus first, and whether it moves (its 3-D
displacement, as the sidecar's, exceeds --moved-threshold).

--model mlp (default) flattens every input into one network. --model objects is one network shared by every
object: with --start masks it sees that object's map, the other objects' maps summed and where the commanded arm
(its elbow, wrist and gripper link origins, by forward kinematics) passes in the head camera's image, in every
cell it crosses and where it is within 12 cm of the table, through a small convolutional network (--start none:
the same network with empty object maps); with --start poses, the arm's points relative to the object's start,
pooled over the path.

Each --train source is a name and one dataset per repeat: repeat r trains on the r-th dataset of every source (a
source given one dataset uses it in every repeat), on --n episodes of each (default: the smallest training
dataset's count, so every source trains on as many), drawn with the seed --seed + r. Each --test set is the
union of its datasets and is never trained on: training episodes whose genome (commanded movement, from the
sidecar DIR/babblegen/attempts.jsonl) appears in a test set are dropped. Reported per test set, mean ± std over
repeats: F1 of "moves" (per object and episode) and the median error of the predicted (dx, dy), in cm, over the
objects that truly moved, next to the trivial baseline "nothing moves". Deterministic for a given --seed: CPU,
one thread, seeded draws and initialisation.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # local datasets: never ask the Hub

import datasets
import numpy as np
import torch
from torch import nn
from world_model_data import Episodes, load_episodes
from world_model_nets import build

BASELINE = "nothing moves"
DISP_SCALE = 10.0  # displacements are learned in decimetres, so both losses have similar magnitudes
CLIP = 5.0  # normalised inputs are clipped to +-CLIP standard deviations of the training data


def normalise(x: np.ndarray, mean: np.ndarray, std: np.ndarray) -> torch.Tensor:
    """Inputs standardised with the training data's statistics and clipped, so that inputs that barely varied in
    training (a map cell an object rarely covered) cannot swamp the model on other data."""
    return torch.tensor(np.clip((x - mean) / std, -CLIP, CLIP), dtype=torch.float32)


def train(
    data: Episodes, epochs: int, seed: int, hidden: int, batch: int = 32, net: dict | None = None
) -> tuple[nn.Module, np.ndarray, np.ndarray]:
    """Fit a model (the network ``net`` names, see `build`); returns it with the input normalisation (mean, std)
    taken from its own training data. Networks other than the MLP see everything after the trajectory as it is
    (maps as shares of a cell, positions in metres), so that geometry means the same on any data."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    mean, std = data.x.mean(axis=0), data.x.std(axis=0)
    std[std < 1e-6] = 1.0  # an input constant in training (every start the same) is not blown up at test time
    if net is not None:
        mean[net["n_trajectory"] :], std[net["n_trajectory"] :] = 0.0, 1.0
    xt = normalise(data.x, mean, std)
    dt = torch.tensor(data.disp * DISP_SCALE, dtype=torch.float32)
    mt = torch.tensor(data.moved, dtype=torch.float32)
    model = build(net, xt.shape[1], dt.shape[1], hidden)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=1e-3)
    bce = nn.BCEWithLogitsLoss()
    for _ in range(epochs):
        order = rng.permutation(len(xt))
        for i in range(0, len(order), batch):
            idx = torch.as_tensor(order[i : i + batch])
            pred_disp, logit = model(xt[idx])
            loss = nn.functional.mse_loss(pred_disp, dt[idx]) + bce(logit, mt[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    return model.eval(), mean, std


def predict(model: nn.Module, mean: np.ndarray, std: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted (dx, dy) in metres and "moves" for each row of ``x``."""
    with torch.no_grad():
        d, logit = model(normalise(x, mean, std))
    return d.numpy() / DISP_SCALE, logit.numpy() > 0


def scores(pred_disp: np.ndarray, pred_moved: np.ndarray, truth: Episodes) -> dict[str, float]:
    """F1 of the class "moves" over object-episodes (nan when neither truth nor prediction has one) and the
    median Euclidean error of (dx, dy), cm, over the object-episodes that truly moved (nan if none did)."""
    tp = float((pred_moved & truth.moved).sum())
    denominator = float(pred_moved.sum() + truth.moved.sum())
    err = np.linalg.norm(pred_disp - truth.disp, axis=-1)[truth.moved] * 100
    return {
        "f1": 2 * tp / denominator if denominator else float("nan"),
        "median_cm": float(np.median(err)) if err.size else float("nan"),
    }


def experiment(
    sources: dict[str, list[Episodes]],
    tests: dict[str, Episodes],
    n: int,
    epochs: int,
    seed: int,
    hidden: int,
    net: dict | None = None,
) -> dict[str, dict[str, dict[str, list[float]]]]:
    """Per test set, per model (the baseline, then every source), each score's value in every repeat."""
    repeats = max(len(v) for v in sources.values())
    out = {t: {m: {"f1": [], "median_cm": []} for m in (BASELINE, *sources)} for t in tests}
    for r in range(repeats):
        for test, truth in tests.items():
            for key, value in scores(np.zeros_like(truth.disp), np.zeros_like(truth.moved), truth).items():
                out[test][BASELINE][key].append(value)
        for name, parts in sources.items():
            data = parts[r % len(parts)]
            idx = np.sort(np.random.default_rng(seed + r).permutation(len(data.x))[:n])
            model, mean, std = train(data.take(idx), epochs, seed + r, hidden, net=net)
            for test, truth in tests.items():
                for key, value in scores(*predict(model, mean, std, truth.x), truth).items():
                    out[test][name][key].append(value)
    return out


def cell(values: list[float], digits: int) -> str:
    """mean ± std of the values that are numbers; "n/a" if none is."""
    v = np.asarray(values, dtype=float)
    v = v[~np.isnan(v)]
    if not len(v):
        return "n/a"
    return f"{v.mean():.{digits}f} ± {v.std():.{digits}f}" if len(v) > 1 else f"{v.mean():.{digits}f}"


def markdown(results: dict[str, dict[str, list[float]]]) -> list[str]:
    """One test set's results as a markdown table."""
    lines = [("model", "moves: F1", "median error, moved (cm)")]
    lines += [(m, cell(s["f1"], 3), cell(s["median_cm"], 1)) for m, s in results.items()]
    widths = [max(len(line[i]) for line in lines) for i in range(3)]
    lines.insert(1, tuple("-" * w for w in widths))
    return ["| " + " | ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)) + " |" for line in lines]


def named_dirs(text: str) -> tuple[str, list[Path]]:
    """argparse type of NAME=DIR[,DIR...]."""
    name, sep, dirs = text.partition("=")
    paths = [Path(d) for d in dirs.split(",") if d]
    if not sep or not name or not paths:
        raise argparse.ArgumentTypeError(f"expected NAME=DIR[,DIR...], got {text!r}")
    return name, paths


def describe(root: Path, data: Episodes) -> str:
    """One line on a loaded dataset: its explorer, starts, episodes and how often objects move."""
    config = json.loads((root / "babblegen" / "run.json").read_text()).get("config", {})
    starts = config.get("world", {}).get("starts", "fixed")
    return (
        f"{root}: {config.get('explorer', '?')}, {starts} starts, {len(data.x)} episodes of "
        f"{len(np.unique(data.genomes))} genomes; something moves in {data.moved.any(axis=1).mean():.0%}, "
        f"{data.moved.mean():.0%} of object-episodes"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--train", type=named_dirs, action="append", required=True, metavar="NAME=DIR[,DIR...]")
    parser.add_argument("--test", type=named_dirs, action="append", required=True, metavar="NAME=DIR[,DIR...]")
    parser.add_argument("--start", choices=("masks", "poses", "none"), default="masks", help="[default: masks]")
    parser.add_argument(
        "--model",
        choices=("mlp", "conv", "objects"),
        default="mlp",
        help="mlp: every input flattened; conv: the start's object maps and the commanded tool path's maps in the "
        "head camera's view through a convolutional network (needs --start masks); objects: one network shared by "
        "every object, that sees the arm's path beside that object's map (--start masks; with --start none the "
        "maps are empty) or relative to its position (--start poses) [default: mlp]",
    )
    parser.add_argument("--n", type=int, default=None, help="training episodes per source [default: smallest]")
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--hidden", type=int, default=128)
    parser.add_argument("--steps", type=int, default=16, help="time steps the trajectory is resampled to")
    parser.add_argument("--grid", type=int, default=16, help="occupancy maps are pooled to GRID x GRID")
    parser.add_argument("--moved-threshold", type=float, default=0.01, help="metres: an object 'moves'")
    parser.add_argument("--json", type=Path, default=None, help="also write every number to this file")
    args = parser.parse_args()
    for flag in ("train", "test"):
        names = [name for name, _ in getattr(args, flag)]
        if len(set(names)) < len(names):
            parser.error(f"--{flag} names must differ: {names}")
    repeats = max(len(dirs) for _, dirs in args.train)
    if any(len(dirs) not in (1, repeats) for _, dirs in args.train):
        parser.error(f"every --train source needs 1 or {repeats} datasets (one per repeat)")
    test_dirs = {d.resolve() for _, dirs in args.test for d in dirs}
    if args.model == "conv" and args.start != "masks":
        parser.error("--model conv looks at the start's masks: use --start masks")
    if clash := sorted(str(d) for _, dirs in args.train for d in dirs if d.resolve() in test_dirs):
        parser.error(f"trained on and tested on: {clash}")

    datasets.disable_progress_bars()
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    cache: dict[Path, Episodes] = {}

    def load(root: Path) -> Episodes:
        if root.resolve() not in cache:
            cache[root.resolve()] = load_episodes(
                root, args.steps, args.start, args.grid, args.moved_threshold, model=args.model
            )
            print(describe(root, cache[root.resolve()]))
        return cache[root.resolve()]

    print("test sets:")
    tests = {name: Episodes.union([load(d) for d in dirs]) for name, dirs in args.test}
    held_out = set(np.concatenate([t.genomes for t in tests.values()]).tolist())
    print("training sources:")
    sources: dict[str, list[Episodes]] = {}
    for name, dirs in args.train:
        sources[name] = []
        for d in dirs:
            data = load(d)
            keep = np.flatnonzero([g not in held_out for g in data.genomes])
            if len(keep) < len(data.x):
                print(f"  {d}: {len(data.x) - len(keep)} episodes dropped, their genomes are in a test set")
            sources[name].append(data.take(keep))
    Episodes.union([*tests.values(), *(p for parts in sources.values() for p in parts)])  # same objects everywhere
    smallest = min(len(p.x) for parts in sources.values() for p in parts)
    n = smallest if args.n is None else min(args.n, smallest)
    if n < 2:
        raise SystemExit(f"too few training episodes: {smallest} in the smallest training dataset")
    n_in = next(iter(tests.values())).x.shape[1]
    print(
        f"per model: {n} training episodes, {n_in} inputs (--start {args.start}), {args.epochs} epochs; "
        f"{repeats} repeats"
    )

    n_objects = len(next(iter(tests.values())).objects)
    net = None
    if args.model == "conv":
        net = {"kind": "conv", "n_trajectory": args.steps * 7, "channels": n_objects + 2, "grid": args.grid}
    elif args.model == "objects" and args.start in ("masks", "none"):
        net = {"kind": "object_maps", "n_trajectory": args.steps * 7, "grid": args.grid}
    elif args.model == "objects":
        net = {"kind": "object_poses", "n_trajectory": args.steps * 7, "steps": args.steps}
    results = experiment(sources, tests, n, args.epochs, args.seed, args.hidden, net)
    for test, by_model in results.items():
        truth = tests[test]
        print(
            f"\ntest set {test}: {len(truth.x)} episodes, {int(truth.moved.sum())} of {truth.moved.size} "
            f"object-episodes move"
        )
        print("\n".join(markdown(by_model)))
    print(
        f"\nF1 of 'moves' per object-episode (moves: displaced over {args.moved_threshold * 100:g} cm); median "
        f"error of the predicted (dx, dy) over the object-episodes that moved; mean ± std over {repeats} repeats."
    )
    if args.json is not None:
        report = {"args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}, "n_train": n}
        report["args"]["train"] = {name: [str(d) for d in dirs] for name, dirs in args.train}
        report["args"]["test"] = {name: [str(d) for d in dirs] for name, dirs in args.test}
        report["tests"] = {
            t: {"episodes": len(e.x), "moved": int(e.moved.sum()), "n": e.moved.size} for t, e in tests.items()
        }
        report["results"] = results
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1) + "\n")
        print(f"all numbers -> {args.json}")


if __name__ == "__main__":
    main()
