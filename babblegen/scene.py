"""Declarative description of a babbling scene: table, objects, workspace box, head camera, home pose.

A task module in tasks/ fills in a `TaskSpec`; the ManiSkill env, the planner's obstacles and the
genome-to-world mapping all read from it, so a new scene is one module and a registration.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from babblegen.shapes import Box, ObjectSpec

FLOOR_HALF_EXTENT = 5.0  # metres: the floor is a square this far each way from the robot; past it an object falls


@dataclass(frozen=True)
class WorkspaceBox:
    """Maps normalised genome coordinates ([0,1]^3 is the box; values may leave it) to world metres."""

    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def to_world(self, norm: np.ndarray) -> np.ndarray:
        low, high = np.asarray(self.low), np.asarray(self.high)
        return low + np.asarray(norm) * (high - low)

    def to_norm(self, world: np.ndarray) -> np.ndarray:
        low, high = np.asarray(self.low), np.asarray(self.high)
        return (np.asarray(world) - low) / (high - low)


@dataclass(frozen=True)
class CameraSpec:
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fov: float  # vertical field of view, radians


@dataclass(frozen=True)
class PlacementRegion:
    """Where one object may start (varied starts): its centre uniform in ``x`` x ``y`` (metres, world frame, on the
    table top) and its yaw uniform in ``yaw`` (radians)."""

    x: tuple[float, float]
    y: tuple[float, float]
    yaw: tuple[float, float] = (-np.pi, np.pi)

    def __post_init__(self) -> None:
        for name in ("x", "y", "yaw"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"placement region {name} must be (low, high) with low <= high, got {(lo, hi)}")


@dataclass(frozen=True)
class StartDistribution:
    """A task's varied starts: one region per object (in the task's object order); objects are drawn in turn and a
    draw is refused when its footprint (the circle around its horizontal extent) comes closer than ``gap`` to an
    object already placed, to a static obstacle, or to the table's edge. Then physics settles the scene."""

    regions: tuple[PlacementRegion, ...]
    gap: float = 0.02  # metres between footprints

    def __post_init__(self) -> None:
        if self.gap < 0:
            raise ValueError(f"gap must be >= 0, got {self.gap}")


@dataclass(frozen=True)
class TaskSpec:
    """Everything babblegen needs to know about a scene."""

    name: str
    env_id: str
    description: str
    table: Box  # the table as one solid box (top surface = center z + half height)
    objects: tuple[ObjectSpec, ...]
    workspace: WorkspaceBox
    camera: CameraSpec
    robot_uid: str = "pr2_like_arm"
    extra_obstacles: tuple[Box, ...] = field(default_factory=tuple)
    starts: StartDistribution | None = None  # where objects may start with ``starts = "varied"`` (None: nowhere)
    # the object set a run with varied starts uses unless told (babblegen.objects): "varied", drawn per start, or
    # "paper", the task's own, where they are the point of the scene
    default_objects: str = "varied"

    def __post_init__(self) -> None:
        if self.starts is not None and len(self.starts.regions) != len(self.objects):
            raise ValueError(f"task {self.name!r}: {len(self.objects)} objects but {len(self.starts.regions)} regions")

    @property
    def table_top(self) -> float:
        return self.table.center[2] + self.table.half_extents[2]

    @property
    def object_names(self) -> list[str]:
        return [o.name for o in self.objects]

    def rest_pose(self, obj: ObjectSpec) -> tuple[float, ...]:
        """Nominal resting pose (x, y, z, qw, qx, qy, qz) of an object on the table."""
        return (obj.xy[0], obj.xy[1], self.table_top + obj.half_height, 1.0, 0.0, 0.0, 0.0)

    def planning_obstacles(self) -> list[Box]:
        """The table, the floor and any extra static boxes (the robot's own body comes from its URDF)."""
        floor = Box("floor", (0.0, 0.0, -0.5), (FLOOR_HALF_EXTENT, FLOOR_HALF_EXTENT, 0.5))
        return [self.table, floor, *self.extra_obstacles]

    def to_dict(self) -> dict:
        return asdict(self)


def yaw_quaternion(yaw: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z) of rotations by ``yaw`` about the vertical axis."""
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def layout_poses(task: TaskSpec, layout: np.ndarray, objects: tuple[ObjectSpec, ...] | None = None) -> np.ndarray:
    """(n_objects, 7) poses (x, y, z, qw, qx, qy, qz) of a layout: each object (the task's, or ``objects``) resting
    on the table top."""
    layout = np.asarray(layout, dtype=np.float64)
    z = np.array([task.table_top + o.half_height for o in (task.objects if objects is None else objects)])
    return np.concatenate([layout[:, :2], z[:, None], yaw_quaternion(layout[:, 2])], axis=1)
