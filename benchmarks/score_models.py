"""Score saved learned simulators (`babblegen evaluate --save-models DIR`) on test sets, without training again: per
model and test set, the F1 of "moves", the error of where moved objects end as a multiple of "nothing moves", how far
along their true moves it ends them (median) and the moved objects these are medians of. Each test set is scored on
its own (one dataset each), for example each half of a test set made by two explorers; with ``--by-shape`` also each
shape's objects alone.

``--true-frames F ...`` says where a model's error is made: each line again with every object's first F frames of
motion taken from the recording (the model rolls out the rest from there). An error that falls far with F = 1 or 2
is made in the strike that starts a motion, not in the sliding, rolling or falling after it.

    python benchmarks/score_models.py eval/models test/ho_nv test/ho_rw
    python benchmarks/score_models.py eval/models/noveb_4000attempts_equal-attempts_repeat1.pt test/var_rw --by-shape
    python benchmarks/score_models.py eval/models test/ho_nv --true-frames 1 2 4
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", type=Path, help="a folder of saved models (*.pt) or one model file")
    parser.add_argument("tests", nargs="+", type=Path, help="test datasets, each scored on its own")
    parser.add_argument("--by-shape", action="store_true", help="also each shape's objects alone, a line each")
    parser.add_argument(
        "--true-frames", type=int, nargs="+", default=[], metavar="F",
        help="also scored with every object's first F frames of motion taken from the recording, a line each F",
    )  # fmt: skip
    args = parser.parse_args()
    if any(f < 1 for f in args.true_frames):
        parser.error("--true-frames counts frames: 1 or more")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.worldmodel.api import load_model
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.metrics import score

    files = sorted(args.models.glob("*.pt")) if args.models.is_dir() else [args.models]
    tests = {str(t): read_dataset(t).episodes for t in args.tests}
    for path in files:
        model = load_model(path)
        cells, shapes, replays = [], [], []
        for name, episodes in tests.items():
            no_mean = np.zeros((len(episodes.scene.objects), 2))  # the skill against a mean is not printed
            scores = score(model.predict(episodes), episodes, no_mean)
            cells.append(line(name, scores["all"]))
            shapes += [line(f"{name} {shape}", s) for shape, s in scores["shapes"].items() if s["moved"]]
            for count in args.true_frames:
                scores = score(replayed(model, episodes, count), episodes, no_mean)
                replays.append(line(f"{name} with its first {count} frames of motion recorded", scores["all"]))
        print(f"{path.name}: " + "; ".join(cells), flush=True)
        if args.by_shape:
            print("".join(f"  {cell}\n" for cell in shapes), end="", flush=True)
        print("".join(f"  {cell}\n" for cell in replays), end="", flush=True)


def replayed(model, episodes, count: int) -> np.ndarray:
    """(E, K, 4) the model's final states with every object's first ``count`` frames of motion the recorded ones."""
    from babblegen.worldmodel.poses import object_state
    from babblegen.worldmodel.simulator import first_moving_frames

    frames = [first_moving_frames(p, count) for p in episodes.poses]
    first, joints0 = [p[0] for p in episodes.poses], [s[0] for s in episodes.states]
    final, _ = model.rollout_poses(first, episodes.actions, joints0, episodes.objects, replay=(episodes.poses, frames))
    return object_state(final)


def line(name: str, s: dict) -> str:
    """One group's F1, error and moved objects, as a line."""
    return f"{name}: F1 {s['f1']:.3f}, error {s['ratio']:.2f}x, {s['along']:.2f} of the way, over {s['moved']} moved"


if __name__ == "__main__":
    main()
