"""Reading the LeRobot dataset: opening it with LeRobot's loader (offline and quiet), its ``meta/info.json`` without
LeRobot, and an episode's columns and images as numpy arrays (video decoded, depth in millimetres, masks from their
PNGs). LeRobot, PyAV, pyarrow and PIL load inside the functions that use them: importing this module stays cheap
for the commands that only name it (``babblegen --help``, ``report``)."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from babblegen.dataset.paths import LEROBOT_INFO
from babblegen.dataset.schema import image_sources

if TYPE_CHECKING:
    import pyarrow as pa


def import_lerobot():
    """LeRobot, offline and quiet; returns ``LeRobotDataset``."""
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1: errors only
    import av
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    av.logging.set_level(av.logging.ERROR)
    av.logging.set_libav_level(av.logging.ERROR)  # LeRobot restores FFmpeg's own logger, which prints mp4 notes
    datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise
    return LeRobotDataset


def load_dataset(root: str | Path, repo_id: str = "local/babblegen", **kwargs):
    """Open a finished dataset for reading with LeRobot (offline); ``kwargs`` go to ``LeRobotDataset``
    (``depth_output_unit="m"``: depth maps in metres)."""
    return import_lerobot()(repo_id, root=Path(root), **kwargs)


def read_dataset_info(root: str | Path) -> dict[str, Any]:
    """LeRobot's ``meta/info.json`` (features, ``total_episodes``, ``total_frames``, ``fps``), read as JSON."""
    return json.loads((Path(root) / LEROBOT_INFO).read_text())


def frame_columns(ds, names) -> dict[str, np.ndarray]:
    """The frame table's ``episode_index`` and columns ``names`` of an opened dataset (`load_dataset`), as numpy
    arrays with one row a frame."""
    return ds.hf_dataset.select_columns(["episode_index", *names]).with_format("numpy")[:]


def to_uint8_image(chw: np.ndarray) -> np.ndarray:
    """LeRobot returns images as float CHW in [0, 1]; this gives HWC uint8."""
    arr = np.asarray(chw)
    return np.clip(np.round(arr.transpose(1, 2, 0) * 255), 0, 255).astype(np.uint8)


def column(table: pa.Table, name: str) -> np.ndarray:
    """One column of the dataset's Arrow table as numpy: (frames,) for scalars, (frames, n) for vectors."""
    import pyarrow as pa

    arr = table.column(name).combine_chunks()
    if pa.types.is_list(arr.type) or pa.types.is_fixed_size_list(arr.type) or pa.types.is_large_list(arr.type):
        return arr.flatten().to_numpy(zero_copy_only=False).reshape(len(arr), -1)
    return arr.to_numpy(zero_copy_only=False)


def decode_video(ds, episode: int, key: str, timestamps: np.ndarray) -> np.ndarray:
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


def episode_images(ds, table: pa.Table, episode: int, rows: slice, timestamps: np.ndarray) -> dict[str, dict[str, Any]]:
    """Every camera's images of an episode read back from the dataset (``table``: its Arrow table, ``rows`` the
    episode's): {camera: {kind: frames}} (`schema.image_sources`)."""
    from PIL import Image

    out: dict[str, dict[str, Any]] = {}
    for key, (camera, kind) in image_sources(ds.meta.features).items():
        if ds.meta.features[key]["dtype"] == "video":
            out.setdefault(camera, {})[kind] = decode_video(ds, episode, key, timestamps)
        else:  # masks, stored as PNG in the table
            cells = table.column(key).combine_chunks().field("bytes").to_pylist()[rows]
            out.setdefault(camera, {})[kind] = np.stack([np.asarray(Image.open(io.BytesIO(c))) for c in cells])
    return out
