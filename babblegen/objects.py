"""Object sets: which objects stand on the table when an episode starts.

``paper`` is the task's own objects (the NovEB paper's gray box, can, blue box and ball), every episode. ``varied``
draws every new start's objects: shape kinds (`VARIED_SHAPES`), sizes, density (so mass), static and dynamic
friction, restitution and colour. ``heldout`` draws objects that no ``varied`` draw can produce, for test sets: other
shape families (`HELDOUT_SHAPES`, two flat bars) and the middle band of each physical range (`ObjectRanges.bands`),
held out by construction. A draw is a function of the run seed and the attempt index alone (`ObjectSampler.draw`),
like a start's layout (`babblegen.starts`). The objects stand in fixed *slots* (``object_0`` ...), whose names and
instance-mask ids stay the same whatever object a start puts there (`slot_task`). Importable without the simulator.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, replace

import numpy as np

from babblegen.scene import PlacementRegion, StartDistribution, TaskSpec
from babblegen.shapes import ObjectSpec

OBJECT_SETS = ("paper", "varied", "heldout")
VARIED_SHAPES = ("box", "cylinder", "sphere", "capsule", "dumbbell", "hull")
HELDOUT_SHAPES = ("ell", "tee")
MAX_OBJECTS = 8
_STREAM = 0x0B7EC7  # the object draws' own random stream, apart from the layouts' and the explorer's
# where every slot may start with drawn objects: the paper's regions of the gray box, the can and the blue box together
# (within the arm's reach), always whole in the head camera's view
SLOT_REGION = PlacementRegion(x=(0.58, 1.0), y=(-0.38, 0.24))


@dataclass(frozen=True)
class ObjectRanges:
    """The ranges ``varied`` and ``heldout`` draw from. ``size``: every dimension of a shape, metres (a box's half
    extents, a radius; a bar's width is a third of it); ``density`` kg/m^3 (log-uniform; mass = density x volume);
    ``static_friction`` (dynamic: 0.6 to 1.0 times it); ``restitution``. Each physical range is cut in three:
    ``varied`` draws from the outer thirds, ``heldout`` from the middle one (on a log scale for density)."""

    size: tuple[float, float] = (0.03, 0.06)
    density: tuple[float, float] = (100.0, 1000.0)
    static_friction: tuple[float, float] = (0.2, 1.0)
    restitution: tuple[float, float] = (0.0, 0.6)

    def __post_init__(self) -> None:
        for name in ("size", "density", "static_friction", "restitution"):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != 2:
                raise ValueError(f"object {name} must be a range [low, high], got {list(value)}")
            object.__setattr__(self, name, value)
            low, high = value
            if low > high:
                raise ValueError(f"object {name} range has its low above its high: [{low}, {high}]")
        if self.size[0] <= 0 or self.density[0] <= 0:
            raise ValueError(f"object sizes and densities must be > 0, got size {self.size}, density {self.density}")
        if self.static_friction[0] < 0 or self.restitution[0] < 0:
            raise ValueError(
                f"object friction and restitution must be >= 0, got {self.static_friction} and {self.restitution}"
            )
        if self.size[1] > 0.08:
            raise ValueError(f"object sizes must be at most 0.08 m (the arm pushes them, the camera sees them whole), "
                             f"got {self.size[1]}")  # fmt: skip

    def bands(self, name: str) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
        """A physical range cut in three (low, middle, high thirds; density's on a log scale)."""
        low, high = getattr(self, name)
        if name == "density":
            a, b = np.log(low), np.log(high)
            cuts = np.exp([a, a + (b - a) / 3, a + 2 * (b - a) / 3, b])
        else:
            cuts = np.array([low, low + (high - low) / 3, low + 2 * (high - low) / 3, high])
        c = [float(v) for v in cuts]
        return (c[0], c[1]), (c[1], c[2]), (c[2], c[3])


def slot_names(count: int) -> list[str]:
    return [f"object_{i}" for i in range(count)]


def slot_task(task: TaskSpec, object_set: str, count: int) -> TaskSpec:
    """The task a run with this object set uses: the task itself for ``paper``; else the same table, camera and
    workspace with ``count`` slots, each holding a stand-in object until a start puts its own there, and each free
    to start anywhere in `SLOT_REGION`."""
    if object_set == "paper":
        return task
    names = slot_names(count)
    grid = np.linspace(SLOT_REGION.y[0] + 0.06, SLOT_REGION.y[1] - 0.06, max(count, 1))
    stand_ins = tuple(
        ObjectSpec(n, "box", (0.025, 0.025, 0.025), (0.5, 0.5, 0.5, 1.0), 0.1, (0.72 + 0.25 * (i % 2), float(grid[i])))
        for i, n in enumerate(names)
    )
    starts = StartDistribution(regions=(SLOT_REGION,) * count)
    return replace(task, objects=stand_ins, starts=starts)


class ObjectSampler:
    """Draws a start's objects for a run seed: ``draw(attempt)`` is a function of (seed, attempt) alone."""

    def __init__(self, object_set: str, count: int, seed: int, ranges: ObjectRanges | None = None):
        if object_set not in ("varied", "heldout"):
            raise ValueError(f"only varied and heldout objects are drawn, not {object_set!r}")
        self.object_set, self.count, self.seed = object_set, int(count), int(seed)
        self.ranges = ranges or ObjectRanges()
        self.shapes = VARIED_SHAPES if object_set == "varied" else HELDOUT_SHAPES
        self.names = slot_names(count)

    def draw(self, attempt: int, again: int = 0) -> tuple[ObjectSpec, ...]:
        """The objects of the start drawn for ``attempt``; ``again`` > 0: another set for it (when a set found no
        place in the start regions, `babblegen.starts.StartSampler.draw`)."""
        key = [self.seed, _STREAM, int(attempt)] + ([int(again)] if again else [])
        rng = np.random.default_rng(key)
        return tuple(self.one(name, rng) for name in self.names)

    def _physical(self, name: str, rng: np.random.Generator) -> float:
        """A value of a physical range: from a random outer third (varied) or the middle third (heldout)."""
        low, middle, high = self.ranges.bands(name)
        band = middle if self.object_set == "heldout" else (low if rng.random() < 0.5 else high)
        if name == "density":
            return float(np.exp(rng.uniform(np.log(band[0]), np.log(band[1]))))
        return float(rng.uniform(*band))

    def one(self, name: str, rng: np.random.Generator) -> ObjectSpec:
        shape = self.shapes[int(rng.integers(len(self.shapes)))]
        size, vertices = self._size(shape, rng)
        hue, sat, val = rng.random(), rng.uniform(0.35, 0.9), rng.uniform(0.45, 0.95)
        color = (*(round(float(c), 4) for c in colorsys.hsv_to_rgb(hue, sat, val)), 1.0)
        density = self._physical("density", rng)
        friction = self._physical("static_friction", rng)
        dynamic = friction * float(rng.uniform(0.6, 1.0))
        restitution = self._physical("restitution", rng)
        stand_in = ObjectSpec(name, shape, size, color, 1.0, (0.0, 0.0), vertices=vertices)
        mass = density * stand_in.volume
        return ObjectSpec(
            name, shape, size, color, _r(mass), (0.0, 0.0), _r(friction), _r(dynamic), _r(restitution), vertices
        )

    def _size(self, shape: str, rng: np.random.Generator) -> tuple[tuple[float, ...], tuple]:
        lo, hi = self.ranges.size

        def u(a: float = lo, b: float = hi) -> float:
            return _r(rng.uniform(a, b))

        if shape == "box":
            return (u(), u(), u()), ()
        if shape == "cylinder":
            return (u(), u(lo, min(1.5 * hi, 0.08))), ()
        if shape == "sphere":
            return (u(),), ()
        if shape == "capsule":
            return (u(0.7 * lo, 0.75 * hi), u(0.5 * lo, hi)), ()
        if shape == "dumbbell":
            ball = u(0.8 * lo, 0.75 * hi)
            return (ball, _r(ball * rng.uniform(0.35, 0.6)), _r(ball + rng.uniform(0.5 * lo, 0.6 * hi))), ()
        if shape in HELDOUT_SHAPES:  # two bars: along x, along y; their half width; their half height
            return (u(1.2 * lo, 1.4 * hi), u(0.8 * lo, hi), _r(rng.uniform(0.35, 0.5) * lo), u(0.7 * lo, 0.8 * hi)), ()
        # hull: 14 points on an ellipsoid with semi-axes in the size range, centred on their bounding box
        axes = np.array([u(), u(), u()])
        directions = rng.normal(size=(14, 3))
        points = axes * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        points -= (points.max(axis=0) + points.min(axis=0)) / 2
        points = np.round(points, 6)
        half = (points.max(axis=0) - points.min(axis=0)) / 2
        return tuple(_r(v) for v in half), tuple(tuple(float(c) for c in p) for p in points)


def _r(value: float) -> float:
    """Values as they are stored and replayed: rounded to 6 decimals."""
    return round(float(value), 6)


def check_object_set(object_set: str, count: int, shapes: tuple[str, ...] = VARIED_SHAPES) -> None:
    """Raise ValueError for an object set and count that cannot work."""
    if object_set not in OBJECT_SETS:
        raise ValueError(f"unknown object set {object_set!r}; choose one of: {', '.join(OBJECT_SETS)}")
    if not 1 <= count <= MAX_OBJECTS:
        raise ValueError(f"the number of objects must be 1 to {MAX_OBJECTS}, got {count}")
    if object_set == "paper" and count != 4:
        raise ValueError(f"--objects paper is the paper's four objects; it cannot have {count} (use --objects varied)")
