"""Start states: where the objects stand when an episode begins.

``fixed`` is the paper's scene: every episode starts from the task's object poses. ``varied`` draws a layout (each
object's x, y and yaw, within the regions its task declares, no two footprints closer than the task's gap) and the
world settles it by physics before the first frame (`World.reset`). A layout is drawn for an attempt index from the
run seed alone (`StartSampler.draw`), so it depends on neither the worker nor the order rollouts finish in, and the
explorers that draw for the same index draw the same layout; NovEB's children inherit their parent's layout unless
a start mutation draws a new one (`babblegen.explorers.noveb`). Importable without the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from babblegen.objects import ObjectSampler, slot_task
from babblegen.scene import TaskSpec
from babblegen.shapes import ObjectSpec
from babblegen.world.settings import START_MODES, WorldSettings

__all__ = [
    "NEW_START",
    "START_MODES",
    "Start",
    "StartDraw",
    "StartSampler",
    "run_starts",
]

_STREAM = 0x5747A  # the start draws' own random stream, apart from the explorer's and the rollouts'
_MAX_TRIES = 10_000
_MAX_LAYOUTS = 20
_MAX_OBJECT_SETS = 3  # object sets drawn for one start before the regions are judged too small


@dataclass
class Start:
    """A start: ``layout`` is (n_objects, 3) x, y (metres) and yaw (radians); ``drawn_at`` the attempt index it was
    drawn for; ``origin`` how: "drawn" whole (`StartSampler.draw` rebuilds it from the index and the run seed),
    "moved", one object of a parent's start moved (`StartSampler.move_one`), or "made", the scene an earlier
    attempt's movement left (`StartSampler.made`): then ``poses`` holds every object's whole pose (n_objects, 7:
    x, y, z, qw, qx, qy, qz; a toppled can stays toppled) and ``made_from`` that attempt's index. ``objects``: the
    objects a varied or held-out object set drew for the start (`babblegen.objects`), one per slot; None: the task's."""

    layout: np.ndarray
    drawn_at: int
    origin: str = "drawn"
    poses: np.ndarray | None = None
    made_from: int | None = None
    objects: tuple[ObjectSpec, ...] | None = None

    def key(self) -> bytes:
        """What identifies the start in a genome's identity: the exact layout, or the exact poses of a made one,
        and its objects when they were drawn."""
        if self.poses is not None:
            key = b"made" + np.ascontiguousarray(self.poses, dtype=np.float64).tobytes()
        else:
            key = np.ascontiguousarray(self.layout, dtype=np.float64).tobytes()
        if self.objects is not None:
            key += b"objects" + repr([o.factors() for o in self.objects]).encode()
        return key

    @property
    def placement(self) -> np.ndarray:
        """What the world places: the poses of a made start, else the layout (`World.reset`)."""
        return self.layout if self.poses is None else self.poses

    def to_dict(self) -> dict:
        out = {"layout": np.asarray(self.layout).tolist(), "drawn_at": int(self.drawn_at), "origin": self.origin}
        if self.poses is not None:
            out.update(poses=np.asarray(self.poses).tolist(), made_from=int(self.made_from))
        if self.objects is not None:
            out["objects"] = [o.factors() for o in self.objects]
        return out

    @classmethod
    def from_dict(cls, data: dict | None) -> Start | None:
        if data is None:
            return None
        layout = np.asarray(data["layout"], dtype=np.float64).reshape(-1, 3)
        poses = data.get("poses")
        poses = None if poses is None else np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        objects = data.get("objects")
        objects = None if objects is None else tuple(ObjectSpec.from_factors(o) for o in objects)
        return cls(layout, int(data["drawn_at"]), data.get("origin", "drawn"), poses, data.get("made_from"), objects)


@dataclass(frozen=True)
class StartDraw:
    """A proposal's start still to be drawn, for the attempt index it becomes: a whole new layout; given a
    ``parent`` start, that layout with one object moved; given ``made_from``, the scene that attempt left."""

    parent: Start | None = None
    made_from: int | None = None

    def resolve(self, sampler: StartSampler, attempt: int) -> Start:
        if self.made_from is not None:
            return sampler.made(self.made_from, attempt)
        return sampler.draw(attempt) if self.parent is None else sampler.move_one(self.parent, attempt)


NEW_START = StartDraw()


def _yaw(q: np.ndarray) -> np.ndarray:
    """Rotation about the vertical of (..., 4) quaternions (w, x, y, z), radians."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class StartSampler:
    """Draws a task's varied starts for a run seed: ``draw(attempt)`` is a function of (seed, attempt) alone. With an
    ``objects`` sampler every drawn start also draws its objects (`babblegen.objects`), and places them by their own
    footprints; a moved or made start keeps its parent's objects."""

    def __init__(self, task: TaskSpec, seed: int, objects: ObjectSampler | None = None):
        if task.starts is None:
            raise ValueError(f"task {task.name!r} declares no start distribution (TaskSpec.starts)")
        self.task, self.seed, self.objects = task, int(seed), objects
        # draws per object before a layout starts again: drawn objects may not fit at all (told in about a second)
        self._tries = _MAX_TRIES if objects is None else _MAX_TRIES // 10
        self.ends: dict[int, np.ndarray] = {}  # attempt -> the objects' poses its movement left (`record_end`)
        self.end_objects: dict[int, tuple[ObjectSpec, ...] | None] = {}  # attempt -> the objects it ran with
        self.radius = np.array([o.footprint_radius for o in task.objects])
        t = task.table
        self._table = (t.center[0] - t.half_extents[0], t.center[0] + t.half_extents[0],
                       t.center[1] - t.half_extents[1], t.center[1] + t.half_extents[1])  # fmt: skip

    def draw(self, attempt: int) -> Start:
        rng = np.random.default_rng([self.seed, _STREAM, int(attempt)])
        if self.objects is None:
            return Start(self.layout(rng), int(attempt))
        again = 0
        while True:  # a set the regions cannot hold: another set for the same attempt, a few times
            objects = self.objects.draw(attempt, again)
            try:
                return Start(self.layout(rng, self._radius(objects)), int(attempt), objects=objects)
            except ValueError:
                again += 1
                if again == _MAX_OBJECT_SETS:
                    raise

    def move_one(self, parent: Start, attempt: int) -> Start:
        """The parent's layout with one object, drawn uniformly, placed anew in its region (the others stay)."""
        rng = np.random.default_rng([self.seed, _STREAM, int(attempt)])
        layout = np.array(parent.layout, dtype=np.float64)
        radius = self._radius(parent.objects)
        i = int(rng.integers(len(layout)))
        others = np.ones(len(layout), dtype=bool)
        others[i] = False
        spot = self._place(i, layout[others], radius[others], rng, radius)
        if spot is None:  # no room for it elsewhere: a whole new layout of the same objects
            spot_layout = self.layout(rng, radius)
            return Start(spot_layout, int(attempt), "moved", objects=parent.objects)
        layout[i] = spot
        return Start(layout, int(attempt), "moved", objects=parent.objects)

    def _radius(self, objects: tuple[ObjectSpec, ...] | None) -> np.ndarray:
        return self.radius if objects is None else np.array([o.footprint_radius for o in objects])

    def record_end(self, attempt: int, poses: np.ndarray, objects: tuple[ObjectSpec, ...] | None = None) -> None:
        """The objects' final poses (n_objects, 7) of an executed attempt, exactly as its sidecar row records them
        (`babblegen.exporters.sidecar.recorded_poses`), and the objects it ran with: a resumed run reads them back
        from there."""
        self.ends[int(attempt)] = np.array(poses, dtype=np.float64)
        self.end_objects[int(attempt)] = objects

    def made(self, made_from: int, attempt: int) -> Start:
        """The scene attempt ``made_from`` left, as the start of ``attempt``; a whole new layout for it when that
        scene cannot start an episode (an object off the table top) or is unknown."""
        poses = self.ends.get(int(made_from))
        if poses is None or not self.on_table(poses):
            return self.draw(attempt)
        layout = np.column_stack([poses[:, :2], _yaw(poses[:, 3:])])
        objects = self.end_objects.get(int(made_from))
        return Start(layout, int(attempt), "made", poses.copy(), int(made_from), objects)

    def on_table(self, poses: np.ndarray) -> bool:
        """Every object above the table top (not fallen), its centre over the table."""
        x0, x1, y0, y1 = self._table
        x, y, z = poses[:, 0], poses[:, 1], poses[:, 2]
        return bool(np.all((x > x0) & (x < x1) & (y > y0) & (y < y1) & (z > self.task.table_top)))

    def layout(self, rng: np.random.Generator, radius: np.ndarray | None = None) -> np.ndarray:
        """Objects (of footprint radii ``radius``: the task's by default) placed in turn, each redrawn until it
        keeps its distances (`StartDistribution`)."""
        radius = self.radius if radius is None else radius
        for _ in range(_MAX_LAYOUTS):  # objects placed early may leave no room for a later one: start again
            placed = np.zeros((len(radius), 3))
            for i in range(len(placed)):
                spot = self._place(i, placed[:i], radius[:i], rng, radius)
                if spot is None:
                    break
                placed[i] = spot
            else:
                return placed
        raise ValueError(
            f"task {self.task.name!r}: no place for {self.task.objects[i].name!r} in its start region "
            f"in {_MAX_LAYOUTS} layouts; widen the region, lower the gap, or use fewer or smaller objects"
        )

    def _place(
        self, i: int, others: np.ndarray, radii: np.ndarray, rng: np.random.Generator, radius: np.ndarray | None = None
    ) -> np.ndarray | None:
        """(x, y, yaw) of object ``i`` in its region, drawn until it keeps its distances from ``others`` (None when no
        draw in ``self._tries`` does)."""
        dist = self.task.starts
        region = dist.regions[i]
        r = float((self.radius if radius is None else radius)[i])
        for _ in range(self._tries):
            x, y, yaw = rng.uniform(*region.x), rng.uniform(*region.y), rng.uniform(*region.yaw)
            if self._fits(r, x, y, others, radii, dist.gap):
                return np.array([x, y, yaw])
        return None

    def _fits(self, r: float, x: float, y: float, others: np.ndarray, radii: np.ndarray, gap: float) -> bool:
        x0, x1, y0, y1 = self._table
        if not (x0 + r + gap <= x <= x1 - r - gap and y0 + r + gap <= y <= y1 - r - gap):
            return False
        if len(others) and np.any(np.hypot(others[:, 0] - x, others[:, 1] - y) < radii + r + gap):
            return False
        for box in self.task.extra_obstacles:  # axis-aligned footprint of a static obstacle
            dx = max(abs(x - box.center[0]) - box.half_extents[0], 0.0)
            dy = max(abs(y - box.center[1]) - box.half_extents[1], 0.0)
            if np.hypot(dx, dy) < r + gap:
                return False
        return True


def run_starts(task: TaskSpec, settings: WorldSettings, seed: int) -> StartSampler | None:
    """A run's start sampler: its task's regions (or its object slots'), drawing objects too when the run does
    (`babblegen.objects`); None with fixed starts."""
    if settings.starts != "varied":
        return None
    settings = settings.for_task(task)
    drawn = settings.objects != "paper"
    objects = ObjectSampler(settings.objects, settings.num_objects, seed, settings.object_ranges) if drawn else None
    return StartSampler(slot_task(task, settings.objects, settings.num_objects), seed, objects)
