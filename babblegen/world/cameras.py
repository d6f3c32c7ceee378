"""The cameras a World records, read in one pass each: colour, depth and instance ids from SAPIEN's minimal
shader (depth and ids share one texture, read back beside the colour one), and each camera's parameters in
OpenCV's convention.

Depth is what the shader gives: whole millimetres along the camera's optical axis, as uint16 (0 where nothing
is seen). Instance ids are compact and the same in every scene rebuild and every process: 0 background, 1 table,
2 floor, 3 robot (every link), then the task's objects in order, then its static obstacles
(`instance_names`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from babblegen.camera_views import CameraView
from babblegen.scene import TaskSpec
from babblegen.world.exact import rigid_inverse, row_norm


def instance_names(object_names: Sequence[str], obstacle_names: Sequence[str] = ()) -> list[str]:
    """Instance id -> name: background, table, floor, robot, the objects, the obstacles."""
    return ["background", "table", "floor", "robot", *object_names, *obstacle_names]


def task_instance_names(task: TaskSpec) -> list[str]:
    return instance_names(task.object_names, [b.name for b in task.extra_obstacles])


class CameraRig:
    """The World's ManiSkill cameras by view name, and the map from the simulator's per-entity segmentation ids
    (which a rebuilt scene may renumber) to the compact instance ids. Rebuild it with the scene."""

    def __init__(self, sim, task: TaskSpec, views: Sequence[CameraView]):
        self.views = {v.name: v for v in views}
        self.sensors = {v.name: sim.scene.sensors[v.name] for v in views}
        ids = {name: i for i, name in enumerate(task_instance_names(task))}
        lut = np.zeros(max(sim.segmentation_id_map, default=0) + 1, dtype=np.uint8)
        for seg_id, entity in sim.segmentation_id_map.items():
            kind = type(entity).__name__
            lut[seg_id] = ids["robot"] if kind == "Link" else ids.get(entity.name, ids["background"])
        self._lut = lut

    def read(self, name: str) -> dict[str, np.ndarray]:
        """One camera's images of the scene as last rendered (`capture` first): ``rgb`` (H, W, 3) uint8, and as
        its view records them ``depth`` (H, W) uint16 mm and ``segmentation`` (H, W) uint8 ids."""
        view = self.views[name]
        obs = self.sensors[name].get_obs(rgb=True, depth=view.depth, segmentation=view.segmentation, position=False)
        out = {"rgb": obs["rgb"][0].numpy()}
        if view.depth:
            out["depth"] = obs["depth"][0, ..., 0].numpy().astype(np.uint16)
        if view.segmentation:
            seg = obs["segmentation"][0, ..., 0].numpy().astype(np.int64)
            out["segmentation"] = self._lut[np.clip(seg, 0, len(self._lut) - 1)]
        return out

    def capture(self, names: Sequence[str]) -> None:
        for name in names:
            self.sensors[name].capture()

    def parameters(self, name: str) -> dict[str, np.ndarray]:
        """``intrinsics`` (3x3 pinhole, pixels) and ``cam2world`` (4x4, OpenCV camera axes in the world frame)
        of a camera where it is now."""
        params = self.sensors[name].get_params()
        world_to_cam = np.eye(4)
        world_to_cam[:3, :] = params["extrinsic_cv"][0].numpy()
        return {
            "intrinsics": params["intrinsic_cv"][0].numpy().astype(np.float64),
            "cam2world": rigid_inverse(world_to_cam),
        }


def look_at_cam2world(eye: Sequence[float], target: Sequence[float]) -> np.ndarray:
    """The OpenCV cam2world (x right, y down, z forward) of a camera at ``eye`` looking at ``target`` with the
    world's z up, as ManiSkill's ``look_at`` places a camera."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    forward = (target - eye) / row_norm(target - eye)
    left = np.cross([0.0, 0.0, 1.0], forward)
    left /= row_norm(left)
    up = np.cross(forward, left)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = -left, -up, forward, eye
    return out


def pinhole(height: int, width: int, fov: float) -> np.ndarray:
    """The 3x3 intrinsics of a camera with vertical field of view ``fov`` (radians) and square pixels, its
    principal point at the image centre (SAPIEN's)."""
    f = (height / 2.0) / np.tan(fov / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def view_parameters(view: CameraView, task: TaskSpec, size: tuple[int, int]) -> dict[str, np.ndarray | None]:
    """A view's ``intrinsics`` and, for a camera that does not move, its ``cam2world`` (None for a wrist
    camera, whose pose is recorded per frame), without the simulator: the same numbers SAPIEN reports
    (``tests/test_cameras.py``)."""
    height, width = size
    if view.mount == "head":
        cam = task.camera
        return {"intrinsics": pinhole(height, width, cam.fov), "cam2world": look_at_cam2world(cam.eye, cam.target)}
    cam2world = look_at_cam2world(view.eye, view.target) if view.mount == "fixed" else None
    return {"intrinsics": pinhole(height, width, view.fov), "cam2world": cam2world}
