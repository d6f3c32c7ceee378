"""Seconds per physics substep of a rollout: the world's own stepping against ManiSkill's controller and the
name-based contact scan it replaced (`babblegen.world.reference.ManiSkillDrivenWorld`), against its own scan
before it summed the object pairs' impulses (`ArmContactsWorld`: the arm's contacts alone) and against that sum read
from every contact, sleeping objects' too (`EveryContactWorld`), on the same commands, alternating, with the frames
checked identical (the pairs' impulses too, between the world and `EveryContactWorld`), and the contact scan's own
share. Rendering is deferred (not measured).

    python benchmarks/bench_substeps.py --n 30
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from babblegen.evaluation import seeded_rollout, warm_up
from babblegen.tasks import DEFAULT_TASK, get_task
from babblegen.world.reference import ManiSkillDrivenWorld
from babblegen.world.rollout import Command
from babblegen.world.world import World


class ArmContactsWorld(World):
    """The world with its contact scan as it was before it recorded the object pairs' impulses
    (``Frames.object_contacts`` stay zero): only the arm's contacts are read."""

    def _touching(self) -> np.ndarray:
        touched = np.zeros(len(self._object_entities), dtype=bool)
        arm, object_of = self._contacts.arm_bodies, self._contacts.object_of_body
        for contact in self.sim.scene.px.get_contacts():
            a, b = contact.bodies
            obj = object_of.get(b) if a in arm else object_of.get(a) if b in arm else None
            if obj is None or touched[obj]:
                continue
            if any(p.impulse.any() or p.separation < 1e-3 for p in contact.points):
                touched[obj] = True
        return touched


class EveryContactWorld(World):
    """The world reading every contact's impulses, never reusing those of sleeping objects."""

    def _touching(self) -> np.ndarray:
        self._contacts.asleep.clear()
        return super()._touching()


def timed(scan, into: list):
    """``scan`` (a world's contact scan), adding its seconds and calls to ``into``."""

    def run() -> np.ndarray:
        t0 = time.perf_counter()
        touched = scan()
        into[0] += time.perf_counter() - t0
        into[1] += 1
        return touched

    return run


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n", type=int, default=30, help="commands (1 to 3 waypoints, low over the table)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    task = get_task(DEFAULT_TASK)
    worlds = {
        "world": World(task, seed=args.seed),
        "world, every contact read": EveryContactWorld(task, seed=args.seed),
        "world, arm contacts only": ArmContactsWorld(task, seed=args.seed),
        "ManiSkill controller": ManiSkillDrivenWorld(task, seed=args.seed),
    }
    scans = {name: [0.0, 0] for name in worlds}  # seconds in the contact scan, scans
    for name, w in worlds.items():
        warm_up(w, None)
        w._touching = timed(w._touching, scans[name])
    rng = np.random.default_rng(args.seed)
    commands = []
    for _ in range(args.n):
        points = rng.uniform(0, 1, (int(rng.integers(1, 4)), 3))
        points[:, 2] *= 0.3  # near the table top, where contacts happen
        commands.append(Command("ee_waypoints", points))
    seconds = {name: 0.0 for name in worlds}
    settings = worlds["world"].settings
    per_frame = settings.sim_freq // settings.fps
    substeps, touching, executed = 0, 0, 0
    for i, command in enumerate(commands):
        order = list(worlds.items())
        order = order[i % len(order) :] + order[: i % len(order)]  # each world first as often as the others
        out = {}
        for name, w in order:
            out[name] = r = seeded_rollout(w, command, args.seed, i, defer_render=True)
            if r.feasible:
                seconds[name] += r.timings["sim"]
        a, *others = out.values()
        if not a.feasible:
            continue
        impulses = [out[name].frames.object_contacts for name in ("world", "world, every contact read")]
        if not np.array_equal(*impulses):
            raise SystemExit(f"command {i}: object_contacts differ")
        for b in others:
            for field in ("state", "object_poses", "contacts", "end_images"):
                if not np.array_equal(getattr(a.frames, field), getattr(b.frames, field)):
                    raise SystemExit(f"command {i}: {field} differ")
        substeps += (len(a.frames) - 1) * per_frame
        touching += bool(a.touched.any())
        executed += 1
    print(f"{len(commands)} commands, {executed} executed, {touching} touching an object; identical frames in each")
    for name, sec in seconds.items():
        scan = scans[name][0] / max(scans[name][1], 1) * 1e6
        print(
            f"{name:>26}: {sec / max(substeps, 1) * 1e6:6.1f} us per substep (simulation loop, recording), "
            f"of which the contact scan {scan:5.1f} us"
        )
    print(f"ratio to the ManiSkill controller: {seconds['world'] / seconds['ManiSkill controller']:.2f}")
    for name in ("world, every contact read", "world, arm contacts only"):
        print(f"ratio to the {name}: {seconds['world'] / seconds[name]:.2f}")
    for w in worlds.values():
        w.close()


if __name__ == "__main__":
    main()
