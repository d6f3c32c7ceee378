"""The cameras a World records: parameters computed without the simulator equal SAPIEN's, and they put each
object's recorded pose on its own pixels in the masks, with a depth just in front of its centre."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from babblegen.camera_views import CAMERA_PRESETS
from babblegen.dataset.schema import features, image_key
from babblegen.tasks import get_task
from babblegen.world.cameras import task_instance_names, view_parameters
from babblegen.world.rollout import Command
from babblegen.world.settings import WorldSettings
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


def _seen_point(obj, pose: np.ndarray) -> np.ndarray:
    """A point inside the object in the world: the centre of its largest part (an ell's bounding box centre lies
    beside its bars)."""
    from scipy.spatial.transform import Rotation

    part = max(obj.parts(), key=lambda p: p.volume)
    w, x, y, z = pose[3:]
    return pose[:3] + Rotation.from_quat([x, y, z, w]).apply(part.offset)


def test_drawn_objects_land_on_their_own_ids_and_depth():
    """With drawn objects (varied and held out), every shape kind's centre, projected through the head camera's
    stored parameters, lands on its own instance id with a depth just in front of it in at least 90 % of the
    object-frames where nothing nearer hides it (the arm or another object: their id and a depth nearer than the
    object's); background, table or floor there, or a depth behind the object, is a miss."""
    from babblegen.objects import HELDOUT_SHAPES, VARIED_SHAPES, ObjectSampler, slot_task
    from babblegen.starts import StartSampler

    views = (replace(CAMERA_PRESETS["head"], depth=True, segmentation=True),)
    settings = WorldSettings(cameras=views, objects="varied", num_objects=6)
    task = slot_task(TASK, "varied", 6)
    world = World(TASK, settings, seed=0)
    feats = features(world.kin.joint_names, task.object_names, 128, 128, views, task, settings)
    info = feats[image_key("head")]["info"]
    k, cam2world = np.asarray(info["intrinsics"]), np.asarray(info["cam2world"])
    names = task_instance_names(task)
    hits: dict[str, list[bool]] = {}
    hidden = 0
    try:
        for object_set, attempts in (("varied", 3), ("heldout", 1)):
            sampler = StartSampler(task, 11, ObjectSampler(object_set, 6, 11))
            for attempt in range(attempts):
                start = sampler.draw(attempt)
                genome = TASK.workspace.to_norm(np.array([[0.62, start.layout[1, 1], 0.9], [0.8, 0.0, 0.78]]))
                rollout = world.rollout(Command("ee_waypoints", genome, start.placement, start.objects))
                assert rollout.feasible, rollout.reason
                frames = rollout.frames
                for t in range(0, len(frames), 2):
                    ids, depth = frames.views["head"]["segmentation"][t], frames.views["head"]["depth"][t]
                    for j, obj in enumerate(start.objects):
                        point = _seen_point(obj, frames.object_poses[t, j].astype(np.float64))
                        cam = np.linalg.inv(cam2world) @ np.append(point, 1.0)
                        u, v = (k @ cam[:3])[:2] / cam[2]
                        row, col = int(np.floor(v)), int(np.floor(u))
                        assert 0 <= row < 128 and 0 <= col < 128, "drawn objects start whole in the head camera's view"
                        seen, d = names[ids[row, col]], depth[row, col] / 1000.0
                        if seen != obj.name and seen not in ("background", "table", "floor") and d < cam[2]:
                            hidden += 1
                            continue
                        ok = seen == obj.name and cam[2] - 2.5 * max(obj.size) < d < cam[2] + 1e-3
                        hits.setdefault(obj.shape, []).append(bool(ok))
    finally:
        world.close()
    assert set(hits) == set(VARIED_SHAPES) | set(HELDOUT_SHAPES)
    for shape, seen in hits.items():
        assert np.mean(seen) >= 0.9, (shape, np.mean(seen), len(seen))
    assert hidden < 0.1 * sum(len(v) for v in hits.values())
