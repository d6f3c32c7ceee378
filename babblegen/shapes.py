"""Every shape fact in one home: the objects on the table (`ObjectSpec`, built from `Part` primitives), the static
boxes around them (`Box`), and what follows from their parts alone: volume, bounding extents, footprint, resting
height, yaw symmetry, signed distance and points on the collision surface.

The simulator builds each object from `ObjectSpec.parts` (tasks/tabletop.py), the viewer draws the same parts
(exporters/rerun/scene.py), the sidecar records `ObjectSpec.factors`, and the world model reads the parts' surface
(`ObjectSpec.surface`): what is simulated, seen, recorded and learned is one geometry. Nothing here imports the
simulator.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

# The shapes an object may have. Sizes (metres): box = half extents (x, y, z); cylinder (upright) = (radius, half
# height); sphere = (radius,); capsule (lying along x) = (radius, half length of its straight part); dumbbell (lying
# along x) = (ball radius, bar radius, half distance between the balls' centres); ell and tee (flat, two bars) =
# (half length of the bar along x, half length of the bar along y, half width of both bars, half height); hull = its
# bounding box's half extents, the shape given by ``vertices`` (a convex hull, built by PhysX from the points).
SHAPES = ("box", "cylinder", "sphere", "capsule", "dumbbell", "ell", "tee", "hull")
PART_KINDS = ("box", "cylinder", "sphere", "capsule", "hull")
SURFACE_POINTS = 64  # points on an object's collision surface, by default (`ObjectSpec.surface`)
_CANDIDATES = 48  # surface candidates per kept point, before farthest-point sampling thins them evenly


@dataclass(frozen=True)
class Box:
    """An oriented box obstacle in the world frame (the table, a wall)."""

    name: str
    center: tuple[float, float, float]
    half_extents: tuple[float, float, float]
    rotation: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def hull_of(points: np.ndarray):
    """scipy's convex hull of (n, 3) points (the hull PhysX builds from them)."""
    from scipy.spatial import ConvexHull

    return ConvexHull(np.asarray(points, dtype=np.float64))


def hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of (n, 3) points."""
    return float(hull_of(points).volume)


def hull_triangles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of (n, 3) points as (m, 3 corners, 3) triangles wound outwards and their (m, 3) unit normals."""
    hull = hull_of(points)
    corners = hull.points[hull.simplices].copy()
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    corners[inward] = corners[inward][:, ::-1]
    normal[inward] *= -1
    return corners, normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)


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

    @property
    def half_extents(self) -> np.ndarray:
        """(3,) the half extents of the part's own bounding box, about its offset."""
        s = self.size
        if self.kind == "box":
            return np.array(s, dtype=np.float64)
        if self.kind == "cylinder":
            return np.array([s[0], s[0], s[1]])
        if self.kind == "sphere":
            return np.full(3, float(s[0]))
        if self.kind == "capsule":
            return np.array([s[0] + s[1], s[0], s[0]])
        return np.abs(np.asarray(self.vertices, dtype=np.float64)).max(axis=0)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) the signed distance of (n, 3) points of the object's frame to the part's surface (negative inside;
        a hull's outside distance is the largest over its face planes, exact on and inside it)."""
        p = np.asarray(points, dtype=np.float64) - np.asarray(self.offset)
        s = self.size
        if self.kind == "box":
            q = np.abs(p) - np.asarray(s)
            return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
        if self.kind == "cylinder":
            q = np.stack([np.hypot(p[:, 0], p[:, 1]) - s[0], np.abs(p[:, 2]) - s[1]], axis=-1)
            return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)
        if self.kind == "sphere":
            return np.linalg.norm(p, axis=-1) - s[0]
        if self.kind == "capsule":
            axis = np.zeros_like(p)
            axis[:, 0] = np.clip(p[:, 0], -s[1], s[1])
            return np.linalg.norm(p - axis, axis=-1) - s[0]
        eq = hull_of(self.vertices).equations  # (f, 4): outward unit normal, offset
        return (p @ eq[:, :3].T + eq[:, 3]).max(axis=-1)

    def surface_samples(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) points on the part's surface, uniform by area, and their (n, 3) outward unit normals, in the
        object's frame."""
        s = self.size
        if self.kind == "box":
            faces = [(a, sign) for a in range(3) for sign in (-1.0, 1.0)]
            areas = np.array([4 * np.prod([s[b] for b in range(3) if b != a]) for a, _ in faces])
            pick = rng.choice(len(faces), size=n, p=areas / areas.sum())
            p = (rng.random((n, 3)) * 2 - 1) * np.asarray(s)
            normals = np.zeros((n, 3))
            for i, (a, sign) in enumerate(faces):
                on = pick == i
                p[on, a] = sign * s[a]
                normals[on, a] = sign
        elif self.kind == "cylinder":
            r, h = s
            side, cap = 2 * np.pi * r * 2 * h, np.pi * r * r
            where = rng.choice(3, size=n, p=np.array([side, cap, cap]) / (side + 2 * cap))
            theta = rng.random(n) * 2 * np.pi
            radius = np.where(where == 0, r, r * np.sqrt(rng.random(n)))
            z = np.where(where == 0, (rng.random(n) * 2 - 1) * h, np.where(where == 1, h, -h))
            p = np.stack([radius * np.cos(theta), radius * np.sin(theta), z], axis=-1)
            normals = np.stack([np.cos(theta), np.sin(theta), np.zeros(n)], axis=-1)
            normals[where == 1] = (0.0, 0.0, 1.0)
            normals[where == 2] = (0.0, 0.0, -1.0)
        elif self.kind == "sphere":
            normals = _directions(rng, n)
            p = normals * s[0]
        elif self.kind == "capsule":
            r, half = s
            side, caps = 2 * np.pi * r * 2 * half, 4 * np.pi * r * r
            on_side = rng.random(n) < side / (side + caps)
            theta = rng.random(n) * 2 * np.pi
            normals = np.where(
                on_side[:, None], np.stack([np.zeros(n), np.cos(theta), np.sin(theta)], -1), _directions(rng, n)
            )
            centre_x = np.where(on_side, (rng.random(n) * 2 - 1) * half, np.sign(normals[:, 0]) * half)
            p = normals * r
            p[:, 0] += centre_x
        elif self.kind == "hull":
            corners, face_normals = hull_triangles(np.asarray(self.vertices))
            areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
            tri = rng.choice(len(corners), size=n, p=areas / areas.sum())
            u, v = rng.random(n), rng.random(n)
            flip = u + v > 1
            u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
            c = corners[tri]
            p = c[:, 0] + u[:, None] * (c[:, 1] - c[:, 0]) + v[:, None] * (c[:, 2] - c[:, 0])
            normals = face_normals[tri]
        else:
            raise ValueError(f"unknown part kind {self.kind!r}")
        return p + np.asarray(self.offset), normals


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) unit vectors uniform on the sphere."""
    d = rng.standard_normal((n, 3))
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def farthest_points(points: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` of (m, 3) points chosen one at a time, each the farthest from those already chosen (the
    first: the farthest from their mean): an even cover of a surface.

    Distances are summed per coordinate row, ``(dx² + dy²) + dz²``, the order in which numpy's
    ``linalg.norm(..., axis=1)`` sums a row of three: the same distances to the bit, about 3x faster."""
    points = np.asarray(points, dtype=np.float64)
    x, y, z = np.ascontiguousarray(points.T)
    mean = points.mean(axis=0)

    def distance(cx: np.ndarray, cy: np.ndarray, cz: np.ndarray) -> np.ndarray:
        return np.sqrt((cx * cx + cy * cy) + cz * cz)

    first = int(np.argmax(distance(x - mean[0], y - mean[1], z - mean[2])))
    chosen = [first]
    nearest = distance(x - x[first], y - y[first], z - z[first])
    for _ in range(min(n, len(points)) - 1):
        nxt = int(np.argmax(nearest))
        chosen.append(nxt)
        np.minimum(nearest, distance(x - x[nxt], y - y[nxt], z - z[nxt]), out=nearest)
    return np.array(chosen)


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
        x_bar = lx - w if self.shape == "ell" else 0.0
        bars = [((lx, w, h), (0.0, 0.0)), ((w, ly, h), (x_bar, y_bar))]
        centre = (np.array([-lx, -w]) + np.array([lx, y_bar + ly])) / 2
        return tuple(Part("box", half, (float(x - centre[0]), float(y - centre[1]), 0.0)) for half, (x, y) in bars)

    @property
    def half_height(self) -> float:
        """Height of the object's origin above the table when it rests upright."""
        s = self.size
        if self.shape in ("sphere", "capsule", "dumbbell"):
            return float(s[0])
        if self.shape in ("ell", "tee"):
            return float(s[3])
        return float(s[1] if self.shape == "cylinder" else s[2])

    @property
    def half_extents(self) -> np.ndarray:
        """(3,) the half extents of the object's bounding box in its own frame, over its parts (a new array)."""
        high = np.zeros(3)
        for part in self.parts():
            high = np.maximum(high, np.abs(part.offset) + part.half_extents)
        return high

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
            corners = [
                (part.offset[0] + sx * part.size[0], part.offset[1] + sy * part.size[1])
                for part in self.parts()
                for sx in (-1, 1)
                for sy in (-1, 1)
            ]
            return float(np.max(np.hypot(*np.asarray(corners).T)))
        return float(np.hypot(s[0], s[1]))

    @property
    def yaw_symmetry(self) -> float:
        """The turn about the vertical after which the object looks the same: 0 for any turn (upright cylinders,
        spheres), pi / 2 for a box of square footprint, pi for other boxes and for what lies along x (capsules,
        dumbbells), 2 pi (none) for ells, tees and hulls."""
        if self.shape in ("cylinder", "sphere"):
            return 0.0
        if self.shape == "box":
            return float(np.pi / 2 if np.isclose(self.size[0], self.size[1]) else np.pi)
        if self.shape in ("capsule", "dumbbell"):
            return float(np.pi)
        return float(2 * np.pi)

    @property
    def volume(self) -> float:
        """The sum of the parts' volumes, as PhysX gives each part its mass (parts of a dumbbell overlap a little)."""
        return float(sum(part.volume for part in self.parts()))

    @property
    def density(self) -> float:
        return self.mass / self.volume

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) the signed distance of (n, 3) points of the object's frame to its collision surface (negative
        inside): the smallest over its parts."""
        return np.min([part.signed_distance(points) for part in self.parts()], axis=0)

    def surface(self, n: int = SURFACE_POINTS) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) points on the object's collision surface in its own frame, spread evenly over it (inner faces of
        touching or overlapping parts excluded), and their (n, 3) outward unit normals. Worked out once per spec
        and size; each call returns new arrays."""
        points, normals = _surface(self, n)
        return points.copy(), normals.copy()

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

    @classmethod
    def from_record(cls, data: dict) -> ObjectSpec:
        """An object as a dataset records it: a sidecar row's factors or an object of run.json's task
        (`TaskSpec.to_dict`, with its ``xy``); fields a run made before they were recorded take PhysX's default
        material, a mass of 1 kg and gray."""
        defaults = {"mass": 1.0, "static_friction": 0.3, "dynamic_friction": 0.3, "restitution": 0.0}
        defaults["color"] = (0.5, 0.5, 0.5, 1.0)
        return cls.from_factors({**defaults, **data}, tuple(data.get("xy", (0.0, 0.0))))


@functools.lru_cache(maxsize=4096)
def _surface(spec: ObjectSpec, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`ObjectSpec.surface`: candidates on every part, uniform by area (seeded by nothing but the spec), those on
    or inside another part dropped, then ``n`` of them by farthest-point sampling."""
    parts = spec.parts()
    rng = np.random.default_rng(0)
    areas = np.array([_area(p) for p in parts])
    counts = np.maximum(np.round(areas / areas.sum() * n * _CANDIDATES).astype(int), 1)
    points, normals = [], []
    for i, (part, count) in enumerate(zip(parts, counts, strict=True)):
        p, nrm = part.surface_samples(int(count), rng)
        outside = np.ones(len(p), dtype=bool)
        for j, other in enumerate(parts):
            if j != i:
                outside &= other.signed_distance(p) > 1e-7
        points.append(p[outside])
        normals.append(nrm[outside])
    p, nrm = np.concatenate(points), np.concatenate(normals)
    keep = farthest_points(p, n)
    return p[keep], nrm[keep]


def _area(part: Part) -> float:
    """A part's surface area."""
    s = part.size
    if part.kind == "box":
        return 8 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2])
    if part.kind == "cylinder":
        return float(2 * np.pi * s[0] * 2 * s[1] + 2 * np.pi * s[0] ** 2)
    if part.kind == "sphere":
        return float(4 * np.pi * s[0] ** 2)
    if part.kind == "capsule":
        return float(2 * np.pi * s[0] * 2 * s[1] + 4 * np.pi * s[0] ** 2)
    return float(hull_of(part.vertices).area)
