"""The world-model example's data: episodes of a babblegen dataset as inputs (commanded joint trajectory, the start
as per-object occupancy maps or poses, the arm's path in the head camera's image) and targets (which objects move,
each one's displacement). Used by examples/train_world_model.py."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # local datasets: never ask the Hub

import numpy as np
import torch
from torch import nn

MASKS = "observation.images.head_segmentation"
HEAD = "observation.images.head"
LOW = 0.12  # metres above the table top: the tool is "low" (at the objects' height) below this
ENV = "observation.environment_state"
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
