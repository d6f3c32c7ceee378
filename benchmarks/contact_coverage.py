"""What a dataset's contacts cover, the way the learned simulator sees them: in every frame where an arm sphere's
sweep passes within 1 cm of an object's collision surface, where on the object's surface (which of its surface
points, in its own frame), from which direction in the object's frame (the sphere's motion, seen from above), and
how fast the sphere moves.

    python benchmarks/contact_coverage.py d/nv1 d/rw1 [--attempts 4000]

Per dataset: contact frames, objects touched, the share of surface points ever touched (per object, then the mean),
the spread of push directions in the object's own frame (entropy of 16 sectors, bits; 4 is uniform), their number of
sectors covered, the median and 90th percentile of the sphere's speed at contact (m/s), overall and per shape, and
the contacts in each band of speed.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

REACH = 0.01  # metres between a sphere's surface and a surface point: a contact
SECTORS = 16
SPEED_BANDS = (0.0, 0.5, 1.0, 1.5, np.inf)  # m/s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--attempts", type=int, default=None)
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from babblegen.shapes import SHAPES
    from babblegen.worldmodel.arm import ArmSpheres
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.poses import quat_conjugate, rotate
    from babblegen.worldmodel.simulator import surfaces

    for root in args.datasets:
        data = read_dataset(Path(root))
        e = data.budget(attempts=args.attempts)
        spheres = ArmSpheres(e.scene.robot)
        fps = data.run["config"]["world"].get("fps", 10)
        touched: dict[tuple[bytes, int], set[int]] = {}
        angles, speeds, shapes = [], [], []
        frames = 0
        for q, poses, objects in zip(e.states, e.poses, e.objects, strict=True):
            balls = spheres(q)
            surf = surfaces(objects)
            for t in range(len(poses) - 1):
                pos, quat = poses[t, :, :3], poses[t, :, 3:]
                world = rotate(quat[:, None], surf.points) + pos[:, None]  # (K, P, 3)
                a0, a1 = balls[t], balls[t + 1]
                seg = a1 - a0
                rel = world[:, :, None] - a0[None, None]  # (K, P, S, 3)
                along = np.clip((rel * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-12), 0, 1)
                gap = np.linalg.norm(rel - along[..., None] * seg, axis=-1) - spheres.radii  # (K, P, S)
                hit = gap.min(axis=-1) < REACH  # (K, P)
                if not hit.any():
                    continue
                frames += 1
                for k in np.flatnonzero(hit.any(axis=1)):  # an object: its vector, in its slot
                    touched.setdefault((objects[k].tobytes(), k), set()).update(np.flatnonzero(hit[k]).tolist())
                    s = int(np.argmin(gap[k].min(axis=0)))
                    move = rotate(quat_conjugate(quat[k]), seg[s])  # the sphere's motion in the object's frame
                    angles.append(np.arctan2(move[1], move[0]))
                    speeds.append(np.linalg.norm(seg[s]) * fps)
                    shapes.append(int(np.argmax(objects[k, : len(SHAPES)])))
        angles, speeds, shapes = np.array(angles), np.array(speeds), np.array(shapes)
        n_points = surf.points.shape[1]
        cover = np.mean([len(v) / n_points for v in touched.values()]) if touched else 0.0
        print(f"{root}: {len(e)} episodes, {frames} contact frames, {len(touched)} objects touched")
        print(f"  surface points touched per object: {cover:.3f} of {n_points}")
        print("  " + _directions(angles) + f"; sphere speed median {np.median(speeds):.2f} m/s, 90th percentile "
              f"{np.percentile(speeds, 90):.2f}" if len(speeds) else "  no contact")  # fmt: skip
        if len(speeds):
            counts = np.histogram(speeds, bins=SPEED_BANDS)[0]
            edges = zip(SPEED_BANDS[:-1], SPEED_BANDS[1:], strict=True)
            names = [f"{lo:g}-{hi:g}" if np.isfinite(hi) else f"over {lo:g}" for lo, hi in edges]
            bands = ", ".join(f"{b} {n}" for b, n in zip(names, counts, strict=True))
            print(f"  contacts by sphere speed (m/s): {bands}")
        for si, name in enumerate(SHAPES):
            sel = shapes == si
            if sel.sum() >= 20:
                speed = np.median(speeds[sel])
                print(f"  {name:9s} {sel.sum():6d} contacts: {_directions(angles[sel])}, speed {speed:.2f}")


def _directions(angles: np.ndarray) -> str:
    counts = np.bincount(((angles + np.pi) / (2 * np.pi) * SECTORS).astype(int) % SECTORS, minlength=SECTORS)
    p = counts / max(counts.sum(), 1)
    entropy = -(p[p > 0] * np.log2(p[p > 0])).sum()
    return f"push directions: entropy {entropy:.2f} bits of 4, {int((counts > 0).sum())} of {SECTORS} sectors"


if __name__ == "__main__":
    main()
