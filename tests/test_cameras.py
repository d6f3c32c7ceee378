"""The cameras a World records: parameters computed without the simulator equal SAPIEN's, and they put each
object's recorded pose on its own pixels in the masks, with a depth just in front of its centre."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from babblegen.exporters.lerobot_schema import features, image_key
from babblegen.tasks import get_task
from babblegen.world.cameras import task_instance_names, view_parameters
from babblegen.world.rollout import Command
from babblegen.world.settings import CAMERA_PRESETS, WorldSettings
from babblegen.world.world import World

pytestmark = pytest.mark.sim

TASK = get_task("noveb_tabletop")
VIEWS = tuple(
    replace(CAMERA_PRESETS[name], depth=True, segmentation=True) for name in ("head", "front", "side", "wrist")
)
SETTINGS = WorldSettings(cameras=VIEWS)
PUSH_THROUGH_CAN = np.array([[0.62, -0.08, 0.77], [0.84, -0.08, 0.77]])


@pytest.fixture(scope="module")
def world():
    w = World(TASK, SETTINGS, seed=0)
    yield w
    w.close()


@pytest.fixture(scope="module")
def push(world):
    rollout = world.rollout(Command("ee_waypoints", TASK.workspace.to_norm(PUSH_THROUGH_CAN)))
    assert rollout.feasible and rollout.touched.any()
    return rollout


def test_camera_parameters_without_the_simulator_are_sapien_s(world):
    for view in VIEWS:
        mine = view_parameters(view, TASK, view.size(SETTINGS))
        sapien = world.cameras.parameters(view.name)
        np.testing.assert_allclose(mine["intrinsics"], sapien["intrinsics"], rtol=1e-5, err_msg=view.name)
        if mine["cam2world"] is not None:
            np.testing.assert_allclose(mine["cam2world"], sapien["cam2world"], atol=1e-5, err_msg=view.name)


def test_every_object_lands_on_its_own_pixels_in_front_of_its_centre(world, push):
    """Each object's recorded position at the first and last frame, projected through the intrinsics and
    cam2world the dataset records, falls on a pixel of that object's id, whose depth is nearer than the
    object's centre by less than the object's size."""
    feats = features(world.kin.joint_names, TASK.object_names, 128, 128, VIEWS, TASK, SETTINGS)
    names = task_instance_names(TASK)
    frames = push.frames
    checked = 0
    for view in VIEWS:
        info = feats[image_key(view.name)]["info"]
        k = np.asarray(info["intrinsics"])
        for t in (0, len(frames) - 1):
            cam2world = (
                np.asarray(info["cam2world"])
                if "cam2world" in info
                else frames.camera_poses[view.name][t]  # the wrist camera, per frame
            )
            ids = frames.views[view.name]["segmentation"][t]
            depth = frames.views[view.name]["depth"][t]
            for j, obj in enumerate(TASK.objects):
                centre = np.append(frames.object_poses[t, j, :3], 1.0)
                cam = np.linalg.inv(cam2world) @ centre
                if cam[2] <= 0:
                    continue  # behind the camera
                u, v = (k @ cam[:3])[:2] / cam[2]
                col, row = int(np.floor(u)), int(np.floor(v))
                if not (0 <= row < ids.shape[0] and 0 <= col < ids.shape[1]):
                    continue  # outside this view
                if ids[row, col] != names.index(obj.name):
                    # occluded by another object or the arm: the id is one of them, never the background
                    assert names[ids[row, col]] not in ("background", "floor"), (view.name, t, obj.name)
                    continue
                size = max(obj.size) * 2.5
                assert cam[2] - size < depth[row, col] / 1000.0 < cam[2], (view.name, t, obj.name)
                checked += 1
    assert checked >= 12, "most objects seen by most cameras"


def test_masks_name_every_instance_seen_and_the_depth_is_in_millimetres(push):
    head = push.frames.views["head"]
    assert head["depth"].dtype == np.uint16 and head["segmentation"].dtype == np.uint8
    seen = set(np.unique(push.frames.views["front"]["segmentation"]))
    names = task_instance_names(TASK)
    assert {names.index(n) for n in ("table", "robot", "can")} <= seen
    table = push.frames.views["head"]["depth"][0][push.frames.views["head"]["segmentation"][0] == 1]
    assert 400 < np.median(table) < 2000, "the table top is 0.4 to 2 m from the head camera"
