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
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # local datasets: never ask the Hub

import datasets
import numpy as np
import torch
from torch import nn

MASKS = "observation.images.head_segmentation"
HEAD = "observation.images.head"
LOW = 0.12  # metres above the table top: the tool is "low" (at the objects' height) below this
ENV = "observation.environment_state"
BASELINE = "nothing moves"
DISP_SCALE = 10.0  # displacements are learned in decimetres, so both losses have similar magnitudes
CLIP = 5.0  # normalised inputs are clipped to +-CLIP standard deviations of the training data
# the objects model sees the paths of the arm's last link origins: elbow, wrist (two links at one origin), gripper
ARM_LINKS = 4


@dataclass
class Episodes:
    """One or more datasets as fixed-size arrays, one row per episode."""

    x: np.ndarray  # (E, inputs): trajectory, then the start, flattened
    disp: np.ndarray  # (E, n_objects, 2) last minus first object position, metres
    moved: np.ndarray  # (E, n_objects) bool
    genomes: np.ndarray  # (E,) str: the explorer's kind and genome; equal for the same commanded movement
    objects: list[str]

    def take(self, idx: np.ndarray) -> Episodes:
        return Episodes(self.x[idx], self.disp[idx], self.moved[idx], self.genomes[idx], self.objects)

    @staticmethod
    def union(parts: list[Episodes]) -> Episodes:
        if any(p.objects != parts[0].objects for p in parts):
            raise SystemExit("the datasets have different objects (different scenes?)")
        cat = [np.concatenate([getattr(p, key) for p in parts]) for key in ("x", "disp", "moved", "genomes")]
        return Episodes(*cat, parts[0].objects)


def resample(seq: np.ndarray, steps: int) -> np.ndarray:
    """A (T, C) sequence linearly resampled to (steps, C) over normalised time."""
    t_old = np.linspace(0.0, 1.0, len(seq))
    t_new = np.linspace(0.0, 1.0, steps)
    return np.stack([np.interp(t_new, t_old, seq[:, c]) for c in range(seq.shape[1])], axis=1)


def yaw(q: np.ndarray) -> np.ndarray:
    """Rotation about the world's z axis of (..., 4) quaternions (w, x, y, z), radians."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def occupancy(mask: np.ndarray, ids: list[int], grid: int) -> np.ndarray:
    """(len(ids), grid, grid): the fraction of each cell that each id covers in an (H, W) instance mask."""
    maps = torch.from_numpy(np.stack([mask == i for i in ids]).astype(np.float32))
    return nn.functional.adaptive_avg_pool2d(maps, grid).numpy()


def mask_ids(features: dict, objects: list[str], root: Path) -> list[int]:
    """Each object's id in the instance masks, from the mask feature's ``info.ids`` (id -> name)."""
    if MASKS not in features:
        raise SystemExit(f"{root} has no {MASKS} (recorded with --no-segmentation); try --start poses")
    by_name = {name: int(i) for i, name in features[MASKS].get("info", {}).get("ids", {}).items()}
    missing = [o for o in objects if o not in by_name]
    if missing:
        raise SystemExit(f"{root}: {MASKS} info.ids names no id for {missing} (ids: {by_name})")
    return [by_name[o] for o in objects]


def arm_kinematics(root: Path):
    """The run's arm as forward kinematics (the robot named in ``run.json``)."""
    from babblegen.tasks import get_robot
    from babblegen.world.kinematics import ArmKinematics, UrdfModel

    run = json.loads((root / "babblegen" / "run.json").read_text())
    robot = get_robot(run["task"]["robot_uid"])
    return ArmKinematics(UrdfModel.load(robot.urdf), robot.base_link, robot.tool_link)


def table_top(root: Path) -> float:
    """Height of the table's top, metres (from ``run.json``)."""
    table = json.loads((root / "babblegen" / "run.json").read_text())["task"]["table"]
    return table["center"][2] + table["half_extents"][2]


def arm_paths(root: Path, actions: list[np.ndarray], steps: int) -> np.ndarray:
    """(E, steps, ARM_LINKS, 3): where the last ``ARM_LINKS`` link origins of the arm (elbow to gripper) are along
    each episode's commanded trajectory, world frame: the parts of the arm that sweep over the table."""
    kin = arm_kinematics(root)
    return np.stack([kin.link_frames(resample(a, steps))[1][:, -ARM_LINKS:] for a in actions])


def path_maps(root: Path, ds, points: np.ndarray, grid: int, presence: bool = False) -> np.ndarray:
    """(E, 2, grid, grid): where each episode's points (E, P, 3), world frame, lie in the head camera's image, as
    the share of the points per cell (with ``presence``, 1 in every cell a point falls in), all of them and those
    within ``LOW`` of the table top (where they can push objects). Put beside the object maps, a convolution can
    see where a path crosses an object."""
    info = ds.meta.features[HEAD]["info"]
    k, world2cam = np.asarray(info["intrinsics"]), np.linalg.inv(np.asarray(info["cam2world"]))
    height, width = ds.meta.features[HEAD]["shape"][:2]
    top = table_top(root)
    out = np.zeros((len(points), 2, grid, grid), dtype=np.float32)
    for e, p in enumerate(points):
        cam = p @ world2cam[:3, :3].T + world2cam[:3, 3]
        uv = cam @ k.T
        col = np.clip((uv[:, 0] / uv[:, 2] / width * grid).astype(int), 0, grid - 1)
        row = np.clip((uv[:, 1] / uv[:, 2] / height * grid).astype(int), 0, grid - 1)
        low = p[:, 2] < top + LOW
        np.add.at(out[e, 0], (row, col), 1.0 / len(p))
        np.add.at(out[e, 1], (row[low], col[low]), 1.0 / len(p))
    return np.minimum(np.ceil(out), 1.0) if presence else out


def load_episodes(root: Path, steps: int, start: str, grid: int, threshold: float, model: str = "mlp") -> Episodes:
    """Read a dataset and turn each episode into one example (see the module docstring). ``model`` adds what its
    network needs after the start: the tool path's maps (conv), the arm's path as maps (objects, masks) or as
    points (objects, poses)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    repo_id = json.loads((root / "babblegen" / "run.json").read_text())["repo_id"]
    ds = LeRobotDataset(repo_id, root=root)
    objects = list(ds.meta.features["observation.contacts"]["names"])
    table = ds.hf_dataset.select_columns(["episode_index", "action", ENV]).with_format("numpy")[:]
    episode = np.asarray(table["episode_index"]).reshape(-1)
    action = np.asarray(table["action"], dtype=np.float64)
    env = np.asarray(table[ENV], dtype=np.float64).reshape(len(episode), len(objects), 7)
    episodes = np.unique(episode)
    if not len(episodes):
        raise SystemExit(f"{root} holds no episodes")
    rows = [np.flatnonzero(episode == e) for e in episodes]  # frames in order within an episode
    first, last = np.array([r[0] for r in rows]), np.array([r[-1] for r in rows])
    x = np.stack([resample(action[r], steps).ravel() for r in rows])
    if start == "masks" or (start == "none" and model == "objects"):
        if start == "masks":
            ids = mask_ids(ds.meta.features, objects, root)
            frames = ds.hf_dataset.select(first.tolist()).select_columns([MASKS]).with_format("numpy")[MASKS]
            maps = np.stack([occupancy(np.asarray(f).reshape(f.shape[:2]), ids, grid).ravel() for f in frames])
        else:  # the objects model without the start: the same network, every object's map empty
            maps = np.zeros((len(x), len(objects) * grid * grid))
        x = np.concatenate([x, maps], axis=1)
        if model == "conv":
            tool = arm_paths(root, [action[r] for r in rows], 64)[:, :, -1]
            x = np.concatenate([x, path_maps(root, ds, tool, grid).reshape(len(x), -1)], 1)
        elif model == "objects":
            arm = arm_paths(root, [action[r] for r in rows], 64).reshape(len(x), -1, 3)
            x = np.concatenate([x, path_maps(root, ds, arm, grid, presence=True).reshape(len(x), -1)], 1)
    elif start == "poses":
        pose = env[first]
        angle = yaw(pose[..., 3:7])
        start_xy_yaw = np.stack([pose[..., 0], pose[..., 1], np.cos(angle), np.sin(angle)], axis=2)
        x = np.concatenate([x, start_xy_yaw.reshape(len(x), -1)], axis=1)
        if model == "objects":
            arm = arm_paths(root, [action[r] for r in rows], steps)
            arm[..., 2] -= table_top(root)  # heights above the table top
            x = np.concatenate([x, arm.reshape(len(x), -1)], axis=1)
    moved = np.linalg.norm(env[last, :, :3] - env[first, :, :3], axis=2) > threshold
    return Episodes(x, env[last, :, :2] - env[first, :, :2], moved, genome_keys(root, episodes), objects)


def genome_keys(root: Path, episodes: np.ndarray) -> np.ndarray:
    """For each episode index, its attempt's kind and genome as one string (from the sidecar)."""
    by_episode: dict[int, str] = {}
    with open(root / "babblegen" / "attempts.jsonl") as f:
        for line in f:
            row = json.loads(line)
            if row.get("episode_index") is not None:
                by_episode[int(row["episode_index"])] = f"{row.get('kind')}:{json.dumps(row['genome'])}"
    return np.array([by_episode[int(e)] for e in episodes])


class WorldModel(nn.Module):
    """MLP: flattened trajectory (and start) -> per-object displacement (dx, dy) and a "moves" logit."""

    def __init__(self, n_in: int, n_objects: int, hidden: int = 128):
        super().__init__()
        self.n_objects = n_objects
        self.net = nn.Sequential(
            nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3 * n_objects)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(x.flatten(1)).view(-1, self.n_objects, 3)
        return out[..., :2], out[..., 2]


def image_features(channels: int) -> nn.Module:
    """The small convolutional network both image models use: ``channels`` maps in, 32 x 4 x 4 features out."""
    return nn.Sequential(
        nn.Conv2d(channels, 16, 3, padding=1), nn.ReLU(),
        nn.Conv2d(16, 32, 3, padding=1, stride=2), nn.ReLU(),
        nn.Conv2d(32, 32, 3, padding=1, stride=2), nn.ReLU(),
        nn.AdaptiveAvgPool2d(4), nn.Flatten(),
    )  # fmt: skip


class ConvWorldModel(nn.Module):
    """The start's object maps and the tool path's two maps (``channels`` images of ``grid`` x ``grid``, the head
    camera's view) through a small convolutional network, beside the trajectory through a linear layer; one head
    predicts each object's (dx, dy) and "moves" logit. Convolutions see the same geometry wherever the objects
    stand, which a flat MLP over the maps has to learn for every place anew."""

    def __init__(self, n_trajectory: int, channels: int, grid: int, n_objects: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.channels, self.grid, self.n_objects = n_trajectory, channels, grid, n_objects
        self.conv = image_features(channels)
        self.trajectory = nn.Linear(n_trajectory, hidden)
        self.head = nn.Sequential(
            nn.ReLU(), nn.Linear(32 * 16 + hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3 * n_objects)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        images = x[:, self.n_trajectory :].reshape(-1, self.channels, self.grid, self.grid)
        features = torch.cat([self.conv(images), self.trajectory(x[:, : self.n_trajectory])], dim=1)
        out = self.head(features).view(-1, self.n_objects, 3)
        return out[..., :2], out[..., 2]


class ObjectMapsModel(nn.Module):
    """One network for every object, shared: object k's occupancy map, the other objects' maps summed and the arm's
    path maps (all of it, its low part) through a convolutional network, with which object it is, predict k's
    (dx, dy) and "moves" logit. Whatever holds for one object at one place is learned for all objects and places:
    what a model must find for a new start is where the arm's path meets an object's map."""

    def __init__(self, n_trajectory: int, n_objects: int, grid: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.n_objects, self.grid = n_trajectory, n_objects, grid
        self.conv = image_features(4)
        self.head = nn.Sequential(
            nn.Linear(32 * 16 + n_objects, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, 3),
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, k, g = len(x), self.n_objects, self.grid
        maps = x[:, self.n_trajectory :].reshape(b, k + 2, g, g)
        objects, path = maps[:, :k], maps[:, k:]
        others = objects.sum(dim=1, keepdim=True) - objects
        channels = torch.cat(
            [objects.unsqueeze(2), others.unsqueeze(2), path.unsqueeze(1).expand(b, k, 2, g, g)], dim=2
        ).reshape(b * k, 4, g, g)
        which = torch.eye(k).expand(b, k, k).reshape(b * k, k)
        out = self.head(torch.cat([self.conv(channels), which], dim=1)).view(b, k, 3)
        return out[..., :2], out[..., 2]


class ObjectPosesModel(nn.Module):
    """One network for every object, shared: each point of the arm's path (``ARM_LINKS`` link origins at each time
    step) relative to object k's start position, its height above the table and which link it is, through a small
    network and pooled over the points (the nearest pass counts wherever in time it happens); with k's own position
    and yaw, where the other objects stand relative to it and which object it is, predict k's (dx, dy) and "moves"
    logit."""

    def __init__(self, n_trajectory: int, n_objects: int, steps: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.n_objects, self.steps = n_trajectory, n_objects, steps
        self.point = nn.Sequential(nn.Linear(3 + ARM_LINKS, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.head = nn.Sequential(
            nn.Linear(hidden + 4 + 3 * n_objects, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, 3),
        )  # fmt: skip

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, k, n = len(x), self.n_objects, self.steps * ARM_LINKS
        start = x[:, self.n_trajectory : self.n_trajectory + 4 * k].reshape(b, k, 4)
        arm = x[:, self.n_trajectory + 4 * k :].reshape(b, 1, n, 3)
        relative = arm[..., :2] - start[:, :, None, :2]  # (b, k, points, 2)
        height = arm[..., 2:].expand(b, k, n, 1)
        link = torch.eye(ARM_LINKS).repeat(self.steps, 1).expand(b, k, n, ARM_LINKS)
        pooled = self.point(torch.cat([10 * relative, 10 * height, link], dim=3)).amax(dim=2)
        others = start[:, None, :, :2] - start[:, :, None, :2]  # (b, k, k, 2)
        which = torch.eye(k).expand(b, k, k)
        out = self.head(torch.cat([pooled, start, 10 * others.flatten(2), which], dim=2)).view(b, k, 3)
        return out[..., :2], out[..., 2]


def normalise(x: np.ndarray, mean: np.ndarray, std: np.ndarray) -> torch.Tensor:
    """Inputs standardised with the training data's statistics and clipped, so that inputs that barely varied in
    training (a map cell an object rarely covered) cannot swamp the model on other data."""
    return torch.tensor(np.clip((x - mean) / std, -CLIP, CLIP), dtype=torch.float32)


def build(net: dict | None, n_in: int, n_objects: int, hidden: int) -> nn.Module:
    """The network ``net`` names (``{"kind": "conv" | "object_maps" | "object_poses", ...its arguments}``), or the
    MLP for None."""
    if net is None:
        return WorldModel(n_in, n_objects, hidden)
    kinds = {"conv": ConvWorldModel, "object_maps": ObjectMapsModel, "object_poses": ObjectPosesModel}
    args = {k: v for k, v in net.items() if k != "kind"}
    return kinds[net["kind"]](**args, n_objects=n_objects, hidden=hidden)


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
