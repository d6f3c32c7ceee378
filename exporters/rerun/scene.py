"""The static scene from the task description: table, obstacles, objects at rest, head camera and the arm's
URDF primitives, with the calls that log them (and the overview's background) to a Rerun recording; and the
primitives of the objects a start draws (`object_parts`), drawn per episode."""

from __future__ import annotations

import functools
import json
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from babblegen.shapes import SHAPES, ObjectSpec, hull_triangles
from babblegen.tasks import get_robot
from babblegen.world.cameras import instance_names, look_at_cam2world
from babblegen.world.kinematics import ArmKinematics, Shape, UrdfModel

from ..geometry import box_footprint, robot_footprint, table_top

if TYPE_CHECKING:
    import rerun as rr

ROBOT_COLOR = (215, 215, 215, 255)
TABLE_COLOR = (140, 102, 71, 255)
TOOL_COLOR = (40, 180, 60, 255)
CONTACT_COLOR = (230, 30, 30, 255)
WAYPOINT_COLOR = (255, 140, 0, 255)
OBSTACLE_COLOR = (235, 230, 217, 255)


# The frames are logged outside the pinhole's subtree: under a Pinhole, the viewer (0.41, software rendering)
# draws an image black, in the 2D view and as a black quad that hides the table in the 3D view (checked with
# scripts/viewer_screenshot.sh). The frustum stays in the 3D scene.
HEAD_IMAGE = "head_camera/image"
# each episode's start: a wireframe box per object where it stood at frame 0 (sizes static, poses per episode)
START = "world/start"
START_LINE_RADIUS = 0.002
# series, legends and mask colours of the slots of a run that draws its objects (the stand-ins are all gray); the
# objects themselves are drawn in their own colours, episode by episode
SLOT_COLORS = (
    (31, 119, 180, 255),
    (255, 127, 14, 255),
    (44, 160, 44, 255),
    (214, 39, 40, 255),
    (148, 103, 189, 255),
    (140, 86, 75, 255),
    (227, 119, 194, 255),
    (23, 190, 207, 255),
)


def objects_drawn(info: dict[str, Any]) -> bool:
    """Whether a run (its run.json) drew each start's objects (``--objects varied`` or ``heldout``): its task's
    objects are then stand-ins for the slots, and each episode's own stand in its sidecar row."""
    return ((info.get("config") or {}).get("world") or {}).get("objects", "paper") != "paper"


@dataclass(frozen=True)
class DrawnPart:
    """One primitive of an object as Rerun draws it, in the object's frame: `entity` (under the object's entity,
    the same for a kind of part at a place in `ObjectSpec.parts`), the archetype and its fields."""

    entity: str
    archetype: str  # Boxes3D, Ellipsoids3D, Cylinders3D, Capsules3D or Mesh3D
    fields: dict[str, np.ndarray]  # one instance's values per field (a mesh: its vertices, normals, triangles)
    kind: str
    size: tuple[float, ...]


def _capsule_along_x(offset: np.ndarray, half: float) -> tuple[np.ndarray, np.ndarray]:
    """A Rerun capsule runs from its translation along +z; one lying along x, centred at ``offset``: the
    translation of its end at -x and the rotation taking z to x."""
    return offset - np.array([half, 0.0, 0.0]), np.array([0.0, np.sqrt(0.5), 0.0, np.sqrt(0.5)])


def hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The convex hull of (n, 3) points as a flat-shaded triangle mesh: (3m, 3) vertices, one per corner of each
    of its m triangles (wound outwards), their (3m, 3) face normals and the (m, 3) triangle indices."""
    corners, normal = hull_triangles(points)
    m = len(corners)
    return corners.reshape(-1, 3), np.repeat(normal, 3, axis=0), np.arange(3 * m, dtype=np.uint32).reshape(m, 3)


def object_parts(obj: dict[str, Any]) -> list[DrawnPart]:
    """An object's primitives (`ObjectSpec.parts`) as Rerun draws them in the object's frame, in its own colour
    (``obj``: a sidecar row's factors or a task's object). Entities are named ``part<k>_<kind>``."""
    return list(_object_parts(json.dumps(obj, sort_keys=True)))


@functools.lru_cache(maxsize=4096)
def _object_parts(key: str) -> tuple[DrawnPart, ...]:
    spec = ObjectSpec.from_record(json.loads(key))
    color = np.array(rgba8(spec.color), dtype=np.uint8)
    out = []
    for k, part in enumerate(spec.parts()):
        offset, s = np.asarray(part.offset, dtype=np.float64), np.asarray(part.size, dtype=np.float64)
        if part.kind == "box":
            arch, fields = "Boxes3D", {"half_sizes": s[:3], "centers": offset}
        elif part.kind == "sphere":
            arch, fields = "Ellipsoids3D", {"half_sizes": np.full(3, s[0]), "centers": offset}
        elif part.kind == "cylinder":  # upright: Rerun's cylinders stand along z too
            arch, fields = "Cylinders3D", {"lengths": 2 * s[1], "radii": s[0], "centers": offset}
        elif part.kind == "capsule":
            translation, quaternion = _capsule_along_x(offset, s[1])
            arch = "Capsules3D"
            fields = {"lengths": 2 * s[1], "radii": s[0], "translations": translation, "quaternions": quaternion}
        elif part.kind == "hull":
            vertices, normals, triangles = hull_mesh(np.asarray(part.vertices) + offset)
            arch = "Mesh3D"
            fields = {"vertex_positions": vertices, "vertex_normals": normals, "triangle_indices": triangles}
        else:
            raise ValueError(f"unknown part kind {part.kind!r}")
        fields["colors" if arch != "Mesh3D" else "albedo_factor"] = color
        out.append(DrawnPart(f"part{k}_{part.kind}", arch, fields, part.kind, tuple(float(v) for v in s)))
    return tuple(out)


def part_entities() -> dict[str, str]:
    """Every part entity an object of any shape may have (`object_parts`), with its archetype."""
    examples = {"hull": {"vertices": [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01], [-0.01, -0.01, -0.01]]}}
    size = {"box": 3, "cylinder": 2, "sphere": 1, "capsule": 2, "dumbbell": 3, "ell": 4, "tee": 4, "hull": 3}
    out: dict[str, str] = {}
    for shape in SHAPES:
        obj = {"name": "x", "shape": shape, "size": [0.02] * size[shape], "color": [1, 1, 1, 1]}
        for part in object_parts({**obj, **examples.get(shape, {})}):
            out[part.entity] = part.archetype
    return out


def bounding_half_sizes(obj: dict[str, Any]) -> np.ndarray:
    """Half extents (3,) of an object's axis-aligned bounding box in its own frame, centred on its origin."""
    return ObjectSpec.from_record(obj).half_extents


def robot_of(task: dict[str, Any]):
    """The registered robot a task description names (the PR2-like arm for datasets that name none)."""
    return get_robot(task.get("robot_uid", "pr2_like_arm"))


def rgba8(color: Iterable[float]) -> tuple[int, int, int, int]:
    """A colour in [0, 1] (RGB or RGBA) as 8-bit RGBA."""
    c = [float(v) for v in color]
    c = (c + [1.0])[:4] if len(c) == 3 else c[:4]
    return tuple(int(round(255 * min(max(v, 0.0), 1.0))) for v in c)  # type: ignore[return-value]


def quat_xyzw(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to unit quaternions (..., 4) in x, y, z, w order (Rerun's)."""
    from scipy.spatial.transform import Rotation

    r = np.asarray(rot, dtype=np.float64)
    return Rotation.from_matrix(r.reshape(-1, 3, 3)).as_quat().reshape(*r.shape[:-2], 4)


class Scene:
    """What the recordings draw: table, objects, head camera (from the task as a dict) and the arm's links."""

    def __init__(self, task: dict[str, Any], joint_names: list[str] | None = None, drawn: bool = False) -> None:
        self.task = task
        self.objects: list[dict[str, Any]] = list(task["objects"])
        self.object_names = [o["name"] for o in self.objects]
        # drawn: each start brings its own objects (`objects_drawn`); the task's are stand-ins for the slots, drawn
        # nowhere, and each slot gets a colour of its own for plots and masks
        self.drawn = drawn
        if drawn:
            self.colors = {n: SLOT_COLORS[i % len(SLOT_COLORS)] for i, n in enumerate(self.object_names)}
        else:
            self.colors = {o["name"]: rgba8(o["color"]) for o in self.objects}
        self.robot = robot_of(task)
        self.urdf = UrdfModel.load(self.robot.urdf)
        self.kin = ArmKinematics(self.urdf, self.robot.base_link, self.robot.tool_link)
        names = list(joint_names or self.kin.joint_names)
        self.joint_names = names
        self._order = [names.index(n) for n in self.kin.joint_names]
        # the moving links' primitives by kind: link index on the chain, pose in the link, size
        self.arm_shapes: dict[str, tuple[np.ndarray, np.ndarray, list[np.ndarray]]] = {}
        for kind in ("box", "sphere", "cylinder"):
            found = [
                (li, s)
                for li, link in enumerate(self.kin.link_names[1:], start=1)
                for s in self.urdf.links.get(link, [])
                if s.kind == kind
            ]
            if found:
                self.arm_shapes[kind] = (
                    np.array([li for li, _ in found]),
                    np.stack([s.origin for _, s in found]),
                    [s.size for _, s in found],
                )

    @property
    def table_top(self) -> float:
        return table_top(self.task)

    def table_outline(self) -> np.ndarray:
        """Corners of the table top (closed loop), world frame."""
        (cx, cy, _), (hx, hy, _) = self.task["table"]["center"], self.task["table"]["half_extents"]
        z = self.table_top
        return np.array([[cx - hx, cy - hy, z], [cx + hx, cy - hy, z], [cx + hx, cy + hy, z], [cx - hx, cy + hy, z]])

    def robot_footprint(self) -> np.ndarray:
        """Corners of the robot base's largest box seen from above (x, y)."""
        return robot_footprint(self.task)

    @property
    def obstacles(self) -> list[dict[str, Any]]:
        """Static boxes besides the table (walls, shelves): name, center, half_extents, rotation."""
        return list(self.task.get("extra_obstacles") or [])

    footprint = staticmethod(box_footprint)

    def rest_position(self, obj: dict[str, Any]) -> np.ndarray:
        return np.array([obj["xy"][0], obj["xy"][1], self.table_top + ObjectSpec.from_record(obj).half_height])

    def half_sizes(self, objects: list[dict[str, Any]] | None = None) -> np.ndarray:
        """(n_objects, 3) half extents of each object's bounding box, in its own frame (the task's objects, or
        an episode's)."""
        return np.array([bounding_half_sizes(o) for o in (objects or self.objects)], dtype=np.float64).reshape(-1, 3)

    def episode_colors(self, objects: list[dict[str, Any]] | None) -> list[tuple[int, int, int, int]]:
        """Each slot's colour in an episode: its drawn object's (an episode's ``objects``), else the task's."""
        if self.drawn and objects:
            return [rgba8(o["color"]) for o in objects]
        return [self.colors[n] for n in self.object_names]

    def link_transforms(self, state: np.ndarray) -> np.ndarray:
        """World poses (T, n_links, 4, 4) of the arm's links for joint states (T, dof) in dataset order."""
        q = np.asarray(state, dtype=np.float64)[:, self._order]
        return self.kin.link_transforms(q)


def _shape_archetype(
    kind: str, sizes: list[np.ndarray], color: tuple[int, ...], poses: np.ndarray | None = None
) -> rr.Boxes3D | rr.Ellipsoids3D | rr.Cylinders3D:
    """URDF primitives of one kind (box sizes are full extents, cylinders are (radius, length) along z) as a
    Rerun archetype; without `poses` only sizes and colour are set, for shapes posed per frame."""
    import rerun as rr

    pose = {} if poses is None else {"centers": poses[:, :3, 3], "quaternions": quat_xyzw(poses[:, :3, :3])}
    if kind == "box":
        return rr.Boxes3D.from_fields(
            half_sizes=[np.asarray(s) / 2 for s in sizes], colors=color, fill_mode="solid", **pose
        )
    if kind == "sphere":
        return rr.Ellipsoids3D.from_fields(
            half_sizes=[[s[0]] * 3 for s in sizes], colors=color, fill_mode="solid", **pose
        )
    return rr.Cylinders3D.from_fields(
        lengths=[s[1] for s in sizes], radii=[s[0] for s in sizes], colors=color, fill_mode="solid", **pose
    )


def part_archetype(part: DrawnPart) -> Any:
    """One part as a Rerun archetype of one instance (solid, in the part's colour)."""
    import rerun as rr

    fields = {k: np.asarray(v)[None] if k not in ("albedo_factor",) else v for k, v in part.fields.items()}
    if part.archetype == "Mesh3D":
        return rr.Mesh3D(
            vertex_positions=part.fields["vertex_positions"],
            vertex_normals=part.fields["vertex_normals"],
            triangle_indices=part.fields["triangle_indices"],
            albedo_factor=part.fields["albedo_factor"],
        )
    return getattr(rr, part.archetype).from_fields(fill_mode="solid", **fields)


def log_frustum(rec: rr.RecordingStream, path: str, cam: dict[str, Any], size: tuple[int, int] | None) -> None:
    """A camera standing at ``cam["eye"]`` looking at ``cam["target"]`` (OpenCV axes, Rerun's RDF), with its
    frustum when its image ``size`` (height, width) is known."""
    import rerun as rr

    pose = look_at_cam2world(cam["eye"], cam["target"])
    rec.log(path, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]), static=True)
    if size is not None:
        h, w = size
        pinhole = rr.Pinhole(fov_y=float(cam["fov"]), aspect_ratio=w / h, width=w, height=h, image_plane_distance=0.25)
        rec.log(path, pinhole, static=True)


def log_cameras(rec: rr.RecordingStream, scene: Scene, cameras: list[dict[str, Any]], size: tuple[int, int]) -> None:
    """The frustums of the fixed cameras other than the head, and the names and colours of the instance ids
    the masks hold (one annotation context for every mask)."""
    import rerun as rr

    for cam in cameras:
        if cam.get("mount") == "fixed":
            size_here = (cam.get("height") or size[0], cam.get("width") or size[1])
            log_frustum(rec, f"world/{cam['name']}_camera", cam, size_here)
    if any(cam.get("segmentation") for cam in cameras):
        colors = {"background": (0, 0, 0, 255), "table": TABLE_COLOR, "floor": (200, 200, 195, 255)}
        colors.update(robot=ROBOT_COLOR, **scene.colors)
        labels = [
            rr.AnnotationInfo(id=i, label=name, color=colors.get(name, OBSTACLE_COLOR))
            for i, name in enumerate(instance_names(scene.object_names, [b["name"] for b in scene.obstacles]))
        ]
        rec.log("/", rr.AnnotationContext(labels), static=True)


def log_scene(
    rec: rr.RecordingStream,
    scene: Scene,
    image_size: tuple[int, int] | None = None,
    cameras: list[dict[str, Any]] | None = None,
) -> None:
    """Static parts: world axes, table, robot link shapes, object shapes and start boxes, cameras, overview
    background."""
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    t = scene.task["table"]
    rec.log(
        "world/table",
        rr.Boxes3D(half_sizes=[t["half_extents"]], centers=[t["center"]], colors=TABLE_COLOR, fill_mode="solid"),
        static=True,
    )
    base: dict[str, list[Shape]] = {}
    for shape in scene.urdf.links.get(scene.robot.base_link, []):
        base.setdefault(shape.kind, []).append(shape)
    for kind, shapes in base.items():
        arch = _shape_archetype(kind, [x.size for x in shapes], ROBOT_COLOR, np.stack([x.origin for x in shapes]))
        rec.log(f"world/robot/base/{kind}", arch, static=True)
    for kind, (_, _, sizes) in scene.arm_shapes.items():
        rec.log(f"world/robot/arm/{kind}", _shape_archetype(kind, sizes, ROBOT_COLOR), static=True)
    for box in scene.obstacles:
        arch = rr.Boxes3D(
            half_sizes=[box["half_extents"]],
            centers=[box["center"]],
            quaternions=[quat_xyzw(np.asarray(box.get("rotation", np.eye(3)), dtype=float))],
            colors=OBSTACLE_COLOR,
            fill_mode="solid",
        )
        rec.log(f"world/obstacles/{box['name']}", arch, static=True)
    for obj in scene.objects:
        if scene.drawn:  # each episode's own parts, at its first frame (EpisodeColumns); the fill mode stays
            for entity, archetype in part_entities().items():
                if archetype != "Mesh3D":
                    fill = getattr(rr, archetype).from_fields(fill_mode="solid")
                    rec.log(f"world/objects/{obj['name']}/{entity}", fill, static=True)
            continue
        parts = object_parts(obj)
        for part in parts:
            # the paper's objects are one primitive each, drawn at .../shape as always
            entity = "shape" if len(parts) == 1 else part.entity
            rec.log(f"world/objects/{obj['name']}/{entity}", part_archetype(part), static=True)  # posed per frame
    start = rr.Boxes3D(
        half_sizes=scene.half_sizes(),
        colors=[scene.colors[n] for n in scene.object_names],
        labels=scene.object_names,
        radii=START_LINE_RADIUS,
        fill_mode="majorwireframe",
    )
    rec.log(START, start, static=True)  # placed at each episode's first frame, see EpisodeColumns
    log_frustum(rec, "world/head_camera", scene.task["camera"], image_size)
    if cameras and image_size is not None:
        log_cameras(rec, scene, cameras, image_size)
    log_overview_background(rec, scene)
    object_lines = rr.SeriesLines(colors=[scene.colors[n] for n in scene.object_names], names=scene.object_names)
    rec.log("contacts", object_lines, static=True)
    rec.log("attempts/contacts/per_object", object_lines, static=True)
    rec.log("attempts/contacts/total", rr.SeriesLines(colors=(20, 20, 20), names="any object"), static=True)
    rec.log("state", rr.SeriesLines(names=scene.joint_names), static=True)
    rec.log("attempts/novelty", rr.SeriesPoints(colors=(120, 60, 200), names="novelty", marker_sizes=2), static=True)
    rec.log("attempts/archived", rr.SeriesPoints(colors=(230, 120, 0), names="archived", marker_sizes=2), static=True)
    rec.log("attempts/feasible", rr.SeriesPoints(colors=(0, 150, 90), names="feasible", marker_sizes=2), static=True)


def log_overview_background(rec: rr.RecordingStream, scene: Scene) -> None:
    """The table outline, the robot's footprint and the objects' rest positions, for the overview view."""
    import rerun as rr

    z = scene.table_top
    table = scene.table_outline()
    robot = np.column_stack([scene.robot_footprint(), np.full(4, z)])
    strips, colors, labels = (
        [np.vstack([table, table[:1]]), np.vstack([robot, robot[:1]])],
        [TABLE_COLOR, (90, 90, 90, 255)],
        ["table", "robot"],
    )
    for box in scene.obstacles:
        foot = scene.footprint(box)
        strips.append(np.column_stack([np.vstack([foot, foot[:1]]), np.full(len(foot) + 1, z)]))
        colors.append((120, 120, 120, 255))
        labels.append(box["name"])
    rec.log("overview/outlines", rr.LineStrips3D(strips, colors=colors, labels=labels, radii=0.004), static=True)
    if scene.drawn:  # the slots' stand-ins rest nowhere
        return
    rec.log(
        "overview/rest_positions",
        rr.Points3D(
            [scene.rest_position(o) for o in scene.objects],
            colors=[scene.colors[n] for n in scene.object_names],
            labels=scene.object_names,
            radii=0.02,
        ),
        static=True,
    )
