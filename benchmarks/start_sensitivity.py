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


def scores(ends, first, final, truth, off) -> np.ndarray:
    """Of (E, K, 4) ends against the recorded ``final`` states from ``first``, over the moved objects ``truth``
    (E, K): the error as a multiple of "nothing moves", its median (cm), the F1 of "moves", the share within 1 cm,
    and the ratio over the moved objects in episodes where one toppled, rolled or left the table (``off``, per moved
    object) and over the others."""
    nothing = np.linalg.norm(first[..., :2] - final[..., :2], axis=-1)[truth]
    err = np.linalg.norm(ends[..., :2] - final[..., :2], axis=-1)[truth]
    went = np.linalg.norm(ends[..., :3] - first[..., :3], axis=-1) > 0.01
    f1 = 2 * (went & truth).sum() / (went.sum() + truth.sum())
    half = [np.median(err[m]) / np.median(nothing[m]) if m.any() else np.nan for m in (off, ~off)]
    return np.array([np.median(err) / np.median(nothing), np.median(err) * 100, f1, np.mean(err < 0.01), *half])


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
    from babblegen.worldmodel.episodes import outcomes, read_dataset
    from babblegen.worldmodel.poses import object_state

    for root in args.datasets:
        e = read_dataset(root).episodes
        moved, stratum = outcomes(e)
        pick = np.flatnonzero(moved.any(axis=1))
        if not len(pick):
            print(f"{root}: no object moved in any episode", flush=True)
            continue
        first, final, truth = object_state(e.first[pick]), object_state(e.final[pick]), moved[pick]
        off = np.broadcast_to((stratum[pick] == 3)[:, None], truth.shape)[truth]
        nothing = np.median(np.linalg.norm(first[..., :2] - final[..., :2], axis=-1)[truth]) * 100
        print(f"{root}: {len(pick)} episodes with {int(truth.sum())} moved objects ({int(off.sum())} in episodes where "
              f"one toppled, rolled or left the table), 'nothing moves' errs {nothing:.1f} cm", flush=True)  # fmt: skip
        for shift in args.shifts:
            draws = [
                shifted_ends(e, pick, shift, np.random.default_rng([args.seed, round(shift * 1000), d]), args.workers)
                for d in range(args.draws)
            ]
            rows = {"one draw": np.mean([scores(x, first, final, truth, off) for x in draws], axis=0)}
            if args.draws > 1:
                rows["centre"] = scores(np.mean(draws, axis=0), first, final, truth, off)
            for name, (ratio, cm, f1, near, off_ratio, rest_ratio) in rows.items():
                print(f"  shift {shift:.1f} mm, {name}: error {ratio:.2f}x (median {cm:.2f} cm), F1 {f1:.3f}, "
                      f"within 1 cm {near:.2f}; toppled, rolled or off {off_ratio:.2f}x, the rest {rest_ratio:.2f}x",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
