"""Open one episode of a babblegen dataset in Rerun from Python.

    python examples/view_episode.py DIR [--episode N] [--save FILE.rrd] [--minimal]

By default this calls babblegen's own logger (`babblegen.exporters.rerun.view_dataset`, the code behind
`babblegen view`): the 3D scene with the arm posed per frame, objects, tool path, contacts, the head camera,
and the overview of every attempt. `--minimal` shows how little the rerun-sdk needs instead: the head-camera
frames as images and the objects as 3D points on a `frame_index` timeline. Without --save the viewer opens;
with no display the recording is written to episode_N.rrd instead. Open a file with `rerun FILE.rrd`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a local dataset: never ask the Hub


def log_minimal(root: Path, episode: int, save: Path | None) -> None:
    """One episode with the plain rerun-sdk: head camera, object positions, per-object contacts."""
    import rerun as rr
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    repo_id = json.loads((root / "babblegen" / "run.json").read_text())["repo_id"]
    ds = LeRobotDataset(repo_id, root=root)
    objects = ds.meta.features["observation.contacts"]["names"]
    meta = ds.meta.episodes[episode]
    start, stop = int(meta["dataset_from_index"]), int(meta["dataset_to_index"])

    rr.init("babblegen_episode", spawn=False)
    if save is None:
        rr.spawn(executable_path=str(Path(sys.executable).parent / "rerun"))
    else:
        rr.save(save)
    rr.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    colors = [(int(255 * c[0]), int(255 * c[1]), int(255 * c[2])) for c in _object_colors(root, objects)]
    for i in range(start, stop):
        frame = ds[i]  # decodes this frame of the head-camera video
        rr.set_time("frame_index", sequence=int(frame["frame_index"]))
        image = (frame["observation.images.head"].clamp(0, 1) * 255).byte().permute(1, 2, 0).numpy()
        rr.log("head_camera", rr.Image(image))
        poses = frame["observation.environment_state"].view(len(objects), 7).numpy()
        rr.log("world/objects", rr.Points3D(poses[:, :3], colors=colors, labels=objects, radii=0.03))
        rr.log("world/tool", rr.Points3D(frame["observation.ee_pos"].numpy()[None], radii=0.015))
        for name, touching in zip(objects, frame["observation.contacts"].tolist(), strict=True):
            rr.log(f"contacts/{name}", rr.Scalars(touching))
    rr.disconnect()


def _object_colors(root: Path, objects: list[str]) -> list[tuple[float, ...]]:
    """Each object's colour from the scene description stored in the dataset's run.json."""
    task = json.loads((root / "babblegen" / "run.json").read_text())["task"]
    by_name = {o["name"]: o["color"] for o in task["objects"]}
    return [tuple(by_name.get(n, (0.5, 0.5, 0.5))) for n in objects]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", type=Path, help="dataset directory written by `babblegen generate`")
    parser.add_argument("--episode", type=int, default=0)
    parser.add_argument("--save", type=Path, default=None, help="write a .rrd file instead of opening the viewer")
    parser.add_argument("--minimal", action="store_true", help="log with the plain rerun-sdk (see above)")
    args = parser.parse_args()

    total = json.loads((args.root / "meta" / "info.json").read_text())["total_episodes"]
    if not 0 <= args.episode < total:
        parser.error(f"episode {args.episode} is not in {args.root} (it has episodes 0 to {total - 1})")
    save = args.save
    if save is None and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        save = Path(f"episode_{args.episode}.rrd")
        print("no display found: writing a recording instead of opening the viewer")
    if save is not None:
        save.parent.mkdir(parents=True, exist_ok=True)

    if args.minimal:
        log_minimal(args.root, args.episode, save)
    else:
        from babblegen.exporters.rerun import view_dataset

        view_dataset(args.root, episodes=[args.episode], save=save)
    if save is not None:
        print(f"episode {args.episode} written to {save}; open it with: rerun {save}")


if __name__ == "__main__":
    main()
