"""`babblegen verify DIR`: re-simulate a sample of a dataset's episodes on this machine and compare them with what
the dataset recorded, value for value: joint states, object poses, contacts, the objects' contact impulses, and the
behaviour descriptor.

The episodes are rebuilt from the dataset's own description of them: the run's configuration (``run.json``, read as
data and validated like any config), each attempt's genome and start (the sidecar). Nothing from the dataset is run
as code. Each rollout is seeded from the run seed and its attempt index, as when the dataset was made, so on a
machine that reproduces babblegen's results every value is equal to the bit.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from babblegen.assembly import build_descriptor
from babblegen.config import ConfigError, resumed_config
from babblegen.dataset.lerobot import frame_columns, load_dataset
from babblegen.dataset.paths import ATTEMPTS, sidecar_dir
from babblegen.dataset.schema import CONTACTS, ENVIRONMENT_STATE, OBJECT_CONTACTS, STATE
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.fingerprint import fingerprint
from babblegen.provenance import differences_from_here
from babblegen.shapes import ObjectSpec
from babblegen.tasks import get_task
from babblegen.world.rollout import Command

# dataset column -> the recorded frames' field it must equal
COLUMNS = {STATE: "state", ENVIRONMENT_STATE: "object_poses", CONTACTS: "contacts"}
# compared too where the dataset has them (datasets made before contact events were recorded do not)
OPTIONAL_COLUMNS = {OBJECT_CONTACTS: "object_contacts"}


def sample(rows: list[dict], n: int) -> list[dict]:
    """``n`` executed attempts spread evenly over the run (all of them when there are fewer)."""
    executed = [r for r in rows if r.get("feasible") and r.get("episode_index") is not None]
    if n <= 0 or n >= len(executed):
        return executed
    return [executed[int(i)] for i in np.linspace(0, len(executed) - 1, n).round()]


def first_difference(
    row: dict, recorded: dict[str, np.ndarray], rollout, descriptor, columns: dict[str, str] = COLUMNS
) -> str | None:
    """What differs between an episode as recorded and as re-simulated (``columns``: dataset column -> frames'
    field), or None."""
    where = f"episode {row['episode_index']} (attempt {row['attempt']})"
    if not rollout.feasible:
        return f"{where}: not executed here ({rollout.reason})"
    frames = rollout.frames
    for column, field in columns.items():
        again = np.asarray(getattr(frames, field), dtype=np.float32).reshape(len(frames), -1)
        before = recorded[column]
        if again.shape != before.shape:
            return f"{where}: {column} has {len(before)} frames recorded, {len(again)} here"
        if not np.array_equal(again, before):
            frame = int(np.flatnonzero((again != before).any(axis=1))[0])
            gap = float(np.abs(again - before).max())
            return f"{where}: {column} differs from frame {frame} on (by up to {gap:.3g})"
    code = descriptor.hex(rollout.code) if rollout.code is not None else None
    if code != row.get("descriptor"):
        return f"{where}: descriptor {code} here, {row.get('descriptor')} recorded"
    return None


def verify(root: Path, episodes: int, echo=print) -> int:
    """Re-simulate and compare; returns the exit status (0: every sampled episode reproduces exactly)."""
    # the simulator, imported when it is needed: `babblegen --help` imports this module
    from babblegen.evaluation import seeded_rollout, warm_up
    from babblegen.world.world import World

    info = read_run_info(root)
    config = resumed_config(info["config"])  # with the settings of its time, where it was stored before them
    rows = sample(read_attempts(root), episodes)
    if not rows:
        raise ConfigError(f"{root} holds no executed episode to verify")
    descriptor = build_descriptor(config)
    ds = load_dataset(root, info["repo_id"])
    present = set(ds.hf_dataset.column_names)
    columns = {**COLUMNS, **{c: f for c, f in OPTIONAL_COLUMNS.items() if c in present}}
    table = frame_columns(ds, columns)
    episode_of = np.asarray(table["episode_index"]).reshape(-1)
    world = World(get_task(config.task), config.world, seed=config.seed)
    try:
        warm_up(world, None)
        echo(fingerprint_line(info.get("fingerprint"), fingerprint(world)))
        for done, row in enumerate(rows, start=1):
            frames = np.flatnonzero(episode_of == row["episode_index"])
            recorded = {c: np.asarray(table[c], dtype=np.float32)[frames].reshape(len(frames), -1) for c in columns}
            rollout = seeded_rollout(
                world, command_of(row), config.seed, row["attempt"], defer_render=True, describe=descriptor
            )
            difference = first_difference(row, recorded, rollout, descriptor, columns)
            if difference is not None:
                echo(f"{done - 1} of {len(rows)} sampled episodes reproduce exactly; then {difference}")
                for line in differences_from_here(info):
                    echo(line)
                return 1
    finally:
        world.close()
    echo(f"{len(rows)} of {len(rows)} sampled episodes reproduce exactly")
    return 0


def fingerprint_line(recorded: dict | None, here: str) -> str:
    """Whether this machine computes like the one(s) that made the dataset, from their fingerprints
    (`babblegen.fingerprint`; run.json's ``fingerprint``)."""
    if recorded is None:
        return f"fingerprint: none recorded (the dataset predates them); this machine's is {here}"
    made = recorded["hash"]
    others = set(recorded.get("nodes", {}).values())
    if here == made and not others:
        return f"fingerprint: this machine computes like the one that made the dataset ({here})"
    if here == made or here in others:
        return (
            f"fingerprint: the dataset was made on machines that compute differently (mixed), this one like one of "
            f"them ({here}): its episodes from the others may differ here"
        )
    return (
        f"fingerprint: this machine computes differently from the one that made the dataset ({here} here, {made} "
        "recorded): expect episodes to differ"
    )


def command_of(row: dict) -> Command:
    """The command an attempt ran, rebuilt from its sidecar row: its genome, its varied start's layout (the poses of
    a made start) and the objects it started with (rows made before objects were recorded: the task's)."""
    start = row.get("start") or {}
    placement = start.get("poses", start.get("layout"))  # a made start's poses, else a drawn layout
    objects = row.get("objects")
    return Command(
        row["kind"],
        np.asarray(row["genome"], dtype=np.float64),
        None if placement is None else np.asarray(placement),
        None if objects is None else tuple(ObjectSpec.from_factors(o) for o in objects),
    )


def register(sub) -> None:
    """Add the `verify` subcommand to the main parser's subparsers."""
    p = sub.add_parser(
        "verify",
        help="re-simulate a sample of a dataset's episodes here and compare them with the recorded ones",
        description=(
            "Re-simulate episodes of a babblegen dataset from their genomes and starts, with the run's seed and "
            "configuration, and compare the joint states, object poses, contacts and behaviour descriptor with "
            "the recorded ones, to the bit. Prints one line; exits 1 when an episode differs, naming the first "
            "difference. Reads the dataset as data only."
        ),
    )
    p.add_argument("dataset", type=Path, metavar="DIR", help="a dataset written by `babblegen generate`")
    p.add_argument(
        "--episodes", type=int, default=12, metavar="N", help="episodes to check, spread over the run (0: all) [12]"
    )
    p.set_defaults(func=cmd_verify)


def cmd_verify(args: argparse.Namespace) -> int:
    root = args.dataset
    if not (sidecar_dir(root) / ATTEMPTS).is_file():
        raise ConfigError(f"{root} is not a babblegen dataset (no {sidecar_dir(root) / ATTEMPTS})")
    if args.episodes < 0:
        raise ConfigError(f"--episodes must not be negative, got {args.episodes}")
    return verify(root, args.episodes, echo=lambda line: print(line, file=sys.stdout))
