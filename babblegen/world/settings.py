"""Simulation, rendering and planning settings: a plain dataclass, importable without the simulator."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

from babblegen.camera_views import CAMERA_PRESETS, MAX_CAMERA_SIDE, CameraView
from babblegen.objects import ObjectRanges, check_object_set
from babblegen.scene import TaskSpec

MODALITIES = ("depth", "segmentation")
RETURNS_HOME = ("retrace", "direct")  # back along the path out, or straight home in joint space where that is free
START_MODES = ("fixed", "varied")  # the paper's scene for every episode, or a settled layout drawn per start


@dataclass(frozen=True)
class WorldSettings:
    """Simulation, rendering and planning choices (all recorded with every dataset)."""

    camera_width: int = 128
    camera_height: int = 128
    fps: int = 10  # recorded frames per second of simulated time
    control_freq: int = 20  # joint targets per second
    sim_freq: int = 100  # physics steps per second
    # PhysX's persistent contact manifolds (PCM), with the scene's boxes (objects' parts, table, floor, obstacles)
    # colliding as convex hulls of their corners. PCM's box-box contact generator runs approximate-reciprocal
    # instructions (rcpps), whose results differ between CPU makers; as hulls no pair of boxes meets it (the arm's
    # links never touch each other), so a run records the same values on Intel and AMD. Without PCM, PhysX's
    # box-box generator pushes from up to both shapes' contact offsets (2 cm each) apart (docs/reproducibility.md).
    # Runs made before: PCM on with PhysX boxes, then PCM off; they resume as they were made.
    pcm: bool = True
    box_hulls: bool = True
    max_joint_speed: float = 2.0  # rad/s on the fastest joint along the path: the arm's limit (its URDF's)
    # the longest movement out (planned, at max_joint_speed) a rollout executes: longer ones are infeasible
    # ("too_long"), found by planning alone; it bounds an episode's frames, and so its cost (0: no bound, the paper)
    max_move_seconds: float = 4.0
    # whether the way from home to the first waypoint counts toward max_move_seconds; false leaves movements on
    # the table's far side from home (the gray box's) as long as those on its near side (docs/departures.md)
    count_approach: bool = True
    dwell_seconds: float = 0.2  # pause at the final waypoint before returning
    # how the arm goes home after the dwell: "retrace" (back through every waypoint) or "direct" (a straight line
    # in joint space, where it is collision-free with the table and the robot, else back along the path)
    return_home: str = "retrace"
    settle_seconds: float = 0.5  # at least this long after the return, before the after image ...
    max_settle_seconds: float = 3.0  # ... and longer, up to this, while an object still moves
    rest_speed: float = 0.005  # m/s (and 10x that in rad/s): an object slower than this is at rest
    plan_iterations: int = 20_000  # RRTConnect iterations per segment (deterministic, load-independent)
    plan_time_limit: float = 30.0  # seconds per segment: a safety net only
    ik_tolerance: float = 0.005  # metres
    ik_seeds: int = 8
    collision_margin: float = 0.01  # metres kept from table, floor and robot body
    # where episodes start: "varied" (layouts the task declares, drawn per start and settled by physics;
    # babblegen.starts), the default since a world model trained on it predicts scenes it never saw
    # (docs/world_model.md), or "fixed" (the paper's scene, every time)
    starts: str = "varied"
    start_settle_seconds: float = 2.0  # a varied start settles until at rest, at most this long (else not used)
    # which objects stand on the table (babblegen.objects): "paper" (the task's own, every episode), "varied" (drawn
    # per start: shape, size, mass, friction, restitution, colour) or "heldout" (shapes and property bands no varied
    # draw produces: test sets); "auto" (`for_task`), a run's default (babblegen.config): with varied starts the
    # task's default object set, "varied" unless its own objects are the point of the scene (since a world model
    # trained on varied objects predicts new shapes and the paper's own objects as well: docs/objects.md), with fixed
    # starts "paper"; how many (the task's four for "paper", 1 to 8 otherwise); what varied draws from
    objects: str = "paper"
    num_objects: int = 4
    object_ranges: ObjectRanges = field(default_factory=ObjectRanges)
    # what is recorded: the head camera (the behaviour camera, always) and any others, each with its modalities
    cameras: tuple[CameraView, ...] = field(default_factory=lambda: default_cameras())

    def __post_init__(self):
        views = tuple(v if isinstance(v, CameraView) else CameraView(**dict(v)) for v in self.cameras)
        object.__setattr__(self, "cameras", views)
        if not isinstance(self.object_ranges, ObjectRanges):
            object.__setattr__(self, "object_ranges", ObjectRanges(**dict(self.object_ranges)))
        check_object_set("varied" if self.objects == "auto" else self.objects, self.num_objects)
        names = [v.name for v in views]
        if "head" not in names:
            raise ValueError("the cameras must include 'head', the behaviour camera the search looks through")
        if len(set(names)) != len(names):
            raise ValueError(f"camera names must differ, got {names}")
        if not self.max_move_seconds >= 0:
            raise ValueError(f"max_move_seconds must be >= 0 (0: no bound), got {self.max_move_seconds}")
        if self.return_home not in RETURNS_HOME:
            raise ValueError(f"unknown return_home {self.return_home!r}; choose one of: {', '.join(RETURNS_HOME)}")
        if self.starts not in START_MODES:
            raise ValueError(f"unknown starts {self.starts!r}; choose one of: {', '.join(START_MODES)}")
        if not self.start_settle_seconds > 0:
            raise ValueError(f"start_settle_seconds must be > 0, got {self.start_settle_seconds}")
        if self.control_freq % self.fps or self.sim_freq % self.control_freq:
            raise ValueError("need fps | control_freq | sim_freq (e.g. 10, 20, 100)")
        if min(self.camera_width, self.camera_height) < 16:
            raise ValueError("camera resolution must be at least 16x16")
        if max(self.camera_width, self.camera_height) > MAX_CAMERA_SIDE:
            raise ValueError(
                f"camera resolution must be at most {MAX_CAMERA_SIDE}x{MAX_CAMERA_SIDE}, "
                f"got {self.camera_width}x{self.camera_height}"
            )

    def to_dict(self) -> dict:
        return asdict(self)

    def for_task(self, task: TaskSpec) -> WorldSettings:
        """These settings with ``objects = "auto"`` resolved for ``task``: its default object set with varied
        starts, else the task's own objects ("paper")."""
        if self.objects != "auto":
            return self
        varied = self.starts == "varied" and task.starts is not None
        return replace(self, objects=task.default_objects if varied else "paper")

    @property
    def head(self) -> CameraView:
        return next(v for v in self.cameras if v.name == "head")


def default_cameras() -> tuple[CameraView, ...]:
    """The head camera's colour and instance masks. Chosen by cost (docs/views.md; benchmarks/bench_views.py):
    masks cost 21 % of a run's executed episodes per second on 2 cores, depth 61 %, a second camera 58 %, so
    depth (``--depth``) and the front view (``--cameras head,front``) are one flag away."""
    return (replace(CAMERA_PRESETS["head"], segmentation=True),)


def cameras_from_names(names: list[str], depth: bool | None, segmentation: bool | None) -> list[dict[str, Any]]:
    """``--cameras head,front`` with ``--depth`` / ``--segmentation`` (None: what the default cameras record)."""
    unknown = [n for n in names if n not in CAMERA_PRESETS]
    if unknown:
        raise ValueError(f"unknown camera {unknown[0]!r}; choose from {', '.join(CAMERA_PRESETS)}")
    defaults = {v.name: v for v in default_cameras()}
    kinds = {"depth": defaults["head"].depth, "segmentation": defaults["head"].segmentation}
    views = []
    for name in dict.fromkeys(["head", *names]):
        view = defaults.get(name, replace(CAMERA_PRESETS[name], **kinds))  # the others: the head camera's kinds
        view = replace(
            view,
            depth=view.depth if depth is None else depth,
            segmentation=view.segmentation if segmentation is None else segmentation,
        )
        views.append(asdict(view))
    return views


# Stored before cameras were a setting: the head camera's colour, nothing else.
LEGACY_CAMERAS = ({"name": "head", "mount": "head"},)
