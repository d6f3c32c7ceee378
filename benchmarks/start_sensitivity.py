"""How precisely any model must know a scene to say where its objects end: every executed episode of a dataset in
which an object moved is run again in the true simulator with the same movement and the same seeded randomness,
from its start with every object shifted by a few millimetres (each in its own random direction, seen from above).
Scored as `babblegen evaluate` scores a model: the median distance between where moved objects end in a shifted
run and in the recorded one, as a multiple of "nothing moves", and the F1 of "moves".

    python benchmarks/start_sensitivity.py test/var_rw test/ho_nv --shifts 0 1 2 --draws 8 --workers 2

Per shift, ``--draws`` shifted runs of every episode: "one draw" scores each run on its own (the mean over draws);
"centre" scores each object's mean end over the draws (the point with the least squared error on average): about the
best a model can say that knows each object's place only to the shift's size, whatever it learned. A shift of 0
replays each episode as recorded (0.00x unless the simulator is not deterministic).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np


def scores(ends: np.ndarray, test, moved: np.ndarray) -> tuple[dict, float]:
    """`metrics.score` of (E, K, 4) ends on the episodes ``test``, and the share of its ``moved`` objects (E, K) that
    end within 1 cm."""
    from babblegen.worldmodel.metrics import score
    from babblegen.worldmodel.poses import object_state

    near = np.linalg.norm(ends[..., :2] - object_state(test.final)[..., :2], axis=-1)[moved] < 0.01
    return score(ends, test, np.zeros((len(test.scene.objects), 2))), float(near.mean())


def summary(runs: list[tuple[dict, float]], strata: tuple[str, ...]) -> str:
    """One line of `scores` results, each number the mean over ``runs``."""
    scored = [s for s, _ in runs]

    def mean(stratum: str, key: str) -> float:
        return float(np.mean([s[stratum][key] for s in scored]))

    parts = ", ".join(f"{k.replace('_', ' ')} {mean(k, 'ratio'):.2f}x" for k in strata if k in scored[0])
    return (
        f"error {mean('all', 'ratio'):.2f}x (median {mean('all', 'err_cm'):.2f} cm), F1 {mean('all', 'f1'):.3f}, "
        f"within 1 cm {np.mean([near for _, near in runs]):.2f}; {parts}"
    )


def shifted_ends(e, pick: np.ndarray, shift_mm: float, rng: np.random.Generator, workers: int) -> np.ndarray:
    """(E, K, 4) where the objects end when episodes ``pick`` of ``e`` run again, every object shifted."""
    from babblegen.worldmodel.planning_sim import execute
    from babblegen.worldmodel.poses import object_state

    jobs = []
    for i in pick:
        c = e.commands[i]
        layout = np.array(c["layout"], dtype=np.float64)
        turn = rng.uniform(0, 2 * np.pi, len(layout))
        layout[:, 0] += shift_mm / 1000 * np.cos(turn)
        layout[:, 1] += shift_mm / 1000 * np.sin(turn)
        jobs.append((str(e.source[i]), int(e.attempt[i]), c["kind"], c["genome"], layout.tolist(), c.get("objects")))
    first = object_state(e.first[pick])
    return np.stack([r[2] if r[0] else first[j] for j, r in enumerate(execute(jobs, workers))])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--shifts", nargs="+", type=float, default=[0.0, 0.5, 1.0, 2.0], help="millimetres")
    parser.add_argument("--draws", type=int, default=1, help="shifted runs of every episode per shift")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.worldmodel.episodes import STRATA, outcomes, read_dataset
    from babblegen.worldmodel.poses import object_state

    for root in args.datasets:
        e = read_dataset(root).episodes
        moved, _ = outcomes(e)
        pick = np.flatnonzero(moved.any(axis=1))
        if not len(pick):
            print(f"{root}: no object moved in any episode", flush=True)
            continue
        test, moved = e.take(pick), moved[pick]
        first, final = object_state(test.first), object_state(test.final)
        nothing = np.median(np.linalg.norm(first[..., :2] - final[..., :2], axis=-1)[moved]) * 100
        print(f"{root}: {len(pick)} episodes with {int(moved.sum())} moved objects, 'nothing moves' errs "
              f"{nothing:.1f} cm", flush=True)  # fmt: skip
        for shift in args.shifts:
            draws = [
                shifted_ends(e, pick, shift, np.random.default_rng([args.seed, round(shift * 1000), d]), args.workers)
                for d in range(args.draws)
            ]
            rows = {"one draw": [scores(x, test, moved) for x in draws]}
            if args.draws > 1:
                rows["centre"] = [scores(np.mean(draws, axis=0), test, moved)]
            for name, runs in rows.items():
                print(f"  shift {shift:.1f} mm, {name}: {summary(runs, STRATA[1:])}", flush=True)


if __name__ == "__main__":
    main()
