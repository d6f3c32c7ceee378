"""Load a babblegen dataset with LeRobot, batch it with a torch DataLoader, and look at one episode.

    python examples/load_dataset.py DIR [--episode N] [--out before_after.png]

Prints the features (with the joint and object names stored in the dataset's metadata), the shapes of one
batch of frames, what one episode holds, and that episode's row of the sidecar table (novelty, contacts,
displacements). Saves the episode's before (first frame) and after (last frame) head-camera images side by
side, and, for a dataset with more views, every camera's colour, depth and instance masks before and after
(OUT_views.png). Without --episode it picks the first episode in which the arm touched an object.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a local dataset: never ask the Hub

import datasets
import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from PIL import Image

from babblegen.dataset.sidecar import read_attempts

HEAD = "observation.images.head"


def open_dataset(root: Path) -> LeRobotDataset:
    """The dataset at `root`, under the repo id babblegen recorded in its run.json."""
    repo_id = json.loads((root / "babblegen" / "run.json").read_text())["repo_id"]
    return LeRobotDataset(repo_id, root=root)


def to_uint8(chw: torch.Tensor) -> np.ndarray:
    """LeRobot's float CHW image in [0, 1] as HWC uint8."""
    return (chw.clamp(0, 1) * 255).round().byte().permute(1, 2, 0).numpy()


def side_by_side(before: np.ndarray, after: np.ndarray, scale: int = 1, gap: int = 4) -> Image.Image:
    """Two HWC uint8 images next to each other on a white background, each scaled up `scale` times."""
    h, w, _ = before.shape
    canvas = np.full((h, 2 * w + gap, 3), 255, dtype=np.uint8)
    canvas[:, :w], canvas[:, w + gap :] = before, after
    img = Image.fromarray(canvas)
    return img.resize((img.width * scale, img.height * scale), Image.NEAREST) if scale > 1 else img


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path, help="dataset directory written by `babblegen generate`")
    parser.add_argument("--episode", type=int, default=None, help="episode to show [default: first with contact]")
    parser.add_argument("--out", type=Path, default=Path("before_after.png"), help="PNG to write")
    parser.add_argument("--scale", type=int, default=2, help="enlarge the saved images this many times")
    parser.add_argument("--batch-size", type=int, default=32)
    args = parser.parse_args()

    datasets.disable_progress_bars()
    ds = open_dataset(args.root)
    print(f"{args.root}: {ds.meta.total_episodes} episodes, {ds.num_frames} frames at {ds.fps} fps")
    print("features:")
    for key, feat in ds.meta.features.items():
        names = feat.get("names")
        shown = "" if names is None else f"  names={names if len(names) <= 8 else names[:8] + ['...']}"
        print(f"  {key:32s} {feat['dtype']:8s} {tuple(feat['shape'])}{shown}")

    # Frames, batched: every key of a frame gains a leading batch dimension (strings become lists).
    loader = torch.utils.data.DataLoader(ds, batch_size=args.batch_size, shuffle=False, num_workers=0)
    batch = next(iter(loader))
    print(f"one batch of {len(batch['index'])} frames:")
    for key, value in batch.items():
        print(f"  {key:32s} {tuple(value.shape) if hasattr(value, 'shape') else type(value).__name__}")

    rows = read_attempts(args.root)
    by_episode = {r["episode_index"]: r for r in rows if r.get("episode_index") is not None}
    episode = args.episode
    if episode is None:
        touched = [e for e, r in sorted(by_episode.items()) if any(r.get("touched", {}).values())]
        episode = touched[0] if touched else 0
    if not 0 <= episode < ds.meta.total_episodes:
        parser.error(f"episode {episode} is not in the dataset (0 to {ds.meta.total_episodes - 1})")

    meta = ds.meta.episodes[episode]
    start, stop = int(meta["dataset_from_index"]), int(meta["dataset_to_index"])
    first, last = ds[start], ds[stop - 1]
    joints = ds.meta.features["observation.state"]["names"]
    objects = ds.meta.features["observation.contacts"]["names"]
    print(f"episode {episode}: frames {start} to {stop - 1} ({stop - start} frames, {(stop - start) / ds.fps:.1f} s)")
    print(f"  task: {first['task']!r}")
    print("  joints (rad)        before -> after:")
    for j, name in enumerate(joints):
        print(f"    {name:24s} {first['observation.state'][j]:+.3f} -> {last['observation.state'][j]:+.3f}")
    env_before = first["observation.environment_state"].view(len(objects), 7)
    env_after = last["observation.environment_state"].view(len(objects), 7)
    # non-video columns come straight from the parquet data, without decoding any video
    contacts = np.asarray(ds.hf_dataset.select(range(start, stop)).with_format("numpy")["observation.contacts"])

    row = by_episode.get(episode, {})
    print(
        f"  sidecar: attempt {row.get('attempt')}, generation {row.get('generation')}, explorer {row.get('explorer')}, "
        f"novelty {row.get('novelty')}, archived {row.get('archived')}, descriptor {row.get('descriptor')}"
    )
    print("  objects        start (x, y, z)            end (x, y, z)            moved  contact frames")
    for o, name in enumerate(objects):
        moved = float(torch.linalg.norm(env_after[o, :3] - env_before[o, :3]))
        n_contact = int(contacts[:, o].sum())
        b, a = env_before[o, :3].tolist(), env_after[o, :3].tolist()
        print(
            f"    {name:12s} ({b[0]:.3f}, {b[1]:+.3f}, {b[2]:.3f})  ({a[0]:.3f}, {a[1]:+.3f}, {a[2]:.3f})  "
            f"{moved:.3f} m  {n_contact} (sidecar: touched={row.get('touched', {}).get(name)}, "
            f"displacement={row.get('displacement', {}).get(name)})"
        )

    args.out.parent.mkdir(parents=True, exist_ok=True)
    side_by_side(to_uint8(first[HEAD]), to_uint8(last[HEAD]), scale=args.scale).save(args.out)
    print(f"before | after images of episode {episode} -> {args.out}")
    if len(ds.meta.camera_keys) > 1:
        in_metres = LeRobotDataset(ds.repo_id, root=args.root, depth_output_unit="m")
        out = args.out.with_name(args.out.stem + "_views.png")
        colors = [o["color"] for o in json.loads((args.root / "babblegen" / "run.json").read_text())["task"]["objects"]]
        views_grid(ds, in_metres, [start, stop - 1], ds.meta.camera_keys, colors, args.scale).save(out)
        print(f"every camera's colour, depth and masks, before (top) and after (bottom) -> {out}")


def views_grid(ds, in_metres, frames: list[int], keys: list[str], colors: list, scale: int) -> Image.Image:
    """One row per frame: each camera's colour image, its depth map (metres, nearer darker, clipped to 0.2 to
    3 m) and its instance masks (ids 0 to 3: background, table, floor, robot; then each object in its colour),
    side by side."""
    palette = np.zeros((256, 3), np.uint8)
    palette[:4] = [[0, 0, 0], [140, 102, 71], [200, 200, 195], [90, 90, 90]]
    palette[4 : 4 + len(colors)] = (np.asarray(colors)[:, :3] * 255).round()
    rows = []
    for index in frames:
        item, metric = ds[index], in_metres[index]
        tiles = []
        for key in keys:
            value = item[key]
            if key.endswith("_depth"):
                depth = metric[key][0].numpy()
                gray = (np.clip((depth - 0.2) / 2.8, 0, 1) * 255).astype(np.uint8)
                tiles.append(np.repeat(gray[..., None], 3, axis=2))
            elif key.endswith("_segmentation"):
                tiles.append(palette[value[0].numpy().round().astype(np.uint8)])  # the ids themselves
            else:
                tiles.append(to_uint8(value))
        height = max(t.shape[0] for t in tiles)
        row = [np.pad(t, ((0, height - t.shape[0]), (0, 4), (0, 0)), constant_values=255) for t in tiles]
        rows.append(np.concatenate(row, axis=1))
    canvas = np.concatenate([np.pad(r, ((0, 4), (0, 0), (0, 0)), constant_values=255) for r in rows], axis=0)
    img = Image.fromarray(canvas)
    return img.resize((img.width * scale, img.height * scale), Image.NEAREST) if scale > 1 else img


if __name__ == "__main__":
    main()
