"""Episodes and per-attempt scalars as Rerun columns: each batch goes out as one chunk per entity, on the
timelines `frame_index`, `timestamp`, `index`, `episode_index` and `attempt`."""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from babblegen.config import RERUN_FRAMES as FRAME_MODES  # what a run's recording logs per episode

from ..lerobot_encoding import encode_png
from .scene import CONTACT_COLOR, HEAD_IMAGE, START, TOOL_COLOR, Scene, object_parts, part_entities, quat_xyzw

if TYPE_CHECKING:
    import rerun as rr

JPEG_QUALITY = 85
MAX_BUFFERED_FRAMES = 3000  # episodes are sent to Rerun in batches of about this many frames


def encode_jpeg(images: np.ndarray, quality: int = JPEG_QUALITY) -> list[bytes]:
    """(T, H, W, 3) uint8 frames as JPEG bytes."""
    from PIL import Image

    out = []
    for img in images:
        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(img)).save(buf, format="JPEG", quality=quality)
        out.append(buf.getvalue())
    return out


def encode_view(kind: str, frames: Any, quality: int = JPEG_QUALITY) -> Any:
    """One camera's frames of one kind as the recording logs them: colour as JPEG, depth as 16-bit PNG (Rerun
    decodes it as a depth image; frames already encoded, a list of bytes, stay as they are), masks as (T, H, W)
    uint8 ids (as rendered, or read back from the dataset's 16-bit PNG)."""
    if isinstance(frames, list):
        return frames
    if kind == "rgb":
        return encode_jpeg(np.asarray(frames), quality)
    if kind == "depth":
        return encode_png(np.asarray(frames))
    return np.asarray(frames, dtype=np.uint8)


def logged_frames(n: int, frames: str) -> np.ndarray:
    """Indices of the frames an episode of ``n`` frames logs: all of them, or its first and last ("ends")."""
    if frames not in FRAME_MODES:
        raise ValueError(f"unknown recording frames {frames!r}; choose one of: {', '.join(FRAME_MODES)}")
    return np.arange(n) if frames == "all" or n <= 2 else np.array([0, n - 1])


class JpegFrames:
    """Every camera's frames as the recording logs them (`encode_view`), those of ``frames`` only; a picklable
    step for the worker-side preparers. Returns {camera: {kind: frames}}."""

    def __init__(self, quality: int = JPEG_QUALITY, frames: str = "all"):
        self.quality = quality
        self.frames = frames
        logged_frames(1, frames)  # checks the mode

    def __call__(self, frames: Any) -> dict[str, dict[str, Any]]:
        pick = logged_frames(len(frames.images), self.frames)
        out: dict[str, dict[str, Any]] = {"head": {"rgb": encode_jpeg(np.asarray(frames.images)[pick], self.quality)}}
        for camera, kinds in (getattr(frames, "views", None) or {}).items():
            mine = out.setdefault(camera, {})
            for kind, images in kinds.items():
                mine[kind] = encode_view(kind, np.asarray(images)[pick], self.quality)
        return out


def view_entity(camera: str, kind: str = "rgb") -> str:
    """Where a camera's images of one kind are logged (outside the camera's pinhole: see ``HEAD_IMAGE``)."""
    return f"{camera}_camera/" + {"rgb": "image", "depth": "depth", "segmentation": "segmentation"}[kind]


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
    # the other cameras' and kinds' frames (`JpegFrames`'s layout, or raw arrays): {camera: {kind: frames}}
    views: dict[str, dict[str, Any]] | None = None
    start_index: int = 0  # dataset-wide index of frame 0
    timestamps: np.ndarray | None = None  # (T,) seconds; frame_index / fps when None
    attempt: int | None = None
    ee_targets: np.ndarray | None = None  # (k, 3) commanded tool waypoints
    objects: list[dict[str, Any]] | None = None  # the objects it started with, one per slot (a sidecar row's)

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
    tool_path: np.ndarray  # (T_all, 3): every frame's tool position, also when only the ends are logged
    object_paths: np.ndarray  # (T_all, n, 3)
    touching: np.ndarray  # (T,) bool
    contacts: np.ndarray  # (T, n)
    state: np.ndarray
    jpegs: list[bytes] | None
    views: dict[str, dict[str, Any]]  # camera -> kind -> JPEG / PNG bytes per frame, or (T, H, W) uint8 ids
    targets: np.ndarray  # (k, 3)
    events: tuple[np.ndarray, np.ndarray]  # contact positions (m, 3), object index (m,)
    colors: list[tuple[int, int, int, int]]  # each slot's colour in this episode
    drawn: list[dict[str, Any]] | None  # its own objects, one per slot (runs that draw them), else None

    def __len__(self) -> int:
        return len(self.ee_pos)


class EpisodeColumns:
    """Collects episodes and sends them to Rerun as one chunk per entity: a recording stays compact (each
    chunk carries a few KiB of schema) and logging costs a handful of calls per batch, not per frame.

    Per logged frame: arm shapes, object poses, the tool point (red while touching), every camera's images,
    contact and joint scalars. At each episode's first frame: its whole tool path, waypoints, object paths, contact
    places and where the objects started (frame 0's poses, as wireframe boxes at `START`); in a run that draws its
    objects, also each object's parts (`object_parts`: shapes, sizes and colours), one entity per part under its
    slot's posed entity, emptied when a later episode's object lacks that part. ``frames="all"`` logs every frame;
    ``"ends"`` only each episode's first and last (before and after the movement, the frames the search compares),
    the paths still drawn from every frame.

    ``fresh``: the recording holds no episode yet; else (a resumed run's next segment) the first batch empties
    every part entity its episodes do not draw.
    """

    def __init__(self, scene: Scene, frames: str = "all", fresh: bool = True) -> None:
        logged_frames(1, frames)  # checks the mode
        self.scene = scene
        self.frames = frames
        self._eps: list[_Prepared] = []
        # per slot, the part entities the last episode sent drew (None: unknown, any of them)
        self._shown: dict[str, set[str] | None] = {n: set() if fresh else None for n in scene.object_names}

    @property
    def n_frames(self) -> int:
        return sum(len(e) for e in self._eps)

    def add(self, ep: EpisodeData) -> None:
        n_all = len(ep)
        pick = logged_frames(n_all, self.frames)
        n = len(pick)
        ts_all = np.asarray(ep.timestamps, dtype=np.float64) if ep.timestamps is not None else np.arange(n_all) / ep.fps
        times = {
            "frame_index": pick,
            "timestamp": ts_all[pick],
            "index": ep.start_index + pick,
            "episode_index": np.full(n, ep.episode_index),
        }
        if ep.attempt is not None:
            times["attempt"] = np.full(n, ep.attempt)
        state = np.asarray(ep.state, dtype=np.float64)[pick]
        tf = self.scene.link_transforms(state)
        arm = {}
        for kind, (links, origins, _) in self.scene.arm_shapes.items():
            world = tf[:, links] @ origins  # (T, S, 4, 4)
            arm[kind] = (world[..., :3, 3].reshape(-1, 3), quat_xyzw(world[..., :3, :3]).reshape(-1, 4))
        poses = np.asarray(ep.object_poses, dtype=np.float64)
        objects = poses[..., [0, 1, 2, 4, 5, 6, 3]]  # position, then the quaternion as x, y, z, w (Rerun's)
        contacts = np.asarray(ep.contacts, dtype=np.float64)
        ee = np.asarray(ep.ee_pos, dtype=np.float64)
        jpegs = None
        if ep.images is not None and len(ep.images):
            jpegs = _logged(ep.images, pick, n_all)
            jpegs = jpegs if isinstance(jpegs, list) else encode_jpeg(np.asarray(jpegs))
        views: dict[str, dict[str, Any]] = {}
        for camera, kinds in (ep.views or {}).items():
            for kind, frames in kinds.items():
                frames = encode_view(kind, _logged(frames, pick, n_all))
                if camera == "head" and kind == "rgb":
                    jpegs = frames
                else:
                    views.setdefault(camera, {})[kind] = frames
        t_idx, o_idx = np.nonzero(contacts > 0)
        self._eps.append(
            _Prepared(
                times=times,
                first={k: v[:1] for k, v in times.items()},
                arm=arm,
                objects=objects[pick],
                ee_pos=ee[pick],
                tool_path=ee,
                object_paths=objects[..., :3],
                touching=contacts[pick].any(axis=1),
                contacts=contacts[pick],
                state=state,
                jpegs=jpegs,
                views=views,
                targets=np.zeros((0, 3)) if ep.ee_targets is None else np.asarray(ep.ee_targets, float).reshape(-1, 3),
                events=(ee[t_idx], o_idx),
                colors=self.scene.episode_colors(ep.objects),
                drawn=(list(ep.objects) if ep.objects else self.scene.objects) if self.scene.drawn else None,
            )
        )

    def send(self, rec: rr.RecordingStream) -> None:
        """Log the collected episodes and clear the buffer."""
        eps, self._eps = self._eps, []
        # episodes with and without an attempt number have different timelines: send them apart
        for group in ([e for e in eps if "attempt" in e.times], [e for e in eps if "attempt" not in e.times]):
            if group:
                self._send(rec, group)

    def _send(self, rec: rr.RecordingStream, eps: list[_Prepared]) -> None:
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
        _send_views(rec, eps, names)
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
            columns=rr.LineStrips3D.columns(strips=[e.tool_path for e in eps]).partition([1] * len(eps)),
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
                strips=[e.object_paths[:, j] for e in eps for j in range(n_obj)],
                colors=[c for e in eps for c in e.colors],
                labels=[n for _ in eps for n in scene.object_names],
            ).partition([n_obj] * len(eps)),
        )
        start = {
            "centers": cat([e.objects[0, :, :3] for e in eps]),
            "quaternions": cat([e.objects[0, :, 3:] for e in eps]),
        }
        if scene.drawn:  # each episode's own bounding boxes and colours
            start["half_sizes"] = cat([scene.half_sizes(e.drawn) for e in eps])
            start["colors"] = [c for e in eps for c in e.colors]
        rec.send_columns(START, indexes=first, columns=rr.Boxes3D.columns(**start).partition([n_obj] * len(eps)))
        if scene.drawn:
            self._send_parts(rec, eps, first)
        rec.send_columns(
            "world/contact_events",
            indexes=first,
            columns=rr.Points3D.columns(
                positions=cat([e.events[0] for e in eps]).reshape(-1, 3),
                colors=[e.colors[o] for e in eps for o in e.events[1].astype(int)],
                labels=[scene.object_names[o] for e in eps for o in e.events[1].astype(int)],
            ).partition([len(e.events[1]) for e in eps]),
        )

    def _send_parts(self, rec: rr.RecordingStream, eps: list[_Prepared], first: list[rr.TimeColumn]) -> None:
        """Each episode's objects, part by part, at its first frame: one entity per part (`object_parts`) under the
        slot's entity, which is posed per frame; a part entity an episode's object lacks gets no instance."""
        import rerun as rr

        universe = part_entities()
        for j, name in enumerate(self.scene.object_names):
            drawn = [{p.entity: p for p in object_parts(e.drawn[j])} for e in eps]
            shown = self._shown[name]
            entities = set().union(*drawn) | (set(universe) if shown is None else shown)
            for entity in sorted(entities):
                archetype = universe[entity]
                columns = []
                for field, dims in PART_FIELDS[archetype].items():
                    dtype = PART_DTYPES.get(field, np.float32)
                    values = [
                        np.asarray(d[entity].fields[field], dtype=dtype).reshape(-1, *dims)
                        if entity in d
                        else np.zeros((0, *dims), dtype=dtype)
                        for d in drawn
                    ]
                    cols = getattr(rr, archetype).columns(**{field: np.concatenate(values)})
                    columns += cols.partition([len(v) for v in values])
                rec.send_columns(f"world/objects/{name}/{entity}", indexes=first, columns=columns)
            self._shown[name] = set(drawn[-1])


# the components of each part archetype (`object_parts`) and the shape of one of their values
PART_FIELDS: dict[str, dict[str, tuple[int, ...]]] = {
    "Boxes3D": {"half_sizes": (3,), "centers": (3,), "colors": (4,)},
    "Ellipsoids3D": {"half_sizes": (3,), "centers": (3,), "colors": (4,)},
    "Cylinders3D": {"lengths": (), "radii": (), "centers": (3,), "colors": (4,)},
    "Capsules3D": {"lengths": (), "radii": (), "translations": (3,), "quaternions": (4,), "colors": (4,)},
    "Mesh3D": {"vertex_positions": (3,), "vertex_normals": (3,), "triangle_indices": (3,), "albedo_factor": (4,)},
}
PART_DTYPES = {"colors": np.uint8, "albedo_factor": np.uint8, "triangle_indices": np.uint32}


def _logged(frames: Any, pick: np.ndarray, n_all: int) -> Any:
    """An episode's frames of one kind, those at ``pick``: already picked (a worker prepared only those), or all
    ``n_all`` of them (picked here)."""
    if len(frames) == len(pick):
        return frames
    if len(frames) != n_all:
        raise ValueError(f"an episode of {n_all} frames came with {len(frames)} images")
    return [frames[i] for i in pick] if isinstance(frames, list) else np.asarray(frames)[pick]


def _send_views(rec: rr.RecordingStream, eps: list[_Prepared], names: list[str]) -> None:
    """The other cameras' images and the head camera's depth and masks, one column per camera and kind."""
    import rerun as rr

    cat = np.concatenate
    pairs = dict.fromkeys((c, k) for e in eps for c, kinds in e.views.items() for k in kinds)
    for camera, kind in pairs:
        having = [e for e in eps if kind in e.views.get(camera, {})]
        idx = [_time_column(k, cat([e.times[k] for e in having])) for k in names]
        frames = [f for e in having for f in e.views[camera][kind]]
        if kind == "rgb":
            cols = rr.EncodedImage.columns(blob=frames, media_type=["image/jpeg"] * len(frames))
        elif kind == "depth":
            cols = rr.EncodedDepthImage.columns(
                blob=frames, media_type=["image/png"] * len(frames), meter=[1000.0] * len(frames)
            )
        else:
            h, w = frames[0].shape
            fmt = rr.components.ImageFormat(width=w, height=h, channel_datatype="U8")
            cols = rr.SegmentationImage.columns(buffer=[f.tobytes() for f in frames], format=[fmt] * len(frames))
        rec.send_columns(view_entity(camera, kind), indexes=idx, columns=cols)


def _time_column(name: str, values: np.ndarray) -> rr.TimeColumn:
    import rerun as rr

    if name == "timestamp":
        return rr.TimeColumn(name, duration=np.asarray(values, dtype=np.float64))
    return rr.TimeColumn(name, sequence=np.asarray(values, dtype=np.int64))


def log_episode(rec: rr.RecordingStream, scene: Scene, ep: EpisodeData) -> None:
    """Log one episode (see `EpisodeColumns` for what is drawn)."""
    cols = EpisodeColumns(scene)
    cols.add(ep)
    cols.send(rec)
