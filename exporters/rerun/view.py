"""A recording from a finished dataset (`babblegen view`): the overview of every attempt and the episodes asked
for, read back from the LeRobot dataset and the sidecar table."""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..sidecar import read_attempts, read_run_info, sidecar_dir
from .attempts import AttemptColumns
from .columns import MAX_BUFFERED_FRAMES, EpisodeColumns, EpisodeData
from .layout import blueprint, new_recording
from .scene import Scene, log_scene, objects_drawn

if TYPE_CHECKING:
    import pyarrow as pa


class ViewerError(RuntimeError):
    """The spawned Rerun viewer went away (no display, closed window) before the data reached it."""


def _column(table: pa.Table, name: str) -> np.ndarray:
    import pyarrow as pa

    arr = table.column(name).combine_chunks()
    if pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type) or pa.types.is_large_list(arr.type):
        return arr.flatten().to_numpy(zero_copy_only=False).reshape(len(arr), -1)
    return arr.to_numpy(zero_copy_only=False)


def _decode_video(ds, episode: int, key: str, timestamps: np.ndarray) -> np.ndarray:
    """An episode's frames of one video feature: (T, H, W, 3) uint8 colour, or (T, H, W) uint16 millimetres for
    a depth map."""
    from lerobot.datasets.depth_utils import dequantize_depth
    from lerobot.datasets.video_utils import decode_video_frames

    ep = ds.meta.episodes[episode]
    path = Path(ds.root) / ds.meta.get_video_file_path(episode, key)
    ts = (np.asarray(timestamps, dtype=np.float64) + float(ep[f"videos/{key}/from_timestamp"])).tolist()
    info = ds.meta.features[key].get("info") or {}
    if not info.get("is_depth_map"):
        return np.asarray(decode_video_frames(path, ts, ds.tolerance_s, return_uint8=True)).transpose(0, 2, 3, 1)
    codes = decode_video_frames(path, ts, ds.tolerance_s, is_depth=True, backend="pyav")
    mm = dequantize_depth(
        codes,
        depth_min=info["video.depth_min"],
        depth_max=info["video.depth_max"],
        shift=info.get("video.shift", 3.5),
        use_log=info.get("video.use_log", False),
        output_unit="mm",
        output_tensor=False,
    )
    return np.asarray(mm).reshape(len(ts), *ds.meta.features[key]["shape"][:2]).astype(np.uint16)


def _episode_images(ds, table, episode: int, rows: slice, timestamps: np.ndarray) -> dict[str, dict[str, Any]]:
    """Every camera's images of an episode read back from the dataset: {camera: {kind: frames}}."""
    import io

    from PIL import Image

    from ..lerobot_schema import image_sources

    out: dict[str, dict[str, Any]] = {}
    for key, (camera, kind) in image_sources(ds.meta.features).items():
        if ds.meta.features[key]["dtype"] == "video":
            out.setdefault(camera, {})[kind] = _decode_video(ds, episode, key, timestamps)
        else:  # masks, stored as PNG in the table
            cells = table.column(key).combine_chunks().field("bytes").to_pylist()[rows]
            out.setdefault(camera, {})[kind] = np.stack([np.asarray(Image.open(io.BytesIO(c))) for c in cells])
    return out


def episode_data(
    data: dict[str, np.ndarray],
    episode: int,
    rows: slice,
    n_objects: int,
    fps: float,
    views: dict[str, dict[str, Any]] | None,
    row: dict[str, Any] | None = None,
) -> EpisodeData:
    """One episode read back from the dataset's columns (``data``, sliced at ``rows``), with its images and, given
    its sidecar row, its attempt, commanded waypoints and objects."""
    row = row or {}
    targets = row.get("ee_targets")
    n = rows.stop - rows.start
    return EpisodeData(
        episode_index=episode,
        state=data["observation.state"][rows],
        ee_pos=data["observation.ee_pos"][rows],
        object_poses=data["observation.environment_state"][rows].reshape(n, n_objects, 7),
        contacts=data["observation.contacts"][rows].reshape(n, n_objects),  # one object's: a column of scalars
        fps=fps,
        views=views,
        start_index=int(data["index"][rows.start]),
        timestamps=data["timestamp"][rows],
        attempt=row.get("attempt"),
        ee_targets=None if targets is None else np.asarray(targets),
        objects=row.get("objects"),
    )


def view_dataset(
    root: str | Path,
    episodes: list[int] | None = None,
    save: str | Path | None = None,
    echo: Callable[[str], Any] = print,
) -> Path | None:
    """Log a dataset (LeRobot episodes + sidecar table) to Rerun: the overview of every attempt plus the
    given episodes. Writes `save` when given, else opens a viewer. Returns the file written, if any."""
    from ..lerobot import HEAD, load_dataset

    root = Path(root)
    info = read_run_info(root)
    rows = read_attempts(root)
    scene = Scene(info["task"], info.get("joint_names"), drawn=objects_drawn(info))
    ds = load_dataset(root, info.get("repo_id", "local/babblegen"))
    total = ds.meta.total_episodes
    episodes = list(range(total)) if episodes is None else episodes
    bad = [e for e in episodes if not 0 <= e < total]
    if bad:
        raise ValueError(f"episode {bad[0]} is not in {root} (it has episodes 0 to {total - 1})")

    rec = new_recording(f"view-{uuid.uuid4()}")
    cameras = (info.get("config", {}).get("world", {}) or {}).get("cameras")
    bp = blueprint("frame_index" if len(episodes) == 1 else "index", cameras)
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
    log_scene(rec, scene, image_size, cameras)
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
        views = None
        if not decode_failed:
            try:
                views = _episode_images(ds, table, e, slice(a, b), data["timestamp"][a:b])
            except Exception as err:  # noqa: BLE001  (the rest of the episode is still worth showing)
                decode_failed = True
                echo(f"babblegen: warning: cannot decode the camera videos ({err}); logging without images")
        batch.add(episode_data(data, e, slice(a, b), n_obj, float(ds.fps), views, row))
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
