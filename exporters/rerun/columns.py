"""Episodes and per-attempt scalars as Rerun columns: each batch goes out as one chunk per entity, on the
timelines `frame_index`, `timestamp`, `index`, `episode_index` and `attempt`."""

from __future__ import annotations

import io
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from .scene import CONTACT_COLOR, HEAD_IMAGE, START, TOOL_COLOR, Scene, quat_xyzw

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
    from ..lerobot_encoding import encode_png

    if isinstance(frames, list):
        return frames
    if kind == "rgb":
        return encode_jpeg(np.asarray(frames), quality)
    if kind == "depth":
        return encode_png(np.asarray(frames))
    return np.asarray(frames, dtype=np.uint8)


class JpegFrames:
    """Every camera's frames as the recording logs them (`encode_view`); a picklable step for the worker-side
    preparers. Returns {camera: {kind: frames}}."""

    def __init__(self, quality: int = JPEG_QUALITY):
        self.quality = quality

    def __call__(self, frames: Any) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {"head": {"rgb": encode_jpeg(frames.images, self.quality)}}
        for camera, kinds in (getattr(frames, "views", None) or {}).items():
            mine = out.setdefault(camera, {})
            for kind, images in kinds.items():
                mine[kind] = encode_view(kind, images, self.quality)
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
    views: dict[str, dict[str, Any]]  # camera -> kind -> JPEG / PNG bytes per frame, or (T, H, W) uint8 ids
    targets: np.ndarray  # (k, 3)
    events: tuple[np.ndarray, np.ndarray]  # contact positions (m, 3), object index (m,)

    def __len__(self) -> int:
        return len(self.ee_pos)


class EpisodeColumns:
    """Collects episodes and sends them to Rerun as one chunk per entity: a recording stays compact (each
    chunk carries a few KiB of schema) and logging costs a handful of calls per batch, not per frame.

    Per frame: arm shapes, object poses, the tool point (red while touching), head-camera JPEGs, contact and
    joint scalars. At each episode's first frame: its tool path, waypoints, object paths, contact places and
    where the objects started (frame 0's poses, as wireframe boxes at `START`).
    """

    def __init__(self, scene: Scene) -> None:
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
        objects = poses[..., [0, 1, 2, 4, 5, 6, 3]]  # position, then the quaternion as x, y, z, w (Rerun's)
        contacts = np.asarray(ep.contacts, dtype=np.float64)
        ee = np.asarray(ep.ee_pos, dtype=np.float64)
        jpegs = None
        if ep.images is not None and len(ep.images):
            jpegs = ep.images if isinstance(ep.images, list) else encode_jpeg(np.asarray(ep.images))
        views: dict[str, dict[str, Any]] = {}
        for camera, kinds in (ep.views or {}).items():
            for kind, frames in kinds.items():
                frames = encode_view(kind, frames)
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
                objects=objects,
                ee_pos=ee,
                touching=contacts.any(axis=1),
                contacts=contacts,
                state=np.asarray(ep.state, dtype=np.float64),
                jpegs=jpegs,
                views=views,
                targets=np.zeros((0, 3)) if ep.ee_targets is None else np.asarray(ep.ee_targets, float).reshape(-1, 3),
                events=(ee[t_idx], o_idx),
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
        rec.send_columns(
            START,
            indexes=first,
            columns=rr.Boxes3D.columns(
                centers=cat([e.objects[0, :, :3] for e in eps]), quaternions=cat([e.objects[0, :, 3:] for e in eps])
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

    def __init__(self, scene: Scene, tally: Tally | None = None, static_overview: bool = False) -> None:
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

    def send(self, rec: rr.RecordingStream) -> None:
        """Log the buffered rows and clear the buffer."""
        import rerun as rr

        if not self._rows:
            return
        rows, self._rows = self._rows, []
        for executed in (True, False):
            part = [r for r in rows if (r["episode"] >= 0) == executed]
            if not part:
                continue

            def indexes(sel: list[dict[str, Any]], executed: bool = executed) -> list[rr.TimeColumn]:
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

    def _send_overview(
        self, rec: rr.RecordingStream, part: list[dict[str, Any]], indexes: Callable[[list], list]
    ) -> None:
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
