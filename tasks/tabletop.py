"""A generic ManiSkill tabletop env built from a `TaskSpec`: a box table, free objects, a head camera.

Scene modules subclass `TabletopEnv`, set `task_spec`, and register with `@register_env`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building.actor_builder import ActorBuilder
from mani_skill.utils.structs import Pose
from mani_skill.utils.structs.types import SceneConfig, SimConfig

from babblegen.camera_views import CAMERA_PRESETS
from babblegen.scene import FLOOR_HALF_EXTENT, TaskSpec
from babblegen.shapes import Box, ObjectSpec, Part

# A URDF/SAPIEN cylinder's axis is x; this turns it upright.
_UPRIGHT = [np.sqrt(0.5), 0.0, -np.sqrt(0.5), 0.0]
OBSTACLE_COLOR = [0.55, 0.6, 0.72, 1.0]  # static obstacles (TaskSpec.extra_obstacles): slate blue
# The wrist camera in the tool link's frame (x along the gripper): 12 cm behind the tool point and 6 cm above,
# pitched 25 degrees down towards it.
WRIST_CAMERA_OFFSET = [-0.12, 0.0, 0.06]
WRIST_CAMERA_TILT = [float(np.cos(0.2182)), 0.0, float(np.sin(0.2182)), 0.0]
DEFAULT_MATERIAL = (0.3, 0.3, 0.0)  # PhysX's default material in SAPIEN: static, dynamic friction, restitution
_CUBE_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)  # a box's, unit


class ObjectBuilder(ActorBuilder):
    """ManiSkill's actor builder, which also takes convex hulls made from points (``hulls``, `_add_hull`). SAPIEN's
    builder takes hulls only from mesh files, which it caches by path for the life of the process."""

    def __init__(self) -> None:
        super().__init__()
        self.hulls: list = []

    def build_physx_component(self, link_parent=None):
        component = super().build_physx_component(link_parent)
        for shape in self.hulls:
            shape.set_collision_groups(self.collision_groups)
            component.attach(shape)
        return component


def _attach_hull(builder: ObjectBuilder, vertices, pose: sapien.Pose, density: float, physical):
    """The convex hull PhysX makes from ``vertices`` (in the shape's frame, at ``pose`` on the body) as a collision
    shape of ``builder``'s body; returns it."""
    shape = sapien.physx.PhysxCollisionShapeConvexMesh(
        vertices=np.asarray(vertices, dtype=np.float32), scale=np.ones(3, np.float32), material=physical
    )
    shape.local_pose = pose
    shape.set_density(density)
    builder.hulls.append(shape)
    return shape


def _add_hull(builder: ObjectBuilder, part: Part, density: float, physical, mat) -> None:
    """A convex hull PhysX makes from the part's points, and its visual: the hull PhysX made (flat shaded), so what
    is seen is what collides."""
    shape = _attach_hull(builder, part.vertices, sapien.Pose(p=list(part.offset)), density, physical)
    vertices = np.asarray(shape.get_vertices(), dtype=np.float32)
    corners = vertices[np.asarray(shape.get_triangles(), dtype=np.int64)].reshape(-1, 3)
    normal = np.cross(corners[1::3] - corners[0::3], corners[2::3] - corners[0::3])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    triangles = np.arange(len(corners), dtype=np.uint32).reshape(-1, 3)
    normals = np.repeat(normal, 3, axis=0).astype(np.float32)
    uvs = np.zeros((len(corners), 2), np.float32)
    visual = sapien.render.RenderShapeTriangleMesh(corners, triangles, normals, uvs, mat)
    visual.local_pose = sapien.Pose(p=list(part.offset))
    builder._procedural_shapes.append(visual)


def _add_box_collision(builder, half_size, pose: sapien.Pose, box_hulls: bool, density: float = 1000.0, physical=None):
    """A box's collision shape: PhysX's box, or (``box_hulls``, on an `ObjectBuilder`) the convex hull of its eight
    corners, which PhysX's contact generators treat as any convex shape. With persistent contact manifolds on, a
    pair of PhysX boxes meets the one generator that runs approximate-reciprocal instructions, whose results differ
    between CPU makers; without them, PhysX's box-box generator pushes from up to both shapes' contact offsets apart
    (docs/reproducibility.md)."""
    if not box_hulls:
        kw = {"density": density} if physical is None else {"density": density, "material": physical}
        builder.add_box_collision(pose=pose, half_size=list(half_size), **kw)
        return
    corners = _CUBE_CORNERS * np.asarray(half_size, np.float32)
    _attach_hull(builder, corners, pose, density, physical or sapien.physx.get_default_material())


def _add_part(builder, part: Part, density: float, physical, mat, box_hulls: bool = False) -> None:
    """One part's collision shape (of ``density`` and material ``physical``, None: the default) and its visual;
    boxes as convex hulls with ``box_hulls`` (`_add_box_collision`)."""
    pose = sapien.Pose(p=list(part.offset))
    kw = {"density": density} if physical is None else {"density": density, "material": physical}
    s = part.size
    if part.kind == "box":
        _add_box_collision(builder, s, pose, box_hulls, density, physical)
        builder.add_box_visual(pose=pose, half_size=list(s), material=mat)
    elif part.kind == "cylinder":
        pose = sapien.Pose(p=list(part.offset), q=_UPRIGHT)
        builder.add_cylinder_collision(pose=pose, radius=s[0], half_length=s[1], **kw)
        builder.add_cylinder_visual(pose=pose, radius=s[0], half_length=s[1], material=mat)
    elif part.kind == "sphere":
        builder.add_sphere_collision(pose=pose, radius=s[0], **kw)
        builder.add_sphere_visual(pose=pose, radius=s[0], material=mat)
    elif part.kind == "capsule":
        builder.add_capsule_collision(pose=pose, radius=s[0], half_length=s[1], **kw)
        builder.add_capsule_visual(pose=pose, radius=s[0], half_length=s[1], material=mat)
    elif part.kind == "hull":
        _add_hull(builder, part, density, physical or sapien.physx.get_default_material(), mat)
    else:
        raise ValueError(f"unknown part kind {part.kind!r}")


class TabletopEnv(BaseEnv):
    """Table, objects and a fixed head camera around the task's arm (``task_spec.robot_uid``, whose agent
    `tasks.envs` registers); every reset restores start poses."""

    SUPPORTED_ROBOTS: list[str]
    task_spec: TaskSpec

    def __init__(
        self,
        *args,
        robot_uids: str | None = None,
        camera_width: int = 128,
        camera_height: int = 128,
        cameras: tuple | None = None,
        sim_freq: int = 100,
        control_freq: int = 20,
        pcm: bool = False,
        box_hulls: bool = False,
        object_specs: tuple[ObjectSpec, ...] | None = None,
        **kwargs,
    ):
        self.camera_width, self.camera_height = camera_width, camera_height
        self.cameras = tuple(cameras) if cameras else (CAMERA_PRESETS["head"],)
        self._sim_freq, self._control_freq, self._pcm = sim_freq, control_freq, pcm
        self._box_hulls = box_hulls  # the scene's boxes collide as convex hulls (`_add_box_collision`)
        self.objects: dict[str, object] = {}
        # what stands on the table now: the task's objects, or the run's slots (babblegen.objects.slot_task)
        self.object_specs: tuple[ObjectSpec, ...] = tuple(object_specs or self.task_spec.objects)
        self._slot_xy = {o.name: o.xy for o in self.object_specs}  # where a slot's object rests before its start
        super().__init__(*args, robot_uids=robot_uids or self.task_spec.robot_uid, **kwargs)

    @property
    def _default_sim_config(self):
        # SceneConfig's other defaults stay ManiSkill's (TGS, no CCD, contact offset 0.02 m, 15 position iterations)
        return SimConfig(
            sim_freq=self._sim_freq, control_freq=self._control_freq, scene_config=SceneConfig(enable_pcm=self._pcm)
        )

    @property
    def _default_sensor_configs(self):
        configs = []
        for view in self.cameras:
            height = view.height or self.camera_height
            width = view.width or self.camera_width
            mount, fov, near = None, view.fov, 0.05
            if view.mount == "head":
                cam = self.task_spec.camera
                pose, fov = sapien_utils.look_at(eye=list(cam.eye), target=list(cam.target)), cam.fov
            elif view.mount == "fixed":
                pose = sapien_utils.look_at(eye=list(view.eye), target=list(view.target))
            else:  # on the tool link: behind and above the tool point, looking along the gripper and down at it
                mount, near = self.agent.tcp, 0.02
                pose = sapien.Pose(p=WRIST_CAMERA_OFFSET, q=WRIST_CAMERA_TILT)
            configs.append(
                CameraConfig(view.name, pose=pose, width=width, height=height, fov=fov, near=near, far=10, mount=mount)
            )
        return configs

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at([1.9, -1.3, 1.7], [0.55, 0.0, 0.7])
        return CameraConfig("overview", pose=pose, width=512, height=512, fov=0.9, near=0.05, far=10)

    def _load_lighting(self, options: dict):
        # no shadows: on a CPU renderer they cost time and add nothing to the behaviour descriptor
        self.scene.set_ambient_light([0.45, 0.45, 0.45])
        self.scene.add_directional_light([0.3, 0.4, -1.0], [0.8, 0.8, 0.8], shadow=False)

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose())

    def _load_scene(self, options: dict):
        spec = self.task_spec
        t = spec.table
        builder = ObjectBuilder().set_scene(self.scene)
        _add_box_collision(builder, t.half_extents, sapien.Pose(), self._box_hulls)
        builder.add_box_visual(
            half_size=list(t.half_extents),
            material=sapien.render.RenderMaterial(base_color=[0.55, 0.4, 0.28, 1]),
        )
        builder.initial_pose = sapien.Pose(p=list(t.center))
        self.table = builder.build_static(name="table")
        floor = ObjectBuilder().set_scene(self.scene)
        half = [FLOOR_HALF_EXTENT, FLOOR_HALF_EXTENT, 0.01]
        _add_box_collision(floor, half, sapien.Pose(), self._box_hulls)
        floor.add_box_visual(half_size=half, material=sapien.render.RenderMaterial(base_color=[0.8, 0.8, 0.78, 1]))
        floor.initial_pose = sapien.Pose(p=[0, 0, -0.01])
        self.floor = floor.build_static(name="floor")
        self.obstacles = [self._build_obstacle(box) for box in spec.extra_obstacles]
        # a start's own objects (``reset(options={"objects": ...})``, one per slot), else those of the last build
        self.object_specs = tuple(options.get("objects") or self.object_specs)
        self.objects = {obj.name: self._build_object(obj) for obj in self.object_specs}

    def _build_obstacle(self, box: Box):
        """A static box that is also a planning obstacle (TaskSpec.extra_obstacles): walls, shelves."""
        builder = ObjectBuilder().set_scene(self.scene)
        _add_box_collision(builder, box.half_extents, sapien.Pose(), self._box_hulls)
        builder.add_box_visual(
            half_size=list(box.half_extents), material=sapien.render.RenderMaterial(base_color=OBSTACLE_COLOR)
        )
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = np.asarray(box.rotation), np.asarray(box.center)
        builder.initial_pose = sapien.Pose(pose)
        return builder.build_static(name=box.name)

    def _build_object(self, obj: ObjectSpec):
        """One free object from its parts (`ObjectSpec.parts`), all of its density. The paper's objects keep the
        simulator's default material, as they always did; any other gets a material of its own (the default one
        is shared with the table and the robot)."""
        builder = ObjectBuilder().set_scene(self.scene)
        mat = sapien.render.RenderMaterial(base_color=list(obj.color))
        density = obj.mass / obj.volume
        physical = None
        if (obj.static_friction, obj.dynamic_friction, obj.restitution) != DEFAULT_MATERIAL:
            physical = sapien.physx.PhysxMaterial(obj.static_friction, obj.dynamic_friction, obj.restitution)
        for part in obj.parts():
            _add_part(builder, part, density, physical, mat, self._box_hulls)
        rest = self._rest_pose(obj)
        builder.initial_pose = sapien.Pose(p=list(rest[:3]), q=list(rest[3:]))
        return builder.build(name=obj.name)

    def _rest_pose(self, obj: ObjectSpec) -> tuple[float, ...]:
        """The object upright on the table where its slot's object rests in the task (the world then places it)."""
        return self.task_spec.rest_pose(replace(obj, xy=self._slot_xy.get(obj.name, obj.xy)))

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            self.agent.reset(torch.as_tensor(self.agent.keyframes["home"].qpos, dtype=torch.float32)[None])
            for obj in self.object_specs:
                rest = torch.tensor(self._rest_pose(obj), dtype=torch.float32)[None]
                self.objects[obj.name].set_pose(Pose.create_from_pq(p=rest[:, :3], q=rest[:, 3:]))

    def evaluate(self):
        return {}

    def _get_obs_extra(self, info: dict):
        return {}

    def compute_dense_reward(self, obs, action, info):
        return torch.zeros(self.num_envs, device=self.device)

    def compute_normalized_dense_reward(self, obs, action, info):
        return self.compute_dense_reward(obs, action, info)
