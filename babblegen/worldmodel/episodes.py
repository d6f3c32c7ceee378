"""Datasets as the world-model evaluation reads them: per executed episode the commanded joints (``action``), the
arm's joints (``observation.state``) and every object's pose in every frame (``observation.environment_state``),
read with LeRobot's own loader, beside the sidecar's attempt index, explorer, genome and start; the budgets a
comparison cuts a dataset to (its first N attempts, its first N episodes); and the outcome of each episode, by
stratum.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from babblegen.config import ConfigError
from babblegen.dataset import schema
from babblegen.dataset.lerobot import load_dataset
from babblegen.dataset.paths import ATTEMPTS, sidecar_dir
from babblegen.dataset.sidecar import read_attempts
from babblegen.shapes import SHAPES, SURFACE_POINTS, ObjectSpec
from babblegen.worldmodel.poses import tilt_of

ACTION, STATE, POSES = schema.ACTION, schema.STATE, schema.ENVIRONMENT_STATE
COLUMNS = (ACTION, STATE, POSES)
MOVED = 0.01  # metres of 3-D displacement, first frame to last: an object "moves" (the sidecar's and report's 1 cm)
TOPPLED = np.deg2rad(30.0)  # an object whose up axis ends tilted more than this from its start is toppled
# the outcome strata, in the order an episode is assigned to the first that fits, last to first
STRATA = ("nothing_moved", "one_object", "several_objects", "toppled_rolled_off")


class EvaluationError(ConfigError):
    """Bad input to the evaluation: reported on one line, exit status 2."""


# An object's properties as the world model reads them (`object_vector`): one number each, SI units.
PROPERTIES = (
    *(f"shape_{s}" for s in SHAPES),  # one-hot over babblegen.shapes.SHAPES
    "footprint_radius",  # m: the upright circle around its horizontal extent, whatever its yaw
    "half_height",  # m: its origin's height above the table when it rests upright
    "half_extent_x",  # m: its bounding box's half extents in its own frame
    "half_extent_y",
    "half_extent_z",
    "volume",  # m^3
    "mass",  # kg
    "density",  # kg/m^3
    "static_friction",
    "dynamic_friction",
    "restitution",
    "yaw_symmetry",  # rad: the turn about the vertical after which it looks the same (0: any turn)
    # m: SURFACE_POINTS points on its collision surface in its own frame (`ObjectSpec.surface`), then their outward
    # unit normals
    *(f"surface_{i:02d}_{a}" for i in range(SURFACE_POINTS) for a in "xyz"),
    *(f"normal_{i:02d}_{a}" for i in range(SURFACE_POINTS) for a in "xyz"),
)
PROPERTY = {name: i for i, name in enumerate(PROPERTIES)}
SUMMARY = PROPERTY["surface_00_x"]  # the properties before the surface: shape, sizes, mass, material, symmetry


def object_vector(spec: ObjectSpec) -> np.ndarray:
    """The object's geometry and material as `PROPERTIES` lists them (a new array each call)."""
    return _object_vector(spec).copy()


@functools.lru_cache(maxsize=4096)
def _object_vector(spec: ObjectSpec) -> np.ndarray:
    """`object_vector`, worked out once per spec: a scene's vectors are asked for at every frame of a rollout."""
    out = np.zeros(len(PROPERTIES))
    out[PROPERTY[f"shape_{spec.shape}"]] = 1.0
    out[PROPERTY["footprint_radius"]] = spec.footprint_radius
    out[PROPERTY["half_height"]] = spec.half_height
    out[PROPERTY["half_extent_x"] : PROPERTY["half_extent_z"] + 1] = spec.half_extents
    out[PROPERTY["volume"]] = spec.volume
    out[PROPERTY["mass"]] = spec.mass
    out[PROPERTY["density"]] = spec.density
    out[PROPERTY["static_friction"]] = spec.static_friction
    out[PROPERTY["dynamic_friction"]] = spec.dynamic_friction
    out[PROPERTY["restitution"]] = spec.restitution
    out[PROPERTY["yaw_symmetry"]] = spec.yaw_symmetry
    points, normals = spec.surface(SURFACE_POINTS)
    out[SUMMARY:] = np.concatenate([points.reshape(-1), normals.reshape(-1)])
    return out


@dataclass(frozen=True)
class Scene:
    """What the evaluation needs to know of a dataset's task (from its ``run.json``): the task's objects (the
    paper's, or the stand-ins in the slots of a run that draws its objects: each episode's own are in
    `EpisodeSet.objects`), and the table top's extent and height."""

    task: str
    specs: tuple[ObjectSpec, ...]
    table: tuple[float, float, float, float]  # x0, x1, y0, y1 of the table top, metres
    top: float  # the table top's height, metres
    robot: str

    @classmethod
    def from_run(cls, run: dict) -> Scene:
        task = run["task"]
        c, h = task["table"]["center"], task["table"]["half_extents"]
        return cls(
            task=task["name"],
            specs=tuple(ObjectSpec.from_record(o) for o in task["objects"]),
            table=(c[0] - h[0], c[0] + h[0], c[1] - h[1], c[1] + h[1]),
            top=float(c[2] + h[2]),
            robot=task["robot_uid"],
        )

    @property
    def objects(self) -> tuple[str, ...]:
        """The objects' names (slots, where the run draws its objects)."""
        return tuple(o.name for o in self.specs)

    @property
    def shapes(self) -> tuple[str, ...]:
        return tuple(o.shape for o in self.specs)

    @property
    def properties(self) -> np.ndarray:
        """(K, P) the task's objects' `object_vector`s."""
        return np.stack([object_vector(o) for o in self.specs])

    @property
    def half_heights(self) -> np.ndarray:
        return np.array([o.half_height for o in self.specs])

    @property
    def yaw_symmetry(self) -> np.ndarray:
        """Per object, the turn about the vertical after which it looks the same (0: any turn, round objects)."""
        return np.array([o.yaw_symmetry for o in self.specs])


@dataclass
class EpisodeSet:
    """Executed episodes of one or more datasets of one scene, in attempt order within each dataset."""

    scene: Scene
    source: np.ndarray  # (E,) str: the dataset each episode comes from
    attempt: np.ndarray  # (E,) int: its attempt index in that run
    explorer: np.ndarray  # (E,) str
    identity: np.ndarray  # (E,) str: the commanded movement and its start (equal: the same episode again)
    layout: np.ndarray  # (E,) str: its start layout (equal: the same start)
    commands: list[dict] = field(repr=False)  # per episode its sidecar's kind, genome and start layout (or None)
    actions: list[np.ndarray] = field(repr=False)  # per episode (T, 7) commanded joints, radians
    states: list[np.ndarray] = field(repr=False)  # per episode (T, 7) the arm's joints
    poses: list[np.ndarray] = field(repr=False)  # per episode (T, K, 7) object poses: x, y, z, qw, qx, qy, qz
    # (E, K, P) per episode and slot the object's `object_vector` (None: the scene's objects in every episode)
    objects: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.objects is None:
            props = self.scene.properties
            self.objects = np.repeat(props[None], len(self.attempt), axis=0)

    def __len__(self) -> int:
        return len(self.attempt)

    @property
    def half_heights(self) -> np.ndarray:
        """(E, K) each object's resting height of its origin above the table."""
        return self.objects[..., PROPERTY["half_height"]]

    @property
    def yaw_symmetry(self) -> np.ndarray:
        """(E, K) each object's yaw symmetry (`yaw_symmetry`; 0: any turn)."""
        return self.objects[..., PROPERTY["yaw_symmetry"]]

    @property
    def shapes(self) -> np.ndarray:
        """(E, K) each object's shape (one of `SHAPES`)."""
        first = PROPERTY[f"shape_{SHAPES[0]}"]
        return np.array(SHAPES)[self.objects[..., first : first + len(SHAPES)].argmax(axis=-1)]

    @property
    def spheres(self) -> np.ndarray:
        """(E, K) whether the object is a sphere (it rolls away rather than stands tilted)."""
        return self.objects[..., PROPERTY["shape_sphere"]] > 0.5

    def take(self, idx: np.ndarray) -> EpisodeSet:
        idx = np.asarray(idx, dtype=np.int64)
        parts = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                parts[f.name] = value[idx]
            elif isinstance(value, list):
                parts[f.name] = [value[i] for i in idx]
            else:
                parts[f.name] = value
        return EpisodeSet(**parts)

    @staticmethod
    def union(parts: list[EpisodeSet]) -> EpisodeSet:
        scene = parts[0].scene
        for p in parts[1:]:  # the objects may differ (each episode has its own), not the slots, table or arm
            same = (len(p.scene.objects), p.scene.table, p.scene.top, p.scene.robot)
            if same != (len(scene.objects), scene.table, scene.top, scene.robot):
                raise EvaluationError(
                    f"datasets of different scenes: {scene.task} with {len(scene.objects)} objects and "
                    f"{p.scene.task} with {len(p.scene.objects)}"
                )
        out = {"scene": scene}
        for f in fields(EpisodeSet):
            if f.name == "scene":
                continue
            values = [getattr(p, f.name) for p in parts]
            out[f.name] = sum(values, []) if isinstance(values[0], list) else np.concatenate(values)
        return EpisodeSet(**out)

    @property
    def first(self) -> np.ndarray:
        """(E, K, 7) the objects' poses in each episode's first frame (its start, settled)."""
        return np.stack([p[0] for p in self.poses])

    @property
    def final(self) -> np.ndarray:
        """(E, K, 7) the objects' poses in each episode's last frame (the "after" scene)."""
        return np.stack([p[-1] for p in self.poses])


@dataclass(frozen=True)
class Dataset:
    """One babblegen dataset on disk, read once: its run description and its executed episodes."""

    root: Path
    run: dict
    episodes: EpisodeSet
    attempts_made: int  # attempts in its sidecar, executed or not

    @property
    def seed(self) -> int:
        return int(self.run["config"]["seed"])

    @property
    def label(self) -> str:
        config = self.run["config"]
        return f"{config['explorer']}, {config['world'].get('starts', 'fixed')} starts, seed {config['seed']}"

    def budget(self, attempts: int | None = None, episodes: int | None = None) -> EpisodeSet:
        """Its episodes from the first ``attempts`` attempts, then the first ``episodes`` of those."""
        keep = np.arange(len(self.episodes))
        if attempts is not None:
            if attempts > self.attempts_made:
                raise EvaluationError(
                    f"{self.root} holds {self.attempts_made} attempts, fewer than the {attempts} asked for: "
                    f"extend it with babblegen generate --out {self.root} --resume --max-attempts {attempts}"
                )
            keep = keep[self.episodes.attempt[keep] < attempts]
        if episodes is not None:
            keep = keep[:episodes]
        return self.episodes.take(keep)


def layout_key(row: dict) -> str:
    """A start's identity: the drawn layout, or the task's fixed scene."""
    layout = _placement(row)
    return "task" if layout is None else hashlib.blake2b(np.asarray(layout, dtype=np.float64).tobytes()).hexdigest()


def _placement(row: dict) -> list | None:
    """What the world placed to start an attempt: a made start's poses, a drawn layout, or None (the task's)."""
    start = row.get("start") or {}
    return start.get("poses", start.get("layout"))


def identity_key(row: dict) -> str:
    """A movement from a start: equal keys are the same episode (the world is deterministic)."""
    raw = json.dumps([row.get("kind"), row.get("genome")]).encode() + layout_key(row).encode()
    return hashlib.blake2b(raw, digest_size=16).hexdigest()


def read_dataset(root: Path) -> Dataset:
    """A dataset's executed episodes, read with LeRobot's loader; a missing, empty or unsuitable dataset is an
    `EvaluationError` naming what is missing."""
    root = Path(root)
    if not root.is_dir():
        raise EvaluationError(f"{root}: no such dataset directory")
    run_path = sidecar_dir(root) / "run.json"
    if not run_path.is_file() or not (sidecar_dir(root) / ATTEMPTS).is_file():
        raise EvaluationError(f"{root} is not a babblegen dataset (no {run_path} or {ATTEMPTS})")
    run = json.loads(run_path.read_text())
    rows = read_attempts(root)
    executed = [r for r in rows if r.get("feasible") and r.get("episode_index") is not None]
    if not executed:
        raise EvaluationError(f"{root} holds no executed episode ({len(rows)} attempts, none executed)")
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise EvaluationError(f"{root} has no meta/info.json: not a finished LeRobot dataset")
    features = json.loads(info_path.read_text()).get("features", {})
    missing = [c for c in COLUMNS if c not in features]
    if missing:
        raise EvaluationError(f"{root} lacks the column(s) the evaluation needs: {', '.join(missing)}")
    scene = Scene.from_run(run)
    table = _read_columns(root, run["repo_id"])
    episode = np.asarray(table["episode_index"]).reshape(-1)
    action = np.asarray(table[ACTION], dtype=np.float64)
    state = np.asarray(table[STATE], dtype=np.float64)
    poses = np.asarray(table[POSES], dtype=np.float64).reshape(len(episode), len(scene.objects), 7)
    order = np.argsort(episode, kind="stable")
    starts = np.searchsorted(episode[order], [r["episode_index"] for r in executed])
    ends = np.searchsorted(episode[order], [r["episode_index"] for r in executed], side="right")
    if np.any(ends - starts < 2):
        bad = next(r["episode_index"] for r, a, b in zip(executed, starts, ends, strict=True) if b - a < 2)
        raise EvaluationError(f"{root}: episode {bad} of the sidecar has fewer than 2 frames in the dataset")
    rows_of = [order[a:b] for a, b in zip(starts, ends, strict=True)]
    episodes = EpisodeSet(
        scene=scene,
        source=np.array([str(root)] * len(executed)),
        attempt=np.array([int(r["attempt"]) for r in executed], dtype=np.int64),
        explorer=np.array([str(r.get("explorer", run["config"]["explorer"])) for r in executed]),
        identity=np.array([identity_key(r) for r in executed]),
        layout=np.array([layout_key(r) for r in executed]),
        commands=[
            {"kind": r["kind"], "genome": r["genome"], "layout": _placement(r), "objects": r.get("objects")}
            for r in executed
        ],
        actions=[action[r] for r in rows_of],
        states=[state[r] for r in rows_of],
        poses=[poses[r] for r in rows_of],
        objects=episode_objects(scene, executed),
    )
    return Dataset(root, run, episodes, len(rows))


def episode_objects(scene: Scene, rows: list[dict]) -> np.ndarray:
    """(E, K, P) the `object_vector` of each row's objects, slot by slot: its own (the sidecar's "objects"), or the
    task's for rows made before objects were recorded."""
    task = scene.properties
    cache: dict[str, np.ndarray] = {}
    out = np.empty((len(rows), *task.shape))
    for i, row in enumerate(rows):
        objects = row.get("objects")
        if objects is None:
            out[i] = task
            continue
        if len(objects) != len(scene.specs):
            raise EvaluationError(
                f"attempt {row.get('attempt')} holds {len(objects)} objects, its task {len(scene.specs)} slots"
            )
        for k, factors in enumerate(objects):
            key = json.dumps(factors, sort_keys=True)
            if key not in cache:
                cache[key] = object_vector(ObjectSpec.from_record(factors))
            out[i, k] = cache[key]
    return out


def _read_columns(root: Path, repo_id: str) -> dict:
    """The frame table's columns the evaluation reads, through LeRobot's loader (offline)."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import datasets

    datasets.disable_progress_bars()
    ds = load_dataset(root, repo_id)
    return ds.hf_dataset.select_columns(["episode_index", *COLUMNS]).with_format("numpy")[:]


def object_distance_moved(episodes: EpisodeSet) -> np.ndarray:
    """(E, K) each object's 3-D displacement from the first frame to the last, metres."""
    return np.linalg.norm(episodes.final[..., :3] - episodes.first[..., :3], axis=-1)


def outcomes(episodes: EpisodeSet) -> tuple[np.ndarray, np.ndarray]:
    """(moved (E, K) bool, stratum (E,) index into `STRATA`) of each episode, from its first and last frames: an
    object moved when displaced over `MOVED`; an episode is ``toppled_rolled_off`` when an object toppled (tilted
    over `TOPPLED`), a round object that cannot stand tilted (a sphere) moved, or an object left the table top
    (beyond its edges, or untoppled over 2 cm below its upright resting height and its start, whichever is lower);
    else ``several_objects`` when two or more moved, ``one_object`` when one did, ``nothing_moved`` otherwise."""
    scene = episodes.scene
    first, final = episodes.first, episodes.final
    moved = object_distance_moved(episodes) > MOVED
    toppled = np.abs(tilt_of(final[..., 3:]) - tilt_of(first[..., 3:])) > TOPPLED
    rolled = moved & episodes.spheres
    x0, x1, y0, y1 = scene.table
    # below where it rested: an object can settle lower than its upright resting height (a hull on another face)
    rest = np.minimum(scene.top + episodes.half_heights, first[..., 2])
    off = (final[..., 2] < rest - 0.02) & ~toppled
    off |= (final[..., 0] < x0) | (final[..., 0] > x1) | (final[..., 1] < y0) | (final[..., 1] > y1)
    stratum = np.minimum(moved.sum(axis=1), 2)
    stratum[(toppled | rolled | off).any(axis=1)] = 3
    return moved, stratum
