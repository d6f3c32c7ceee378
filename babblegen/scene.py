"""Declarative description of a babbling scene: table, objects, workspace box, head camera, home pose.

A task module in tasks/ fills in a `TaskSpec`; the ManiSkill env, the planner's obstacles and the
genome-to-world mapping all read from it, so a new scene is one module and a registration.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from babblegen.world.collision import Box

# The shapes an object may have. Sizes (metres): box = half extents (x, y, z); cylinder (upright) = (radius, half
# height); sphere = (radius,); capsule (lying along x) = (radius, half length of its straight part); dumbbell (lying
# along x) = (ball radius, bar radius, half distance between the balls' centres); ell and tee (flat, two bars) =
# (half length of the bar along x, half length of the bar along y, half width of both bars, half height); hull = its
# bounding box's half extents, the shape given by ``vertices`` (a convex hull, built by PhysX from the points).
SHAPES = ("box", "cylinder", "sphere", "capsule", "dumbbell", "ell", "tee", "hull")


@dataclass(frozen=True)
class Part:
    """One collision and visual primitive of an object, in the object's frame: ``kind`` is box (half extents),
    cylinder (radius, half length; axis z), sphere (radius), capsule (radius, half length; axis x) or hull
    (``vertices``)."""

    kind: str
    size: tuple[float, ...]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vertices: tuple[tuple[float, float, float], ...] = ()

    @property
    def volume(self) -> float:
        s = self.size
        if self.kind == "box":
            return 8 * s[0] * s[1] * s[2]
        if self.kind == "cylinder":
            return float(np.pi * s[0] ** 2 * 2 * s[1])
        if self.kind == "sphere":
            return float(4 / 3 * np.pi * s[0] ** 3)
        if self.kind == "capsule":
            return float(np.pi * s[0] ** 2 * 2 * s[1] + 4 / 3 * np.pi * s[0] ** 3)
        return hull_volume(np.asarray(self.vertices))


def hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of (n, 3) points."""
    from scipy.spatial import ConvexHull

    return float(ConvexHull(points).volume)


@dataclass(frozen=True)
class ObjectSpec:
    """A free object resting on the table: shape and size (`SHAPES`), colour, mass (kg; its density is mass /
    volume), its own material's static and dynamic friction and restitution, and ``xy``, where it rests in the task's
    fixed scene. Every part of an object shares its density and material."""

    name: str
    shape: str
    size: tuple[float, ...]
    color: tuple[float, float, float, float]
    mass: float
    xy: tuple[float, float]
    # PhysX's default material, which the paper's objects share with the table and the robot
    static_friction: float = 0.3
    dynamic_friction: float = 0.3
    restitution: float = 0.0
    vertices: tuple[tuple[float, float, float], ...] = ()  # a hull's points, centred on its bounding box

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ValueError(f"unknown object shape {self.shape!r}; known: {', '.join(SHAPES)}")
        if not all(v > 0 for v in self.size) or not self.mass > 0:
            raise ValueError(f"object {self.name!r}: sizes and mass must be > 0, got {self.size} and {self.mass}")
        if min(self.static_friction, self.dynamic_friction, self.restitution) < 0:
            raise ValueError(f"object {self.name!r}: frictions and restitution must be >= 0")

    def parts(self) -> tuple[Part, ...]:
        """The primitives the object is built from, in its own frame (origin: its bounding box's centre)."""
        s = self.size
        if self.shape in ("box", "cylinder", "sphere", "capsule"):
            return (Part(self.shape, tuple(s)),)
        if self.shape == "hull":
            return (Part("hull", tuple(s), vertices=self.vertices),)
        if self.shape == "dumbbell":
            ball, bar, half = s
            return (
                Part("sphere", (ball,), (-half, 0.0, 0.0)),
                Part("sphere", (ball,), (half, 0.0, 0.0)),
                Part("capsule", (bar, max(half - ball, 1e-3)), (0.0, 0.0, 0.0)),
            )
        lx, ly, w, h = s  # ell, tee: a bar along x and one along y, touching, not overlapping
        y_bar = ly + w
        if self.shape == "ell":
            parts = [((lx, w, h), (0.0, 0.0)), ((w, ly, h), (lx - w, y_bar))]
            low, high = np.array([-lx, -w]), np.array([lx, y_bar + ly])
        else:
            parts = [((lx, w, h), (0.0, 0.0)), ((w, ly, h), (0.0, y_bar))]
            low, high = np.array([-lx, -w]), np.array([lx, y_bar + ly])
        centre = (low + high) / 2
        return tuple(Part("box", half, (float(x - centre[0]), float(y - centre[1]), 0.0)) for half, (x, y) in parts)

    @property
    def half_height(self) -> float:
        """Height of the object's origin above the table when it rests upright."""
        s = self.size
        if self.shape in ("sphere", "capsule", "dumbbell"):
            return float(s[0])
        if self.shape == "ell" or self.shape == "tee":
            return float(s[3])
        return float(s[1] if self.shape == "cylinder" else s[2])

    @property
    def footprint_radius(self) -> float:
        """Radius of the smallest upright circle around the object's horizontal extent, whatever its yaw."""
        s = self.size
        if self.shape in ("cylinder", "sphere"):
            return float(s[0])
        if self.shape == "capsule":
            return float(s[0] + s[1])
        if self.shape == "dumbbell":
            return float(s[0] + s[2])
        if self.shape == "hull":
            return float(np.max(np.hypot(*np.asarray(self.vertices)[:, :2].T)))
        if self.shape in ("ell", "tee"):
            corners = []
            for part in self.parts():
                for sx in (-1, 1):
                    for sy in (-1, 1):
                        corners.append((part.offset[0] + sx * part.size[0], part.offset[1] + sy * part.size[1]))
            return float(np.max(np.hypot(*np.asarray(corners).T)))
        return float(np.hypot(s[0], s[1]))

    @property
    def volume(self) -> float:
        """The sum of the parts' volumes, as PhysX gives each part its mass (parts of a dumbbell overlap a little)."""
        return float(sum(part.volume for part in self.parts()))

    @property
    def density(self) -> float:
        return self.mass / self.volume

    def factors(self) -> dict:
        """The object's factors of variation, as a sidecar row and the episode table record them."""
        out = {
            "name": self.name,
            "shape": self.shape,
            "size": [float(v) for v in self.size],
            "mass": float(self.mass),
            "density": round(self.density, 6),
            "static_friction": float(self.static_friction),
            "dynamic_friction": float(self.dynamic_friction),
            "restitution": float(self.restitution),
            "color": [float(v) for v in self.color],
        }
        if self.vertices:
            out["vertices"] = [list(v) for v in self.vertices]
        return out

    @classmethod
    def from_factors(cls, data: dict, xy: tuple[float, float] = (0.0, 0.0)) -> ObjectSpec:
        """`factors`' inverse (the values exactly as stored)."""
        return cls(
            data["name"],
            data["shape"],
            tuple(data["size"]),
            tuple(data["color"]),
            data["mass"],
            xy,
            data["static_friction"],
            data["dynamic_friction"],
            data["restitution"],
            tuple(tuple(v) for v in data.get("vertices", ())),
        )


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
        floor = Box("floor", (0.0, 0.0, -0.5), (5.0, 5.0, 0.5))
        return [self.table, floor, *self.extra_obstacles]

    def to_dict(self) -> dict:
        return asdict(self)
