"""How near the arm, as the learned simulator sees it, comes to an object in the frame where the arm sets it moving:
read two ways, to the object's surface points (what the model's arm edges read) and exactly, to its collision
surface (the signed distance from its parts, `babblegen.shapes.ObjectSpec.signed_distance`).

    python benchmarks/strike_onset_gap.py d/test_nv d/test_rw [--along 201]

For every object the arm sets moving (its first frame of motion, with an arm sphere's sweep within 5 cm of its
surface points): the planner's collision spheres on the recorded joints, swept over that frame. Per link whose
sphere passes nearest the points: the strikes, the share whose sweep stays outside (a positive gap), and the gap's
median and 10th and 90th percentiles, in mm, each way. The exact gap is the least over ``--along`` evenly spaced
positions of each sweep.
"""

from __future__ import annotations

import argparse
import collections
import os
from pathlib import Path

import numpy as np

NEAR = 0.05  # metres: a first motion with no sphere this near the points was not the arm's (another object, a roll)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--along", type=int, default=201, help="positions per sweep for the exact gap")
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.shapes import ObjectSpec
    from babblegen.worldmodel import contact_graph as cg
    from babblegen.worldmodel.arm import ArmSpheres
    from babblegen.worldmodel.episodes import EpisodeSet, read_dataset
    from babblegen.worldmodel.poses import quat_conjugate, rotate
    from babblegen.worldmodel.simulator import surfaces

    episodes = EpisodeSet.union([read_dataset(Path(d)).episodes for d in args.datasets])
    spheres = ArmSpheres(episodes.scene.robot)
    names, link = spheres.model.kin.link_names, spheres.model.link_of_sphere
    surf = surfaces(np.asarray(episodes.objects, dtype=np.float64))
    along = np.linspace(0.0, 1.0, args.along)
    rows: dict[str, list[tuple[float, float]]] = collections.defaultdict(list)
    for e in range(len(episodes)):
        poses, command = episodes.poses[e], episodes.commands[e] or {}
        specs = [ObjectSpec.from_record(o) for o in command.get("objects") or []] or list(episodes.scene.specs)
        balls = spheres(episodes.states[e])  # (T, S, 3)
        moves = cg.moving(poses[:-1], poses[1:])
        for k in range(poses.shape[1]):
            first = np.flatnonzero(moves[:, k])
            if not len(first):
                continue
            t, pose = first[0], poses[first[0], k]
            points = rotate(pose[3:][None], surf.points[e, k]) + pose[:3]
            a0, a1 = balls[t], balls[t + 1]
            _, _, gap = cg._segment_gap(points[None], a0[:, None], a1[:, None], spheres.radii[:, None])
            to_points = gap.min(axis=1)  # (S,)
            nearest = int(np.argmin(to_points))
            if to_points[nearest] > NEAR:
                continue
            sweep = a0[:, None] + along[None, :, None] * (a1 - a0)[:, None]  # (S, A, 3)
            local = rotate(quat_conjugate(pose[3:])[None], sweep.reshape(-1, 3) - pose[:3])
            exact = specs[k].signed_distance(local).reshape(len(a0), len(along)).min(axis=1) - spheres.radii
            rows[names[link[nearest]]].append((to_points[nearest] * 1e3, exact.min() * 1e3))
    print(f"{sum(len(r) for r in rows.values())} strikes in {len(episodes)} episodes")
    print("link | strikes | points: outside, median [p10, p90] mm | exact: outside, median [p10, p90] mm")
    for name, found in sorted(rows.items(), key=lambda item: -len(item[1])):
        gaps = np.array(found)
        cells = []
        for g in gaps.T:
            lo, mid, hi = np.percentile(g, [10, 50, 90])
            cells.append(f"{np.mean(g > 0):4.0%}, {mid:+6.1f} [{lo:+6.1f}, {hi:+6.1f}]")
        print(f"{name} | {len(gaps)} | {cells[0]} | {cells[1]}")


if __name__ == "__main__":
    main()
