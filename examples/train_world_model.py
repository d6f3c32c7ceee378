"""Train a small world model on babbling data: from the commanded joint trajectory, predict where every object
ends up (its horizontal displacement) and which objects move. Then ask the NovEB paper's open question: does
data from NovEB train a better model than the same number of random-babbling episodes?

    python examples/train_world_model.py --noveb DIR_A --random DIR_B [--epochs 300] [--seed 0] [--repeats 3]

Per episode, the input is the `action` column (commanded joint positions) resampled to --steps time steps
(optionally with the tool path `observation.ee_pos`, and with --before the head camera's masks or depth map of
the first frame, 16 x 16); the targets come from `observation.environment_state`:
last frame minus first frame, (dx, dy) per object, and "moved" = displaced more than --moved-threshold metres.

Each repeat holds out about the same number of episodes from both datasets as one common test set, trains one
model on N NovEB episodes and one on N random episodes (N equal, the rest of each dataset or --n), and
evaluates both on that test set, next to the trivial baseline "nothing moves". The split is by genome (read
from the sidecar, DIR/babblegen/attempts.jsonl): every episode of one commanded movement lands on the same side,
so a model is never tested on a movement it was trained on. Deterministic for a given --seed: CPU, one
thread, seeded splits and initialisation.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # local datasets: never ask the Hub

import datasets
import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from torch import nn


@dataclass
class Episodes:
    """One dataset as fixed-size arrays, one row per episode."""

    source: str
    x: np.ndarray  # (E, steps * channels [+ pixels]) commanded joints (and tool path) resampled in time, flattened
    disp: np.ndarray  # (E, n_objects, 2) final minus first object position, metres
    moved: np.ndarray  # (E, n_objects) bool
    object_names: list[str]
    genome: np.ndarray  # (E,) int: episodes with equal values executed the same genome


def resample(seq: np.ndarray, steps: int) -> np.ndarray:
    """A (T, C) sequence linearly resampled to (steps, C) over normalised time."""
    t_old = np.linspace(0.0, 1.0, len(seq))
    t_new = np.linspace(0.0, 1.0, steps)
    return np.stack([np.interp(t_new, t_old, seq[:, c]) for c in range(seq.shape[1])], axis=1)


def load_episodes(
    root: Path, source: str, steps: int, with_ee: bool, threshold: float, before: str | None = None
) -> Episodes:
    """Read a dataset's per-frame columns and turn each episode into one example; with ``before``
    ("masks" or "depth"), the head camera's instance masks or depth map of the episode's first frame, averaged
    down to 16 x 16, join the input."""
    repo_id = json.loads((root / "babblegen" / "run.json").read_text())["repo_id"]
    ds = LeRobotDataset(repo_id, root=root)
    objects = list(ds.meta.features["observation.contacts"]["names"])
    columns = ["episode_index", "action", "observation.environment_state", *(["observation.ee_pos"] if with_ee else [])]
    table = ds.hf_dataset.select_columns(columns).with_format("numpy")[:]
    episode = np.asarray(table["episode_index"]).reshape(-1)
    action = np.asarray(table["action"], dtype=np.float64)
    env = np.asarray(table["observation.environment_state"], dtype=np.float64).reshape(len(episode), -1, 7)
    inputs = np.concatenate([action, np.asarray(table["observation.ee_pos"])], axis=1) if with_ee else action
    xs, disps = [], []
    view = {"masks": "observation.images.head_segmentation", "depth": "observation.images.head_depth"}.get(before)
    if view is not None and view not in ds.meta.features:
        raise SystemExit(f"{root} has no {view} (recorded with --no-{'segmentation' if before == 'masks' else before})")
    for e in np.unique(episode):
        rows = np.flatnonzero(episode == e)  # frames in order within an episode
        x = resample(inputs[rows], steps).ravel()
        if view is not None:
            image = ds[int(rows[0])][view][0][None, None].float()  # (1, 1, H, W): ids / 255, or millimetres
            x = np.concatenate([x, torch.nn.functional.adaptive_avg_pool2d(image, 16).numpy().ravel()])
        xs.append(x)
        disps.append(env[rows[-1], :, :2] - env[rows[0], :, :2])
    if not xs:
        raise SystemExit(f"{root} holds no episodes")
    disp = np.stack(disps)
    moved = np.linalg.norm(disp, axis=2) > threshold
    return Episodes(source, np.stack(xs), disp, moved, objects, genome_groups(root, np.unique(episode)))


def genome_groups(root: Path, episodes: np.ndarray) -> np.ndarray:
    """For each episode index, a group id shared by all episodes that executed the same genome (sidecar)."""
    by_episode: dict[int, str] = {}
    with open(root / "babblegen" / "attempts.jsonl") as f:
        for line in f:
            row = json.loads(line)
            if row.get("episode_index") is not None:
                by_episode[int(row["episode_index"])] = f"{row.get('kind')}:{json.dumps(row['genome'])}"
    ids: dict[str, int] = {}
    return np.array([ids.setdefault(by_episode[int(e)], len(ids)) for e in episodes])


class WorldModel(nn.Module):
    """MLP: flattened trajectory -> per-object displacement (dx, dy) and a "moves" logit."""

    def __init__(self, n_in: int, n_objects: int, hidden: int = 128):
        super().__init__()
        self.n_objects = n_objects
        self.net = nn.Sequential(
            nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3 * n_objects)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(x.flatten(1)).view(-1, self.n_objects, 3)
        return out[..., :2], out[..., 2]


_KEYS = ("x", "disp", "moved")
DISP_SCALE = 10.0  # displacements are learned in decimetres, so both losses have similar magnitudes


def train(
    x: np.ndarray, disp: np.ndarray, moved: np.ndarray, epochs: int, seed: int, hidden: int, batch: int = 32
) -> tuple[WorldModel, np.ndarray, np.ndarray]:
    """Fit a model; returns it with the input normalisation (mean, std) taken from its own training data."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    mean, std = x.mean(axis=0), x.std(axis=0) + 1e-3
    xt = torch.tensor((x - mean) / std, dtype=torch.float32)
    dt = torch.tensor(disp * DISP_SCALE, dtype=torch.float32)
    mt = torch.tensor(moved, dtype=torch.float32)
    model = WorldModel(xt[0].numel(), disp.shape[1], hidden)
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


def predict(model: WorldModel, mean: np.ndarray, std: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    with torch.no_grad():
        d, logit = model(torch.tensor((x - mean) / std, dtype=torch.float32))
    return d.numpy() / DISP_SCALE, logit.numpy() > 0


def scores(
    pred_disp: np.ndarray, pred_moved: np.ndarray, disp: np.ndarray, moved: np.ndarray, source: np.ndarray
) -> dict[str, float]:
    """MSE of the displacement (cm^2 per object and axis) on the whole test set, on its NovEB and random parts
    and on the episodes where something moved; accuracy and F1 of "which objects move" (F1 of the class "moves":
    0 for a model that never says so)."""
    err = ((pred_disp - disp) * 100) ** 2

    def mse(mask: np.ndarray) -> float:
        return float(err[mask].mean()) if mask.any() else float("nan")

    tp = (pred_moved & moved).sum()
    return {
        "mse": float(err.mean()),
        "mse_noveb": mse(source == "noveb"),
        "mse_random": mse(source == "random"),
        "mse_moved": mse(moved.any(axis=1)),
        "acc": float((pred_moved == moved).mean()),
        "f1": float(2 * tp / max(pred_moved.sum() + moved.sum(), 1)),
    }


def split(groups: np.ndarray, n_test: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) episode indices: whole genome groups, in random order, go to the test set until it holds
    at least ``n_test`` episodes; no group is on both sides."""
    test: list[int] = []
    for g in rng.permutation(np.unique(groups)):
        if len(test) >= n_test:
            break
        test.extend(np.flatnonzero(groups == g).tolist())
    test_set = set(test)
    train = [i for i in rng.permutation(len(groups)).tolist() if i not in test_set]
    return np.asarray(train, dtype=int), np.asarray(test, dtype=int)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--noveb", type=Path, required=True, help="dataset made with --explorer noveb")
    parser.add_argument("--random", type=Path, required=True, help="dataset made with --explorer random")
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3, help="independent splits and initialisations (seed + r)")
    parser.add_argument("--test-fraction", type=float, default=0.25, help="of the smaller dataset, per source")
    parser.add_argument("--n", type=int, default=None, help="training episodes per source [default: all left]")
    parser.add_argument("--steps", type=int, default=16, help="time steps the trajectory is resampled to")
    parser.add_argument("--ee", action="store_true", help="also feed the tool path observation.ee_pos")
    parser.add_argument("--hidden", type=int, default=128)
    parser.add_argument("--moved-threshold", type=float, default=0.01, help="metres: an object 'moves'")
    parser.add_argument(
        "--before",
        choices=("masks", "depth"),
        default=None,
        help="also feed the head camera's masks or depth map of each episode's first frame (16 x 16)",
    )
    args = parser.parse_args()

    datasets.disable_progress_bars()
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    data = {
        name: load_episodes(root, name, args.steps, args.ee, args.moved_threshold, args.before)
        for name, root in (("noveb", args.noveb), ("random", args.random))
    }
    if data["noveb"].object_names != data["random"].object_names:
        raise SystemExit("the two datasets have different objects (different scenes?)")
    objects = data["noveb"].object_names
    n_small = min(len(d.x) for d in data.values())
    n_test = max(1, round(args.test_fraction * n_small))
    n_train = n_small - n_test if args.n is None else min(args.n, n_small - n_test)
    n_train -= max(len(d.genome) - len(np.unique(d.genome)) for d in data.values())  # room for group overshoot
    if n_train < 2:
        raise SystemExit(f"too few episodes: {n_small} in the smaller dataset")

    for name, d in data.items():
        frac = d.moved.any(axis=1).mean()
        per_obj = ", ".join(f"{o} {m:.0%}" for o, m in zip(objects, d.moved.mean(axis=0), strict=True))
        print(
            f"{name:7s} {len(d.x):4d} episodes of {len(np.unique(d.genome))} distinct genomes; something moves in "
            f"{frac:.0%} ({per_obj})"
        )
    print(
        f"per repeat: test = {n_test} + {n_test} held-out episodes (NovEB + random), train = {n_train} episodes "
        f"per model; {data['noveb'].x.shape[1]} inputs, {args.epochs} epochs, {args.repeats} repeats"
    )

    labels = {"noveb": "trained on NovEB", "random": "trained on random", "both": "trained on both (half each)"}
    rows: dict[str, list[dict[str, float]]] = {"nothing moves": [], **{label: [] for label in labels.values()}}
    for r in range(args.repeats):
        rng = np.random.default_rng(args.seed + r)
        parts = {name: split(d.genome, n_test, rng) for name, d in data.items()}
        test = {key: np.concatenate([getattr(d, key)[parts[n][1]] for n, d in data.items()]) for key in _KEYS}
        test["source"] = np.repeat(list(data), [len(parts[n][1]) for n in data])
        truth = (test["disp"], test["moved"], test["source"])
        rows["nothing moves"].append(scores(np.zeros_like(test["disp"]), np.zeros_like(test["moved"]), *truth))
        train_idx = {name: parts[name][0][:n_train] for name in data}
        train_sets = {name: {key: getattr(data[name], key)[train_idx[name]] for key in _KEYS} for name in data}
        # the same number of episodes again, half from each source
        half = {name: train_idx[name][: (n_train + (name == "noveb")) // 2] for name in data}
        train_sets["both"] = {key: np.concatenate([getattr(data[n], key)[half[n]] for n in data]) for key in _KEYS}
        for name, label in labels.items():
            t = train_sets[name]
            model, mean, std = train(t["x"], t["disp"], t["moved"], args.epochs, args.seed + r, args.hidden)
            rows[label].append(scores(*predict(model, mean, std, test["x"]), *truth))

    def cell(values: list[float], digits: int) -> str:
        v = np.asarray(values)[~np.isnan(values)]  # a part with no episodes (e.g. nothing moved) has no score
        if not len(v):
            return "n/a"
        return f"{v.mean():.{digits}f} ± {v.std():.{digits}f}" if len(v) > 1 else f"{v.mean():.{digits}f}"

    columns = {
        "MSE cm² all": ("mse", 1),
        "NovEB part": ("mse_noveb", 1),
        "random part": ("mse_random", 1),
        "moved episodes": ("mse_moved", 1),
        "moves: acc.": ("acc", 3),
        "moves: F1": ("f1", 3),
    }
    header = ("model", *columns)
    lines = [header]
    for label, rs in rows.items():
        lines.append((label, *(cell([s[key] for s in rs], digits) for key, digits in columns.values())))
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    lines.insert(1, tuple("-" * w for w in widths))
    print()
    for line in lines:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)) + " |")
    print(
        "\nMSE: per object and axis of the final (dx, dy), on the common test set, its NovEB and random parts, and "
        f"its episodes in which some object moved more than {args.moved_threshold * 100:.0f} cm; "
        f"mean ± std over {args.repeats} repeats."
    )


if __name__ == "__main__":
    main()
