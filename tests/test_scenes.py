"""Every registered scene builds, renders the head camera, and executes a movement; extra static obstacles are
both simulated and planned around.

One World per scene (module scope): the first render of a World compiles shaders on the CPU renderer.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from babblegen.tasks import TASKS, get_task
from babblegen.world.rollout import Command
from babblegen.world.world import World, WorldSettings

pytestmark = pytest.mark.filterwarnings("ignore:__array_wrap__ must accept context:DeprecationWarning")

# Tool targets in free air, 25 cm above the table top, over the middle of the table (world frame, metres above
# the table top): any reasonable scene has one of them reachable and collision-free.
FREE_AIR = [(0.65, -0.25, 0.25), (0.70, 0.0, 0.25), (0.60, -0.40, 0.22)]


@pytest.fixture(scope="module", params=sorted(TASKS))
def world(request):
    w = World(get_task(request.param), WorldSettings(camera_width=64, camera_height=64), seed=0)
    yield w
    w.close()


def free_air_rollout(w: World):
    for x, y, dz in FREE_AIR:
        target = np.array([[x, y, w.task.table_top + dz]])
        r = w.rollout(Command("ee_waypoints", w.task.workspace.to_norm(target)))
        if r.feasible:
            return r
    pytest.fail(f"{w.task.name}: none of the free-air targets is feasible")


def test_scene_is_registered_consistently(world):
    task = world.task
    env_cls = type(gym.make(task.env_id, obs_mode="none", render_backend="none").unwrapped)
    assert env_cls.task_spec is task
    assert task.description.strip()
    assert len(set(task.object_names)) == len(task.object_names)
    # every object rests where the spec says, after a reset
    world.reset()
    rest = np.array([task.rest_pose(o) for o in task.objects])
    assert np.allclose(world.start_poses[:, :3], rest[:, :3], atol=1e-3)


def project(w: World, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (column, row) of world points in the head camera image."""
    params = w._camera.get_params()
    k, ext = params["intrinsic_cv"][0].numpy(), params["extrinsic_cv"][0].numpy()
    uv = (np.atleast_2d(points) @ ext[:3, :3].T + ext[:3, 3]) @ k.T
    return uv[:, :2] / uv[:, 2:]


def test_head_camera_sees_the_scene(world):
    world.reset()
    image = world._render()
    assert image.shape == (64, 64, 3) and image.dtype == np.uint8
    assert image.std() > 10 and len(np.unique(image.reshape(-1, 3), axis=0)) > 10
    # every object is in view and stands out from the table around it
    colours, counts = np.unique(image[32:].reshape(-1, 3), axis=0, return_counts=True)
    table = colours[np.argmax(counts)].astype(int)
    for obj, (u, v) in zip(world.task.objects, project(world, world.start_poses[:, :3]), strict=True):
        assert 0 <= u < 64 and 0 <= v < 64, f"{obj.name} is outside the image"
        assert np.abs(image[int(v), int(u)].astype(int) - table).max() > 20, f"{obj.name} is not visible"


def test_one_feasible_rollout(world):
    r = free_air_rollout(world)
    n = len(r.frames)
    assert n > 5
    assert r.frames.images.shape == (n, 64, 64, 3)
    assert r.frames.object_poses.shape == (n, len(world.task.objects), 7)
    # a movement through free air leaves every object where it was: the scene is stable at rest
    assert not r.touched.any()
    assert r.displacement.max() < 0.005, dict(zip(world.task.object_names, r.displacement, strict=True))
    assert np.abs(r.frames.images[0].astype(int) - r.frames.images[-1].astype(int)).max() < 40


def test_extra_obstacles_are_simulated_and_planned_around(world):
    task = world.task
    if not task.extra_obstacles:
        pytest.skip(f"{task.name} has no extra obstacles")
    built = {a.name: a for a in world.sim.obstacles}
    for box in task.extra_obstacles:
        assert np.allclose(built[box.name].pose.p.numpy()[0], box.center, atol=1e-6)  # a static actor in the sim
        assert box in world.collision.obstacles
        # the tool point inside the obstacle: no collision-free configuration reaches it
        inside = np.array([box.center])
        r = world.rollout(Command("ee_waypoints", task.workspace.to_norm(inside)))
        assert not r.feasible and r.reason in ("target_in_collision", "out_of_reach", "no_ik")
