"""Writes tests/reference/canonical.json: canonical rollouts of the default scene and the hashes of what they
record, which tests/test_reference.py re-simulates and compares to the bit.

    .venv/bin/python tests/reference/make_reference.py

The rollouts, together: the arm touching every object, every pair of objects touching each other, pushes and the can
toppled; fixed and varied starts; drawn objects (``--objects varied``), stored whole with their start. Each is a
command (waypoints in normalised workspace coordinates, with a varied start's layout or none), seeded with a run
seed and an attempt index as in a run, simulated with the default settings and its first and last frames rendered.
Recorded per rollout (`babblegen.fingerprint.rollout_digests`): sha256 of its joint states, commanded joints, tool
positions, object poses and contacts (float32 bytes), of its after image and of the head camera's instance masks at
both ends, and its behaviour descriptor (hex) with the descriptor a run with its starts uses. Beside them, what it
touched (the arm, object pairs) and whether the can fell.

Regenerate only when recorded values are meant to change (a new simulator, new default settings), and say why in
the commit.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # tests/: the watched World

OUT = HERE / "canonical.json"
# name -> (waypoints, varied start layout or None, run seed, attempt): movements of earlier NovEB runs, replayed
ROLLOUTS: dict[str, tuple[list, list | None, int, int]] = {
    "fixed: the gray box swept aside": ([[0.5118216247002567, 0.9504636963259353, 0.14415961271963373]], None, 1, 0),
    "fixed: the can knocked over": ([[0.3847810797564037, 0.620355840732748, 0.17298424917803137]], None, 1, 46),
    "fixed: the blue box pushed into the ball": (
        [
            [0.17118435933051498, -0.021110621541629446, 0.407357740370534],
            [0.7255282581252479, 0.6111141844962431, 0.2890792608813688],
        ],
        None,
        1,
        214,
    ),
    "varied: the can knocked into the gray box, the blue box and the ball": (
        [
            [0.5952168497227146, -0.03364709409244093, 0.2710955236343176],
            [0.6661653373678316, 0.8630611444684362, 0.2845521527825324],
        ],
        [
            [0.6841025038118432, 0.12682028797475128, -0.3402198105341614],
            [0.8635645184298457, -0.2786992279878751, -1.8232037165444923],
            [0.9117815324179568, -0.12697899830671022, -0.010339399502056867],
            [0.9880957547358259, -0.24128150016112027, 0.5310280090177373],
        ],
        1,
        1136,
    ),
    "varied: the blue box pushed into the can, the can into the gray box": (
        [[0.7143345840533009, 0.5931833203475035, 0.1520972178810357]],
        [
            [0.7171300292176821, 0.07577778841060984, -0.30301337838367504],
            [0.7894718902198021, -0.03888690125265548, 0.5697390716175126],
            [0.7510270494746655, -0.17338552842258695, -0.8827742835629269],
            [1.0995614578541069, -0.18842237203178394, -1.5315537316308678],
        ],
        1,
        361,
    ),
    "varied: the gray box pushed into the ball": (
        [
            [0.3007369806250341, 0.44310145415399727, 0.6716810733423282],
            [0.6568742379499373, 0.8373196124936126, 0.33721846156624713],
        ],
        [
            [0.888574760712418, 0.07636838754432557, -2.531608060665925],
            [0.5990604721142807, 0.08402880981836042, -1.322371348321094],
            [0.6686448315964187, -0.14630361993467317, 0.5763138250492319],
            [1.0230469047430313, 0.040188946633804845, 2.152320162263244],
        ],
        3,
        514,
    ),
    "varied: the can knocked into the ball and the blue box": (
        [
            [0.35675536189094625, 0.14077397775680234, 0.1672683085937492],
            [0.7661378132245931, 0.7713783307348947, 0.7055694192898343],
        ],
        [
            [0.7078704412151712, 0.029281146981213518, -1.6248240894097146],
            [0.826438414524345, -0.2948547255901877, 2.0000763916845337],
            [0.7705061480340756, -0.16126017709754392, -2.044538092816513],
            [1.0050637166361571, 0.2069788440706326, -0.4446224051843761],
        ],
        203,
        51,
    ),
    "varied: the blue box pushed into the gray box": (
        [
            [0.05856262699208026, 0.765447666492454, 0.23631166445829876],
            [0.41558537855482947, 0.013958225810877356, 0.12667486114289317],
        ],
        [
            [0.8172421114539951, 0.2142785149468874, -2.3765732277660456],
            [0.6113947218783365, -0.21554233680416907, 3.081794779813846],
            [0.7274609019246967, -0.15364508406058505, -1.158654633419161],
            [1.193817147721491, 0.036664979084890637, -0.13581744521194627],
        ],
        203,
        310,
    ),
}


# drawn objects (--objects varied, four slots): name -> (waypoints, run seed, attempt), movements of an earlier run
# from the start it drew for that attempt; the start's layout and objects are stored whole in the reference
OBJECT_SETTINGS = {"objects": "varied", "num_objects": 4}
OBJECT_ROLLOUTS: dict[str, tuple[list, int, int]] = {
    "drawn objects: a sphere pushed into a hull and two dumbbells": (
        [[0.23064647951565842, 0.9814554881995063, 0.2790528458285658]],
        1,
        178,
    ),
    "drawn objects: a capsule pushed over into a cylinder": (
        [
            [0.199397461796393, 0.352481443504243, 0.2252499741071704],
            [-0.21313834733405995, 1.0569540473898018, -0.4070915767487161],
        ],
        1,
        261,
    ),
}


def simulate(world, waypoints, layout, seed: int, attempt: int, objects: list | None = None):
    """One canonical rollout, seeded as attempt ``attempt`` of a run of seed ``seed``; ``objects``: the start's own
    (factors, `ObjectSpec.factors`), None: the task's."""
    from babblegen.evaluation import seeded_rollout
    from babblegen.shapes import ObjectSpec
    from babblegen.world.rollout import Command

    start = None if layout is None else np.asarray(layout, dtype=np.float64)
    drawn = None if objects is None else tuple(ObjectSpec.from_factors(o) for o in objects)
    command = Command("ee_waypoints", np.asarray(waypoints, dtype=np.float64), start, drawn)
    return seeded_rollout(world, command, seed, attempt, defer_render=True)


def descriptor_for(layout) -> str:
    """The descriptor a run with these starts uses by default ("auto")."""
    from babblegen.config import RunConfig

    config = RunConfig()
    config.world = type(config.world)(starts="fixed" if layout is None else "varied")
    return config.resolved_descriptor()


def observed(world, rollout) -> dict:
    """What a rollout touched: the objects the arm touched, the pairs of objects that touched, whether the can
    ended on its side."""
    from test_contacts import CAN, tilt

    names = world.task.object_names
    out = {
        "arm": [names[i] for i in np.flatnonzero(rollout.touched)],
        "pairs": sorted(f"{names[a]}-{names[b]}" for a, b in world.pairs),
    }
    if "can" in names:
        out["can_toppled"] = bool(tilt(rollout.final_poses[CAN, 3:]) > 80)
    else:
        out["toppled"] = [n for n, pose in zip(names, rollout.final_poses, strict=True) if tilt(pose[3:]) > 60]
    return out


def main() -> None:
    from watch import WatchedWorld

    from babblegen.descriptors import make_descriptor
    from babblegen.evaluation import warm_up
    from babblegen.fingerprint import rollout_digests
    from babblegen.tasks import get_task
    from babblegen.world.settings import WorldSettings

    settings = WorldSettings()
    world = WatchedWorld(get_task("noveb_tabletop"), settings)
    warm_up(world, None)
    rollouts = []
    for name, (waypoints, layout, seed, attempt) in ROLLOUTS.items():
        rollout = simulate(world, waypoints, layout, seed, attempt)
        assert rollout.feasible, (name, rollout.reason)
        descriptor = descriptor_for(layout)
        rollouts.append(
            {
                "name": name,
                "waypoints": waypoints,
                "start": layout,
                "seed": seed,
                "attempt": attempt,
                "descriptor_name": descriptor,
                "touches": observed(world, rollout),
                "digests": rollout_digests(rollout, make_descriptor(descriptor)),
            }
        )
        print(name, rollouts[-1]["touches"])
    world.close()
    from babblegen.objects import ObjectSampler
    from babblegen.starts import StartSampler

    drawn_settings = WorldSettings(**OBJECT_SETTINGS)
    world = WatchedWorld(get_task("noveb_tabletop"), drawn_settings)
    warm_up(world, None)
    for name, (waypoints, seed, attempt) in OBJECT_ROLLOUTS.items():
        start = StartSampler(world.task, seed, ObjectSampler("varied", 4, seed)).draw(attempt)
        objects, layout = [o.factors() for o in start.objects], start.layout.tolist()
        rollout = simulate(world, waypoints, layout, seed, attempt, objects)
        assert rollout.feasible, (name, rollout.reason)
        rollouts.append(
            {
                "name": name,
                "waypoints": waypoints,
                "start": layout,
                "objects": objects,
                "seed": seed,
                "attempt": attempt,
                "descriptor_name": "change16",
                "touches": observed(world, rollout),
                "digests": rollout_digests(rollout, make_descriptor("change16")),
            }
        )
        print(name, rollouts[-1]["touches"])
    world.close()
    head = json.dumps({"task": "noveb_tabletop", "world": settings.to_dict(), "objects_world": OBJECT_SETTINGS})[:-1]
    lines = ",\n".join(json.dumps(r) for r in rollouts)
    OUT.write_text(f'{head}, "rollouts": [\n{lines}\n]}}\n')  # one line per rollout
    print(f"{OUT}: {OUT.stat().st_size} bytes")


if __name__ == "__main__":
    main()
