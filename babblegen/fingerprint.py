"""How a machine computes: the hash of a short canonical simulation and render, recorded in run.json.

Two fixed movements in the run's own world (one sweeps the gray box aside, one knocks the can over: contacts,
sliding, toppling) are simulated and their first and last frames rendered, seeded as an attempt is; the fingerprint
hashes what they record (joint states, commanded joints, tool positions, object poses, contacts, the after image,
the head camera's instance masks at both ends and the after image's pHash). Two machines with equal fingerprints
computed those to the bit; `babblegen verify` compares this machine's with the dataset's first, and a Ray node whose
fingerprint differs from the coordinator's is refused (``allow_mixed_machines``). It takes well under a second in
a warm World.

``python -m babblegen.fingerprint`` reads ``{"task": ..., "world": {...}}`` (JSON) on stdin and prints the
fingerprint of that world here: how a coordinator without a World of its own (a Ray run) computes its own.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from typing import Any

import numpy as np

from babblegen.descriptors import describe_rollout, make_descriptor
from babblegen.tasks import get_task
from babblegen.world.rollout import Command
from babblegen.world.settings import WorldSettings

# Set, it changes this process's fingerprint as a machine that computes otherwise would: how the tests make one
# node of a cluster look like another kind of machine. Not a setting of babblegen's.
SALT_ENV = "BABBLEGEN_FINGERPRINT_SALT"
# (waypoints in normalised workspace coordinates, run seed, attempt): two movements of a seed-1 NovEB run in the
# default scene. The first sweeps the gray box 7 cm aside, the second knocks the can over.
CANONICAL = (
    ([[0.5118216247002567, 0.9504636963259353, 0.14415961271963373]], 1, 0),
    ([[0.3847810797564037, 0.620355840732748, 0.17298424917803137]], 1, 46),
)
FIELDS = ("state", "action", "ee_pos", "object_poses", "contacts")  # the recorded frames', as float32
LENGTH = 16  # hex digits kept


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def rollout_digests(rollout: Any, descriptor: Any | None = None) -> dict[str, Any]:
    """sha256 of each thing a rollout recorded: every per-frame field of ``FIELDS`` (float32 bytes), the after
    image, the head camera's instance masks at both ends when recorded, and the behaviour descriptor's code (hex)
    of ``descriptor``. An infeasible rollout: its reason."""
    if not rollout.feasible:
        return {"feasible": False, "reason": rollout.reason}
    frames = rollout.frames
    out: dict[str, Any] = {"feasible": True, "frames": len(frames)}
    for name in FIELDS:
        out[name] = sha256(np.ascontiguousarray(getattr(frames, name), dtype=np.float32).tobytes())
    out["after_image"] = sha256(np.ascontiguousarray(rollout.after_image).tobytes())
    ends = frames.end_views if frames.end_views is not None else (frames.views or {}).get("head", {})
    if "segmentation" in ends:
        masks = ends["segmentation"]
        out["masks_at_ends"] = sha256(np.ascontiguousarray(masks[[0, -1]]).tobytes())
    if descriptor is not None:
        out["descriptor"] = descriptor.hex(describe_rollout(descriptor, rollout))
    return out


def fingerprint(world: Any) -> str:
    """This machine's fingerprint in ``world`` (a warm `babblegen.world.world.World`): the canonical movements
    simulated and their ends rendered with its settings (`CANONICAL`), hashed."""
    from babblegen.seeded import seeded_rollout  # the simulator: loaded where a World runs, not by this module

    phash = make_descriptor("phash16")
    parts = []
    for waypoints, seed, attempt in CANONICAL:
        command = Command("ee_waypoints", np.asarray(waypoints))
        rollout = seeded_rollout(world, command, seed, attempt, defer_render=True)
        parts.append(rollout_digests(rollout, phash))
    salt = os.environ.get(SALT_ENV, "")
    return sha256(json.dumps([parts, salt], sort_keys=True).encode())[:LENGTH]


def fingerprint_here(task_name: str, settings: Any) -> str:
    """The fingerprint of a fresh World of ``task_name`` with ``settings`` in this process."""
    from babblegen.seeded import warm_up  # the simulator
    from babblegen.world.world import World

    world = World(get_task(task_name), settings)
    try:
        warm_up(world, None)
        return fingerprint(world)
    finally:
        world.close()


def start_in_subprocess(task_name: str, settings: Any):
    """Start computing this machine's fingerprint in a child process (a coordinator keeps no World of its own);
    `finish_subprocess` collects it."""
    import subprocess

    from babblegen.interrupts import spawning

    with spawning():  # a signal to the whole process group reaches the run, which stops its children itself
        child = subprocess.Popen(
            [sys.executable, "-m", "babblegen.fingerprint"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
    child.stdin.write(json.dumps({"task": task_name, "world": settings.to_dict()}))
    child.stdin.close()
    return child


def finish_subprocess(child, timeout: float = 600.0) -> str:
    """The fingerprint `start_in_subprocess` computed."""
    out = child.stdout.read()
    err = child.stderr.read()
    if child.wait(timeout) != 0 or not out.strip():
        raise RuntimeError(f"computing this machine's fingerprint failed:\n{err[-2000:]}")
    return out.strip().splitlines()[-1]


def main() -> None:
    os.environ.setdefault("LP_NUM_THREADS", "1")
    spec = json.loads(sys.stdin.read())
    print(fingerprint_here(spec["task"], WorldSettings(**spec["world"])), flush=True)
    sys.stdout.flush()
    os._exit(0)  # no bindings' leak report at teardown


if __name__ == "__main__":
    main()
