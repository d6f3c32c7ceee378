"""Rerun recordings of babbling runs: the 3D scene per episode, the head camera, contacts, and the paper's
overview of final tool and object positions (Figs. 2-3), built from numpy arrays so that the run loop (live
rollouts) and `babblegen view` (a finished LeRobot dataset) log the same entities.

Timelines follow LeRobot's column names: `frame_index` and `timestamp` (seconds) count within an episode,
`index` counts frames over the whole dataset, `episode_index` is the episode, and `attempt` numbers every
attempted movement, infeasible ones included (per-attempt scalars live there: novelty, archived, feasible,
accumulated contacts).

Entities:
    world/table, world/obstacles/<name>                                     the static scene
    world/robot/base/*, world/robot/arm/{box,sphere,cylinder}              the arm (posed per frame by FK)
    world/objects/<name> (pose per frame), world/objects/<name>/shape       objects in their own colours
    world/head_camera (pose and pinhole frustum), head_camera/image        head-camera frames (JPEG)
    world/tool (red while touching), world/tool_path, world/tool_waypoints  the tool point, its path, its targets
    world/object_paths, world/contact_events                                object paths, where contacts happened
    contacts, state                                                         per-frame scalars (object, joint)
    attempts/{novelty,archived,feasible}, attempts/contacts/*              per-attempt scalars
    overview/final_tool, overview/final_objects/<name>, overview/outlines  final positions seen from above

`RerunSink` writes the run's recordings to DIR/babblegen/rerun/ as one .rrd per commit segment; all segments
share one recording id, so `rerun DIR/babblegen/rerun/*.rrd` opens them as a single recording.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import json
import os
import uuid
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.world.kinematics import ArmKinematics, Shape, UrdfModel

from .sidecar import ATTEMPTS, read_attempts, read_run_info, sidecar_dir

APP_ID = "babblegen"
RERUN_DIR = "rerun"
INDEX = "index.json"
SEGMENT = "segment-{:05d}.rrd"
JPEG_QUALITY = 85
MAX_BUFFERED_FRAMES = 3000  # episodes are sent to Rerun in batches of about this many frames
BASE_LINK, TOOL_LINK = "base_link", "r_gripper_link"

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


def urdf_path(robot_uid: str = "pr2_like_arm") -> Path:
    """The robot's URDF shipped in babblegen.tasks, found without importing the task modules (ManiSkill)."""
    spec = importlib.util.find_spec("babblegen.tasks")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("babblegen.tasks is not installed")
    return Path(next(iter(spec.submodule_search_locations))) / "assets" / f"{robot_uid}.urdf"


def rgba8(color: Iterable[float]) -> tuple[int, int, int, int]:
    """A colour in [0, 1] (RGB or RGBA) as 8-bit RGBA."""
    c = [float(v) for v in color]
    c = (c + [1.0])[:4] if len(c) == 3 else c[:4]
    return tuple(int(round(255 * min(max(v, 0.0), 1.0))) for v in c)  # type: ignore[return-value]


def quat_xyzw(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to unit quaternions (..., 4) in x, y, z, w order (Shepperd's method)."""
    r = np.asarray(rot, dtype=np.float64)
    shape = r.shape[:-2]
    r = r.reshape(-1, 3, 3)
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    case = np.argmax(np.stack([m00 + m11 + m22, m00, m11, m22], axis=1), axis=1)
    q = np.empty((len(r), 4))
    for c in range(4):
        k = case == c
        if not k.any():
            continue
        m = r[k]
        if c == 0:
            s = 2 * np.sqrt(1 + m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2])
            q[k] = (
                np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1], s * s / 4], 1)
                / s[:, None]
            )
        else:
            i, j, n = c - 1, c % 3, (c + 1) % 3
            s = 2 * np.sqrt(1 + m[:, i, i] - m[:, j, j] - m[:, n, n])
            v = np.empty((k.sum(), 4))
            v[:, i] = s * s / 4
            v[:, j] = m[:, j, i] + m[:, i, j]
            v[:, n] = m[:, n, i] + m[:, i, n]
            v[:, 3] = m[:, n, j] - m[:, j, n]
            q[k] = v / s[:, None]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(*shape, 4)


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    return np.concatenate([q[..., 1:4], q[..., :1]], axis=-1)


def encode_jpeg(images: np.ndarray, quality: int = JPEG_QUALITY) -> list[bytes]:
    """(T, H, W, 3) uint8 frames as JPEG bytes."""
    from PIL import Image

    out = []
    for img in images:
        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(img)).save(buf, format="JPEG", quality=quality)
        out.append(buf.getvalue())
    return out


# --- the scene ---------------------------------------------------------------------------------------------
class Scene:
    """What the recordings draw: table, objects, head camera (from the task as a dict) and the arm's links."""

    def __init__(self, task: dict[str, Any], joint_names: list[str] | None = None):
        self.task = task
        self.objects: list[dict[str, Any]] = list(task["objects"])
        self.object_names = [o["name"] for o in self.objects]
        self.colors = {o["name"]: rgba8(o["color"]) for o in self.objects}
        self.urdf = UrdfModel.load(urdf_path(task.get("robot_uid", "pr2_like_arm")))
        self.kin = ArmKinematics(self.urdf, BASE_LINK, TOOL_LINK)
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
        t = self.task["table"]
        return float(t["center"][2] + t["half_extents"][2])

    def table_outline(self) -> np.ndarray:
        """Corners of the table top (closed loop), world frame."""
        (cx, cy, _), (hx, hy, _) = self.task["table"]["center"], self.task["table"]["half_extents"]
        z = self.table_top
        return np.array([[cx - hx, cy - hy, z], [cx + hx, cy - hy, z], [cx + hx, cy + hy, z], [cx - hx, cy + hy, z]])

    def robot_footprint(self) -> np.ndarray:
        """Corners of the robot base's largest box seen from above (x, y)."""
        boxes = [s for s in self.urdf.links.get(BASE_LINK, []) if s.kind == "box"]
        if not boxes:
            return np.array([[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]])
        b = max(boxes, key=lambda s: s.size[0] * s.size[1])
        (cx, cy), (hx, hy) = b.origin[:2, 3], b.size[:2] / 2
        return np.array([[cx - hx, cy - hy], [cx + hx, cy - hy], [cx + hx, cy + hy], [cx - hx, cy + hy]])

    @property
    def obstacles(self) -> list[dict[str, Any]]:
        """Static boxes besides the table (walls, shelves): name, center, half_extents, rotation."""
        return list(self.task.get("extra_obstacles") or [])

    @staticmethod
    def footprint(box: dict[str, Any]) -> np.ndarray:
        """A box's outline seen from above: the convex hull (counter-clockwise) of its corners' x, y."""
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
        rot = np.asarray(box.get("rotation", np.eye(3)), dtype=float)
        pts = sorted(
            {tuple(np.round(p, 9)) for p in (np.asarray(box["center"]) + (signs * box["half_extents"]) @ rot.T)[:, :2]}
        )
        if len(pts) < 3:
            return np.asarray(pts)

        def turns_left(o: tuple, a: tuple, b: tuple) -> bool:
            return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]) > 0

        def half(points: list[tuple]) -> list[tuple]:
            out: list[tuple] = []
            for p in points:
                while len(out) >= 2 and not turns_left(out[-2], out[-1], p):
                    out.pop()
                out.append(p)
            return out[:-1]

        return np.asarray(half(pts) + half(pts[::-1]))

    def rest_position(self, obj: dict[str, Any]) -> np.ndarray:
        half = {"box": lambda s: s[2], "cylinder": lambda s: s[1], "sphere": lambda s: s[0]}[obj["shape"]](obj["size"])
        return np.array([obj["xy"][0], obj["xy"][1], self.table_top + half])

    def link_transforms(self, state: np.ndarray) -> np.ndarray:
        """World poses (T, n_links, 4, 4) of the arm's links for joint states (T, dof) in dataset order."""
        q = np.asarray(state, dtype=np.float64)[:, self._order]
        return self.kin.link_transforms(q)

    def camera_rotation(self) -> np.ndarray:
        """Columns: the head camera's right, down and forward axes in the world frame (Rerun's RDF)."""
        cam = self.task["camera"]
        fwd = np.asarray(cam["target"], float) - np.asarray(cam["eye"], float)
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        return np.stack([right, np.cross(fwd, right), fwd], axis=1)


def _shape_archetype(kind: str, sizes: list[np.ndarray], color: tuple[int, ...], poses: np.ndarray | None = None):
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


def log_scene(rec, scene: Scene, image_size: tuple[int, int] | None = None) -> None:
    """Static parts: world axes, table, robot link shapes, object shapes, head camera, overview background."""
    import rerun as rr

    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    t = scene.task["table"]
    rec.log(
        "world/table",
        rr.Boxes3D(half_sizes=[t["half_extents"]], centers=[t["center"]], colors=TABLE_COLOR, fill_mode="solid"),
        static=True,
    )
    base: dict[str, list[Shape]] = {}
    for shape in scene.urdf.links.get(BASE_LINK, []):
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
        name, size, color = obj["name"], obj["size"], scene.colors[obj["name"]]
        if obj["shape"] == "box":
            arch = rr.Boxes3D(half_sizes=[size], colors=color, fill_mode="solid")
        elif obj["shape"] == "cylinder":
            arch = rr.Cylinders3D(lengths=[2 * size[1]], radii=[size[0]], colors=color, fill_mode="solid")
        else:
            arch = rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=color, fill_mode="solid")
        rec.log(f"world/objects/{name}/shape", arch, static=True)  # posed per frame, see EpisodeColumns
    cam = scene.task["camera"]
    rec.log("world/head_camera", rr.Transform3D(translation=cam["eye"], mat3x3=scene.camera_rotation()), static=True)
    if image_size is not None:
        h, w = image_size
        rec.log(
            "world/head_camera",
            rr.Pinhole(fov_y=float(cam["fov"]), aspect_ratio=w / h, width=w, height=h, image_plane_distance=0.25),
            static=True,
        )
    log_overview_background(rec, scene)
    object_lines = rr.SeriesLines(colors=[scene.colors[n] for n in scene.object_names], names=scene.object_names)
    rec.log("contacts", object_lines, static=True)
    rec.log("attempts/contacts/per_object", object_lines, static=True)
    rec.log("attempts/contacts/total", rr.SeriesLines(colors=(20, 20, 20), names="any object"), static=True)
    rec.log("state", rr.SeriesLines(names=scene.joint_names), static=True)
    rec.log("attempts/novelty", rr.SeriesPoints(colors=(120, 60, 200), names="novelty", marker_sizes=2), static=True)
    rec.log("attempts/archived", rr.SeriesPoints(colors=(230, 120, 0), names="archived", marker_sizes=2), static=True)
    rec.log("attempts/feasible", rr.SeriesPoints(colors=(0, 150, 90), names="feasible", marker_sizes=2), static=True)


def log_overview_background(rec, scene: Scene) -> None:
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


# --- episodes ------------------------------------------------------------------------------------------------
@dataclass
class EpisodeData:
    """One executed trajectory, frame 0 = before the movement, last frame = after it."""

    episode_index: int
    state: np.ndarray  # (T, dof)
    ee_pos: np.ndarray  # (T, 3)
    object_poses: np.ndarray  # (T, n_objects, 7) x, y, z, qw, qx, qy, qz
    contacts: np.ndarray  # (T, n_objects)
    fps: float
    images: np.ndarray | list[bytes] | None = None  # (T, H, W, 3) uint8, or JPEG bytes per frame
    start_index: int = 0  # dataset-wide index of frame 0
    timestamps: np.ndarray | None = None  # (T,) seconds; frame_index / fps when None
    attempt: int | None = None
    ee_targets: np.ndarray | None = None  # (k, 3) commanded tool waypoints

    def __len__(self) -> int:
        return len(self.state)


@dataclass
class _Prepared:
    """An episode turned into the columns Rerun receives."""

    times: dict[str, np.ndarray]  # timeline -> (T,) per frame
    first: dict[str, np.ndarray]  # timeline -> (1,) first frame
    arm: dict[str, tuple[np.ndarray, np.ndarray]]  # shape kind -> centers (T*S, 3), quaternions (T*S, 4)
    objects: np.ndarray  # (T, n, 7) as translation + xyzw quaternion
    ee_pos: np.ndarray
    touching: np.ndarray  # (T,) bool
    contacts: np.ndarray  # (T, n)
    state: np.ndarray
    jpegs: list[bytes] | None
    targets: np.ndarray  # (k, 3)
    events: tuple[np.ndarray, np.ndarray]  # contact positions (m, 3), object index (m,)

    def __len__(self) -> int:
        return len(self.ee_pos)


class EpisodeColumns:
    """Collects episodes and sends them to Rerun as one chunk per entity: a recording stays compact (each
    chunk carries a few KiB of schema) and logging costs a handful of calls per batch, not per frame.

    Per frame: arm shapes, object poses, the tool point (red while touching), head-camera JPEGs, contact and
    joint scalars. At each episode's first frame: its tool path, waypoints, object paths and contact places.
    """

    def __init__(self, scene: Scene):
        self.scene = scene
        self._eps: list[_Prepared] = []

    @property
    def n_frames(self) -> int:
        return sum(len(e) for e in self._eps)

    def add(self, ep: EpisodeData) -> None:
        n = len(ep)
        frames = np.arange(n)
        ts = np.asarray(ep.timestamps, dtype=np.float64) if ep.timestamps is not None else frames / float(ep.fps)
        times = {
            "frame_index": frames,
            "timestamp": ts,
            "index": ep.start_index + frames,
            "episode_index": np.full(n, ep.episode_index),
        }
        if ep.attempt is not None:
            times["attempt"] = np.full(n, ep.attempt)
        tf = self.scene.link_transforms(ep.state)
        arm = {}
        for kind, (links, origins, _) in self.scene.arm_shapes.items():
            world = tf[:, links] @ origins  # (T, S, 4, 4)
            arm[kind] = (world[..., :3, 3].reshape(-1, 3), quat_xyzw(world[..., :3, :3]).reshape(-1, 4))
        poses = np.asarray(ep.object_poses, dtype=np.float64)
        objects = np.concatenate([poses[..., :3], wxyz_to_xyzw(poses[..., 3:7])], axis=-1)
        contacts = np.asarray(ep.contacts, dtype=np.float64)
        ee = np.asarray(ep.ee_pos, dtype=np.float64)
        jpegs = None
        if ep.images is not None and len(ep.images):
            jpegs = ep.images if isinstance(ep.images, list) else encode_jpeg(np.asarray(ep.images))
        t_idx, o_idx = np.nonzero(contacts > 0)
        self._eps.append(
            _Prepared(
                times=times,
                first={k: v[:1] for k, v in times.items()},
                arm=arm,
                objects=objects,
                ee_pos=ee,
                touching=contacts.any(axis=1),
                contacts=contacts,
                state=np.asarray(ep.state, dtype=np.float64),
                jpegs=jpegs,
                targets=np.zeros((0, 3)) if ep.ee_targets is None else np.asarray(ep.ee_targets, float).reshape(-1, 3),
                events=(ee[t_idx], o_idx),
            )
        )

    def send(self, rec) -> None:
        """Log the collected episodes and clear the buffer."""
        eps, self._eps = self._eps, []
        # episodes with and without an attempt number have different timelines: send them apart
        for group in ([e for e in eps if "attempt" in e.times], [e for e in eps if "attempt" not in e.times]):
            if group:
                self._send(rec, group)

    def _send(self, rec, eps: list[_Prepared]) -> None:
        import rerun as rr

        scene = self.scene
        cat = np.concatenate
        names = list(eps[0].times)
        idx = [_time_column(k, cat([e.times[k] for e in eps])) for k in names]
        first = [_time_column(k, cat([e.first[k] for e in eps])) for k in names]
        n_frames = sum(len(e) for e in eps)

        for kind, (_, _, _) in scene.arm_shapes.items():
            centers = cat([e.arm[kind][0] for e in eps])
            quats = cat([e.arm[kind][1] for e in eps])
            per_frame = len(centers) // n_frames
            if kind == "box":
                cols = rr.Boxes3D.columns(centers=centers, quaternions=quats)
            elif kind == "cylinder":
                cols = rr.Cylinders3D.columns(centers=centers, quaternions=quats)
            else:
                cols = rr.Ellipsoids3D.columns(centers=centers, quaternions=quats)
            rec.send_columns(f"world/robot/arm/{kind}", indexes=idx, columns=cols.partition([per_frame] * n_frames))
        objects = cat([e.objects for e in eps])
        for j, name in enumerate(scene.object_names):
            rec.send_columns(
                f"world/objects/{name}",
                indexes=idx,
                columns=rr.Transform3D.columns(translation=objects[:, j, :3], quaternion=objects[:, j, 3:]),
            )
        touching = cat([e.touching for e in eps])
        rec.send_columns(
            "world/tool",
            indexes=idx,
            columns=rr.Points3D.columns(
                positions=cat([e.ee_pos for e in eps]),
                colors=np.where(touching[:, None], CONTACT_COLOR, TOOL_COLOR).astype(np.uint8),
                radii=np.where(touching, 0.02, 0.012).astype(np.float32),
            ),
        )
        with_images = [i for i, e in enumerate(eps) if e.jpegs is not None]
        if with_images:
            blobs = [b for i in with_images for b in eps[i].jpegs]
            img_idx = [_time_column(k, cat([eps[i].times[k] for i in with_images])) for k in names]
            rec.send_columns(
                HEAD_IMAGE,
                indexes=img_idx,
                columns=rr.EncodedImage.columns(blob=blobs, media_type=["image/jpeg"] * len(blobs)),
            )
        n_obj, dof = len(scene.object_names), len(scene.joint_names)
        rec.send_columns(
            "contacts",
            indexes=idx,
            columns=rr.Scalars.columns(scalars=cat([e.contacts for e in eps]).ravel()).partition([n_obj] * n_frames),
        )
        rec.send_columns(
            "state",
            indexes=idx,
            columns=rr.Scalars.columns(scalars=cat([e.state for e in eps]).ravel()).partition([dof] * n_frames),
        )

        # whole-episode drawings, at each episode's first frame
        rec.send_columns(
            "world/tool_path",
            indexes=first,
            columns=rr.LineStrips3D.columns(strips=[e.ee_pos for e in eps]).partition([1] * len(eps)),
        )
        rec.send_columns(
            "world/tool_waypoints",
            indexes=first,
            columns=rr.Points3D.columns(positions=cat([e.targets for e in eps])).partition(
                [len(e.targets) for e in eps]
            ),
        )
        rec.send_columns(
            "world/object_paths",
            indexes=first,
            columns=rr.LineStrips3D.columns(
                strips=[e.objects[:, j, :3] for e in eps for j in range(n_obj)],
                colors=[scene.colors[n] for _ in eps for n in scene.object_names],
                labels=[n for _ in eps for n in scene.object_names],
            ).partition([n_obj] * len(eps)),
        )
        objs = cat([e.events[1] for e in eps]).astype(int)
        rec.send_columns(
            "world/contact_events",
            indexes=first,
            columns=rr.Points3D.columns(
                positions=cat([e.events[0] for e in eps]).reshape(-1, 3),
                colors=[scene.colors[scene.object_names[o]] for o in objs],
                labels=[scene.object_names[o] for o in objs],
            ).partition([len(e.events[1]) for e in eps]),
        )


def _time_column(name: str, values: np.ndarray):
    import rerun as rr

    if name == "timestamp":
        return rr.TimeColumn(name, duration=np.asarray(values, dtype=np.float64))
    return rr.TimeColumn(name, sequence=np.asarray(values, dtype=np.int64))


def log_episode(rec, scene: Scene, ep: EpisodeData) -> None:
    """Log one episode (see `EpisodeColumns` for what is drawn)."""
    cols = EpisodeColumns(scene)
    cols.add(ep)
    cols.send(rec)


# --- per attempt ---------------------------------------------------------------------------------------------
@dataclass
class Tally:
    """Running counts over attempt rows in order: where the next episode starts and accumulated contacts."""

    object_names: list[str]
    attempts: int = 0
    episodes: int = 0
    frames: int = 0
    contacts: int = 0
    per_object: dict[str, int] = field(default_factory=dict)

    def add(self, row: dict[str, Any]) -> None:
        self.attempts += 1
        if row.get("feasible"):
            self.episodes += 1
            self.frames += int(row.get("n_frames") or 0)
            touched = row.get("touched") or {}
            self.contacts += int(any(touched.values()))
            for name in self.object_names:
                self.per_object[name] = self.per_object.get(name, 0) + int(bool(touched.get(name)))

    @classmethod
    def from_rows(cls, rows: Iterable[dict[str, Any]], object_names: list[str]) -> Tally:
        tally = cls(list(object_names))
        for row in rows:
            tally.add(row)
        return tally


class AttemptColumns:
    """Buffers per-attempt scalars and overview points, sent to Rerun as columns in one go."""

    def __init__(self, scene: Scene, tally: Tally | None = None, static_overview: bool = False):
        self.scene = scene
        self.tally = tally or Tally(scene.object_names)
        self.static_overview = static_overview  # for a finished run: send() is called once with every row
        self._rows: list[dict[str, Any]] = []

    def __len__(self) -> int:
        return len(self._rows)

    def add(self, row: dict[str, Any]) -> None:
        start = self.tally.frames
        self.tally.add(row)
        executed = bool(row.get("feasible")) and row.get("episode_index") is not None
        self._rows.append(
            {
                "attempt": int(row["attempt"]),
                "feasible": float(bool(row.get("feasible"))),
                "archived": float(bool(row.get("archived"))),
                "novelty": np.nan if row.get("novelty") is None else float(row["novelty"]),
                "total": float(self.tally.contacts),
                "per_object": [float(self.tally.per_object.get(n, 0)) for n in self.scene.object_names],
                "episode": int(row["episode_index"]) if executed else -1,
                "last_index": start + max(int(row.get("n_frames") or 1), 1) - 1 if executed else -1,
                "final_ee": row.get("final_ee_pos") if executed else None,
                "final_poses": row.get("final_poses") if executed else None,
            }
        )

    def send(self, rec) -> None:
        """Log the buffered rows and clear the buffer."""
        import rerun as rr

        if not self._rows:
            return
        rows, self._rows = self._rows, []
        for executed in (True, False):
            part = [r for r in rows if (r["episode"] >= 0) == executed]
            if not part:
                continue

            def indexes(sel: list[dict[str, Any]], executed: bool = executed) -> list:
                idx = [rr.TimeColumn("attempt", sequence=[r["attempt"] for r in sel])]
                if executed:
                    idx.append(rr.TimeColumn("episode_index", sequence=[r["episode"] for r in sel]))
                    idx.append(rr.TimeColumn("index", sequence=[r["last_index"] for r in sel]))
                return idx

            idx = indexes(part)
            for key in ("feasible", "archived", "total"):
                path = "attempts/contacts/total" if key == "total" else f"attempts/{key}"
                rec.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=[r[key] for r in part]))
            n_obj = len(self.scene.object_names)
            rec.send_columns(
                "attempts/contacts/per_object",
                indexes=idx,
                columns=rr.Scalars.columns(scalars=np.ravel([r["per_object"] for r in part])).partition(
                    [n_obj] * len(part)
                ),
            )
            novel = [r for r in part if not np.isnan(r["novelty"])]
            if novel:
                rec.send_columns(
                    "attempts/novelty",
                    indexes=indexes(novel),
                    columns=rr.Scalars.columns(scalars=[r["novelty"] for r in novel]),
                )
            if executed:
                self._send_overview(rec, part, indexes)

    def _send_overview(self, rec, part: list[dict[str, Any]], indexes: Callable[[list], list]) -> None:
        """Final tool and object positions: static when the whole run is known (all points on every timeline),
        else one point per attempt, accumulated by the overview view's visible time range."""
        import rerun as rr

        points = {"overview/final_tool": ([r for r in part if r["final_ee"] is not None], None)}
        for name in self.scene.object_names:
            points[f"overview/final_objects/{name}"] = ([r for r in part if name in (r["final_poses"] or {})], name)
        for path, (sel, name) in points.items():
            if not sel:
                continue
            pos = [r["final_ee"] if name is None else r["final_poses"][name][:3] for r in sel]
            color = TOOL_COLOR if name is None else self.scene.colors[name]
            if self.static_overview:
                rec.log(path, rr.Points3D(pos, colors=color, radii=0.008), static=True)
            else:
                n = len(sel)
                cols = rr.Points3D.columns(positions=pos, colors=[color] * n, radii=[0.008] * n)
                rec.send_columns(path, indexes=indexes(sel), columns=cols)


# --- recordings and the default layout ---------------------------------------------------------------------
def new_recording(recording_id: str):
    """A recording stream whose only timelines are the ones babblegen sets."""
    import rerun as rr

    rec = rr.RecordingStream(APP_ID, recording_id=recording_id, send_properties=False)
    rec.set_log_tick_enabled(False)
    rec.set_log_time_enabled(False)
    return rec


def blueprint(timeline: str = "index"):
    """3D scene, head camera and the overview of final positions, with plots that have data on ``timeline``:
    one episode (``frame_index``) gets its contacts and joint state, many also the per-attempt plots."""
    import rerun.blueprint as rrb

    so_far = [
        rrb.VisibleTimeRange(tl, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative())
        for tl in ("attempt", "episode_index", "index")
    ]
    if timeline == "frame_index":  # one episode: every plot has data on the frame timeline
        plots = rrb.Vertical(
            rrb.TimeSeriesView(origin="contacts", name="Contacts per frame"),
            rrb.TimeSeriesView(origin="state", name="Joint state"),
        )
    else:  # per-attempt series live on the attempt, episode and index timelines
        plots = rrb.Vertical(
            rrb.TimeSeriesView(origin="contacts", name="Contacts per frame"),
            rrb.TimeSeriesView(origin="attempts/contacts", name="Accumulated contacts"),
            rrb.Tabs(
                rrb.TimeSeriesView(
                    origin="attempts",
                    contents=["attempts/novelty", "attempts/archived", "attempts/feasible"],
                    name="Per attempt",
                ),
                rrb.TimeSeriesView(origin="state", name="Joint state"),
            ),
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                origin="world",
                name="Scene",
                eye_controls=rrb.EyeControls3D(
                    position=(-0.9, -1.9, 2.1), look_target=(0.75, 0.0, 0.7), eye_up=(0, 0, 1)
                ),
            ),
            rrb.Vertical(
                rrb.Spatial2DView(origin=HEAD_IMAGE.rsplit("/", 1)[0], name="Head camera"),
                rrb.Spatial3DView(
                    origin="overview",
                    name="Final tool and object positions, from above",
                    eye_controls=rrb.EyeControls3D(
                        position=(0.45, 0.0, 3.6), look_target=(0.45, 0.0, 0.7), eye_up=(1, 0, 0)
                    ),
                    time_ranges=so_far,
                ),
            ),
            plots,
            column_shares=[3, 2, 2],
        ),
        rrb.TimePanel(timeline=timeline),
    )


def _guarded(method: Callable) -> Callable:
    """Run a sink method; on any error warn once and disable the sink (an interruption still propagates)."""

    @functools.wraps(method)
    def wrapper(self: RerunSink, *args: Any, **kwargs: Any) -> Any:
        if not self.enabled:
            return None
        try:
            return method(self, *args, **kwargs)
        except Exception as e:
            from babblegen.interrupts import Interrupted

            if isinstance(e, Interrupted):
                raise
            self._disable(e)
            return None

    return wrapper


class RerunSink:
    """Writes a run's Rerun recording to DIR/babblegen/rerun/, one `segment-NNNNN.rrd` per commit segment.

    A segment is opened at the first attempt after a commit point and closed at the next one (`flush`), so a
    crash can only damage the segment in progress. `index.json` lists the closed segments with the number of
    attempts, episodes and frames logged up to their end; `rollback` keeps the segments covered by the last
    commit and deletes the rest. Any error disables the sink with one warning; the run goes on.
    """

    def __init__(self, out_dir: Path, task: Any, joint_names: list[str]):
        # the sink reports its own failures in one warning; the SDK's Rust logger would repeat them (a full disk
        # gives three ERROR lines). RUST_LOG set by the user still wins.
        os.environ.setdefault("RUST_LOG", "off")
        self.out = Path(out_dir)
        self.dir = sidecar_dir(self.out) / RERUN_DIR
        self.task = task if isinstance(task, dict) else task.to_dict()
        self.joint_names = list(joint_names)
        self.enabled = True
        self.scene: Scene | None = None
        self.columns: AttemptColumns | None = None
        self.episodes: EpisodeColumns | None = None
        self._tally = Tally([o["name"] for o in self.task["objects"]])
        self._index: dict[str, Any] | None = None
        self._rec = None
        self._segment: Path | None = None
        self._in_progress = False
        self._fps = 10.0
        self._image_size: tuple[int, int] | None = None

    # --- hooks called by the run loop ---------------------------------------------------------------------
    @_guarded
    def log(self, row: dict[str, Any], rollout: Any) -> None:
        """Log one attempt (and its episode when it was executed)."""
        self._open()
        self._in_progress = True
        frames = getattr(rollout, "frames", None)
        if frames is not None and row.get("episode_index") is not None:
            ep = EpisodeData(
                episode_index=int(row["episode_index"]),
                state=frames.state,
                ee_pos=frames.ee_pos,
                object_poses=frames.object_poses,
                contacts=frames.contacts,
                images=frames.images,
                fps=self._fps,
                start_index=self.columns.tally.frames,
                attempt=int(row["attempt"]),
                ee_targets=rollout.ee_targets,
            )
            self.episodes.add(ep)
        self.columns.add(row)
        if self.episodes.n_frames >= MAX_BUFFERED_FRAMES:
            self.episodes.send(self._rec)
        self._in_progress = False

    @_guarded
    def flush(self) -> None:
        """Commit point: close the segment in progress and record it in the index."""
        self._close_segment()

    @_guarded
    def rollback(self, executed_episodes: int) -> None:
        """Resume: keep the segments covered by the last commit, delete the others."""
        rows = read_attempts(self.out) if (sidecar_dir(self.out) / ATTEMPTS).exists() else []
        index = self._load_index()
        kept = []
        for seg in index["segments"]:
            if seg["attempts_end"] > len(rows) or seg["episodes_end"] > executed_episodes:
                break
            kept.append(seg)
        keep_files = {seg["file"] for seg in kept}
        if self.dir.exists():
            for p in self.dir.iterdir():
                if p.name != INDEX and p.name not in keep_files and (p.suffix in (".rrd", ".tmp")):
                    p.unlink()
        index["segments"] = kept
        self._write_index()
        self._tally = Tally.from_rows(rows, self._tally.object_names)
        if self.columns is not None:
            self.columns = AttemptColumns(self.scene, self._tally)

    def close(self) -> None:
        """End of the run (or of an interrupted one): close and index the segment in progress."""
        if self.enabled:
            self.flush()

    # --- internals ----------------------------------------------------------------------------------------
    def _disable(self, error: BaseException) -> None:
        self.enabled = False
        warnings.warn(
            f"Rerun recording stopped after an error ({type(error).__name__}: {error}); the run goes on without it",
            RuntimeWarning,
            stacklevel=3,
        )
        if self._rec is not None:
            with contextlib.suppress(Exception):  # already reporting an error
                self._rec.disconnect()
            self._rec = None

    def _load_index(self) -> dict[str, Any]:
        if self._index is None:
            path = self.dir / INDEX
            if path.exists():
                self._index = json.loads(path.read_text())
            else:
                self._index = {"recording_id": str(uuid.uuid4()), "segments": []}
        return self._index

    def _write_index(self) -> None:
        from .lerobot import atomic_write

        self.dir.mkdir(parents=True, exist_ok=True)
        atomic_write(self.dir / INDEX, json.dumps(self._load_index(), indent=1).encode())

    def _open(self) -> None:
        if self._rec is not None:
            return
        if self.scene is None:
            self.scene = Scene(self.task, self.joint_names)
            info = read_run_info(self.out)
            world = info.get("config", {}).get("world", {})
            self._fps = float(world.get("fps", self._fps))
            if "camera_height" in world:
                self._image_size = (int(world["camera_height"]), int(world["camera_width"]))
            self.columns = AttemptColumns(self.scene, self._tally)
            self.episodes = EpisodeColumns(self.scene)
        index = self._load_index()
        self.dir.mkdir(parents=True, exist_ok=True)
        numbers = [int(p.stem.split("-")[1]) for p in self.dir.glob("segment-*.rrd")]
        numbers += [int(Path(s["file"]).stem.split("-")[1]) for s in index["segments"]]
        self._segment = self.dir / SEGMENT.format(max(numbers, default=-1) + 1)
        rec = new_recording(index["recording_id"])
        rec.save(self._segment, default_blueprint=blueprint())
        self._rec = rec
        log_scene(rec, self.scene, self._image_size)

    def _close_segment(self) -> None:
        if self._rec is None:
            return
        rec, self._rec = self._rec, None
        self.episodes.send(rec)
        self.columns.send(rec)
        rec.flush()
        rec.disconnect()
        tally = self.columns.tally
        self._load_index()["segments"].append(
            {
                "file": self._segment.name,
                "attempts_end": tally.attempts + int(self._in_progress),
                "episodes_end": tally.episodes + int(self._in_progress),
                "frames_end": tally.frames,
            }
        )
        self._write_index()
        self._in_progress = False


def recording_files(root: str | Path) -> list[Path]:
    """The run's committed recording segments, in order."""
    d = sidecar_dir(root) / RERUN_DIR
    path = d / INDEX
    if not path.exists():
        return []
    return [d / s["file"] for s in json.loads(path.read_text())["segments"] if (d / s["file"]).exists()]


class ViewerError(RuntimeError):
    """The spawned Rerun viewer went away (no display, closed window) before the data reached it."""


# --- a recording from a finished dataset (`babblegen view`) -------------------------------------------------
def _column(table, name: str) -> np.ndarray:
    import pyarrow as pa

    arr = table.column(name).combine_chunks()
    if pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type) or pa.types.is_large_list(arr.type):
        return arr.flatten().to_numpy(zero_copy_only=False).reshape(len(arr), -1)
    return arr.to_numpy(zero_copy_only=False)


def _decode_head(ds, episode: int, timestamps: np.ndarray) -> np.ndarray | None:
    """An episode's head-camera frames as (T, H, W, 3) uint8, or None when they cannot be decoded."""
    from lerobot.datasets.video_utils import decode_video_frames

    from .lerobot import HEAD

    if HEAD not in ds.meta.video_keys:
        return None
    ep = ds.meta.episodes[episode]
    path = Path(ds.root) / ds.meta.get_video_file_path(episode, HEAD)
    ts = (np.asarray(timestamps, dtype=np.float64) + float(ep[f"videos/{HEAD}/from_timestamp"])).tolist()
    frames = decode_video_frames(path, ts, ds.tolerance_s, return_uint8=True)
    return np.asarray(frames).transpose(0, 2, 3, 1)


def view_dataset(
    root: str | Path,
    episodes: list[int] | None = None,
    save: str | Path | None = None,
    echo: Callable[[str], Any] = print,
) -> Path | None:
    """Log a dataset (LeRobot episodes + sidecar table) to Rerun: the overview of every attempt plus the
    given episodes. Writes `save` when given, else opens a viewer. Returns the file written, if any."""
    from .lerobot import HEAD, load_dataset

    root = Path(root)
    info = read_run_info(root)
    rows = read_attempts(root)
    scene = Scene(info["task"], info.get("joint_names"))
    ds = load_dataset(root, info.get("repo_id", "local/babblegen"))
    total = ds.meta.total_episodes
    episodes = list(range(total)) if episodes is None else episodes
    bad = [e for e in episodes if not 0 <= e < total]
    if bad:
        raise ValueError(f"episode {bad[0]} is not in {root} (it has episodes 0 to {total - 1})")

    rec = new_recording(f"view-{uuid.uuid4()}")
    bp = blueprint("frame_index" if len(episodes) == 1 else "index")
    if save is not None:
        save = Path(save)
        save.parent.mkdir(parents=True, exist_ok=True)
        rec.save(save, default_blueprint=bp)
    else:
        import sys

        import rerun as rr

        beside = Path(sys.executable).parent / "rerun"  # the viewer installed with rerun-sdk, even off PATH
        rr.spawn(recording=rec, default_blueprint=bp, executable_path=str(beside) if beside.exists() else None)
    image_size = None
    head = ds.meta.features.get(HEAD)
    if head is not None:
        image_size = (int(head["shape"][0]), int(head["shape"][1]))
    log_scene(rec, scene, image_size)
    columns = AttemptColumns(scene, static_overview=True)
    for row in rows:
        columns.add(row)
    columns.send(rec)

    table = ds.hf_dataset.with_format("arrow")[:]
    data = {
        name: _column(table, name)
        for name in (
            "observation.state",
            "observation.ee_pos",
            "observation.environment_state",
            "observation.contacts",
            "timestamp",
            "index",
        )
    }
    by_episode = {r["episode_index"]: r for r in rows if r.get("episode_index") is not None}
    n_obj = len(scene.object_names)
    decode_failed = False
    batch = EpisodeColumns(scene)
    for e in episodes:
        meta = ds.meta.episodes[e]
        a, b = int(meta["dataset_from_index"]), int(meta["dataset_to_index"])
        row = by_episode.get(e, {})
        images = None
        if not decode_failed:
            try:
                images = _decode_head(ds, e, data["timestamp"][a:b])
            except Exception as err:  # noqa: BLE001  (the rest of the episode is still worth showing)
                decode_failed = True
                echo(f"babblegen: warning: cannot decode the head-camera video ({err}); logging without images")
        targets = row.get("ee_targets")
        batch.add(
            EpisodeData(
                episode_index=e,
                state=data["observation.state"][a:b],
                ee_pos=data["observation.ee_pos"][a:b],
                object_poses=data["observation.environment_state"][a:b].reshape(b - a, n_obj, 7),
                contacts=data["observation.contacts"][a:b],
                fps=float(ds.fps),
                images=images,
                start_index=int(data["index"][a]),
                timestamps=data["timestamp"][a:b],
                attempt=row.get("attempt"),
                ee_targets=None if targets is None else np.asarray(targets),
            )
        )
        if batch.n_frames >= MAX_BUFFERED_FRAMES:
            batch.send(rec)
    batch.send(rec)
    try:
        rec.flush()
    except RuntimeError as e:
        if save is not None:
            raise
        raise ViewerError(f"the Rerun viewer could not be reached ({e}); write a file with --save FILE.rrd") from e
    finally:
        rec.disconnect()
    return save


def default_view_file(root: Path) -> Path:
    """Where `babblegen view` writes its recording when no viewer can be opened."""
    target = sidecar_dir(root)
    if os.access(target, os.W_OK):
        return target / "view.rrd"
    import tempfile

    return Path(tempfile.gettempdir()) / f"babblegen-view-{Path(root).resolve().name}.rrd"
