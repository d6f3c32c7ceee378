"""A recording from a finished dataset (`babblegen view`): the overview of every attempt and the episodes asked
for, read back from the LeRobot dataset and the sidecar table."""

from __future__ import annotations

import os
import sys
import tempfile
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.dataset.lerobot import column, episode_images, load_dataset
from babblegen.dataset.paths import sidecar_dir
from babblegen.dataset.schema import CONTACTS, EE_POS, ENVIRONMENT_STATE, HEAD, STATE
from babblegen.dataset.sidecar import read_attempts, read_run_info

from .attempts import AttemptColumns
from .columns import MAX_BUFFERED_FRAMES, EpisodeColumns, EpisodeData
from .layout import blueprint, new_recording
from .scene import Scene, log_scene, objects_drawn


class ViewerError(RuntimeError):
    """The spawned Rerun viewer went away (no display, closed window) before the data reached it."""


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
        state=data[STATE][rows],
        ee_pos=data[EE_POS][rows],
        object_poses=data[ENVIRONMENT_STATE][rows].reshape(n, n_objects, 7),
        contacts=data[CONTACTS][rows].reshape(n, n_objects),  # one object's: a column of scalars
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
    data = {name: column(table, name) for name in (STATE, EE_POS, ENVIRONMENT_STATE, CONTACTS, "timestamp", "index")}
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
                views = episode_images(ds, table, e, slice(a, b), data["timestamp"][a:b])
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
    return Path(tempfile.gettempdir()) / f"babblegen-view-{Path(root).resolve().name}.rrd"
