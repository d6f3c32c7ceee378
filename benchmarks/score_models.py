"""Score saved learned simulators (`babblegen evaluate --save-models DIR`) on test sets, without training again: per
model and test set, the F1 of "moves", the error of where moved objects end as a multiple of "nothing moves" and the
moved objects it is the median of. Each test set is scored on its own (one dataset each), for example each half of a
test set made by two explorers; with ``--by-shape`` also each shape's objects alone.

    python benchmarks/score_models.py eval/models test/ho_nv test/ho_rw
    python benchmarks/score_models.py eval/models/noveb_4000attempts_equal-attempts_repeat1.pt test/var_rw --by-shape
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
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.worldmodel.api import load_model
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.metrics import score

    files = sorted(args.models.glob("*.pt")) if args.models.is_dir() else [args.models]
    tests = {str(t): read_dataset(t).episodes for t in args.tests}
    for path in files:
        model = load_model(path)
        cells, shapes = [], []
        for name, episodes in tests.items():
            scores = score(model.predict(episodes), episodes, np.zeros((len(episodes.scene.objects), 2)))
            cells.append(line(name, scores["all"]))
            shapes += [line(f"{name} {shape}", s) for shape, s in scores["shapes"].items() if s["moved"]]
        print(f"{path.name}: " + "; ".join(cells), flush=True)
        if args.by_shape:
            print("".join(f"  {cell}\n" for cell in shapes), end="", flush=True)


def line(name: str, s: dict) -> str:
    """One group's F1, error and moved objects, as a line."""
    return f"{name}: F1 {s['f1']:.3f}, error {s['ratio']:.2f}x over {s['moved']} moved"


if __name__ == "__main__":
    main()
