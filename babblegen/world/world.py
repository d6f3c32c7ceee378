"""The simulated world: turns a command into an executed, recorded trajectory (or a reason it was not).

One `World` owns a ManiSkill env (SAPIEN physics + CPU rendering) and an `ArmPlanner` (`planning.py`: IK and
collision-free joint paths). A rollout: plan, reset the scene, execute the path out and back under the joint
position controller, let the scene settle, and record frames at a fixed rate.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Iterator

import gymnasium as gym
import numpy as np
import sapien
import torch

from babblegen.objects import slot_task
from babblegen.scene import TaskSpec, layout_poses
from babblegen.shapes import ObjectSpec
from babblegen.tasks import get_robot
from babblegen.world.cameras import CameraRig
from babblegen.world.contacts import ContactReader
from babblegen.world.exact import row_norm
from babblegen.world.planning import ArmPlanner, Plan
from babblegen.world.rollout import Command, Frames, Rollout
from babblegen.world.schedule import (
    frames_per_step,
    movement_schedule,
    recorded_actions,
    timed_path,
    too_long,
    way_home,
)
from babblegen.world.settings import WorldSettings


class World:
    """Executes commands in a task's scene. Not thread-safe: one World per process."""

    def __init__(self, task: TaskSpec, settings: WorldSettings | None = None, seed: int = 0):
        from babblegen.tasks import envs  # ManiSkill: loaded with the first World, not with this module's users

        envs.register_envs()  # the agents, and an env for every registered scene
        self.robot = robot = get_robot(task.robot_uid)

        self.settings = s = (settings or WorldSettings()).for_task(task)
        # with drawn objects, the task's table and camera with the run's object slots (babblegen.objects)
        self.task = task = slot_task(task, s.objects, s.num_objects)
        self.rng = np.random.default_rng(seed)
        self.env = gym.make(
            task.env_id,
            obs_mode="none",
            sim_backend="physx_cpu",
            render_backend="cpu",
            control_mode="pd_joint_pos",
            camera_width=s.camera_width,
            camera_height=s.camera_height,
            cameras=s.cameras,
            sim_freq=s.sim_freq,
            control_freq=s.control_freq,
            pcm=s.pcm,
            box_hulls=s.box_hulls,
            object_specs=task.objects,
        )
        self.env.reset(seed=seed)
        self.sim = self.env.unwrapped
        self.agent = self.sim.agent
        self.home = np.asarray(self.agent.keyframes["home"].qpos, dtype=np.float64)

        self.planning = ArmPlanner(task, robot, self.home, s)
        # its parts, under the names the rest of the code uses
        self.kin, self.collision, self.planner = self.planning.kin, self.planning.collision, self.planning.joint_planner
        self.reach = self.planning.reach

        self.object_names = task.object_names
        self.scene_objects = task.objects  # what the scene holds now (`reset`)
        self._bind_scene()
        self.start_poses = self._object_poses()

    def _bind_scene(self) -> None:
        """Handles on the simulated scene's objects, arm and camera (again after the scene is rebuilt)."""
        self.agent = self.sim.agent
        self._object_entities = [self.sim.objects[n]._objs[0] for n in self.object_names]
        self._object_bodies = [
            e.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent) for e in self._object_entities
        ]
        self._arm = self.agent.robot._objs[0]
        self._tool = next(link for link in self._arm.links if link.entity.name == self.robot.tool_link)
        static = sapien.physx.PhysxRigidStaticComponent
        statics = [a._objs[0].find_component_by_type(static) for a in (self.sim.table, self.sim.floor)]
        arm_bodies = {link for link in self._arm.links if link.entity.name != self.robot.base_link}
        self._contacts = ContactReader(self.sim, arm_bodies, self._object_bodies, statics)  # read every substep
        self._drive_joints = self._position_drives()
        self._camera = self.sim.scene.sensors["head"]
        self.cameras = CameraRig(self.sim, self.task, self.settings.cameras)
        self._others = [v.name for v in self.settings.cameras if v.name != "head"]
        self._moving = [v.name for v in self.settings.cameras if v.mount == "wrist"]

    def _position_drives(self) -> list | None:
        """The simulator's joints that the agent's joint-position controller drives, in the order of its action,
        or None if the controller does more than set each joint's drive target to its action (then every
        control step goes through ManiSkill's controller)."""
        from mani_skill.agents.controllers import PDJointPosController

        controller = self.agent.controller
        parts = list(getattr(controller, "controllers", {"": controller}).values())
        joints = []
        for part in parts:
            cfg = getattr(part, "config", None)
            plain = type(part) is PDJointPosController and not (
                cfg.interpolate or cfg.use_delta or cfg.normalize_action
            )
            if not plain:
                return None
            joints += [joint._objs[0] for joint in part.joints]
        return joints if len(joints) == self.kin.dof else None

    def _drive(self, target: np.ndarray) -> None:
        """Send one control step's joint targets. With a plain joint-position controller this is what ManiSkill's
        ``set_action`` does on the CPU backend, minus its tensor bookkeeping: each joint's drive target set to
        the float32 target (20 us of a 70 us physics substep, for the same simulation, bit for bit:
        ``tests/test_world.py``); its ``before_simulation_step`` does nothing for such a controller."""
        if self._drive_joints is None:
            self.agent.set_action(torch.as_tensor(target, dtype=torch.float32)[None])
            self.agent.before_simulation_step()
            return
        values = np.asarray(target, dtype=np.float32)
        if np.isnan(values).any():
            raise ValueError(f"joint targets must not be NaN, got {values}")
        for joint, value in zip(self._drive_joints, values.tolist(), strict=True):
            joint.set_drive_target(value)

    # --- planning (`ArmPlanner`) ---------------------------------------------------------------------------
    @property
    def start_norm(self) -> np.ndarray:
        """The home tool position in normalised workspace coordinates (the start of every trajectory)."""
        return self.planning.start_norm

    def shoulder_distance(self, points: np.ndarray) -> np.ndarray:
        """`ArmPlanner.shoulder_distance`: beyond `reach`, no configuration gets the tool there."""
        return self.planning.shoulder_distance(points)

    def solve_ik(self, target: np.ndarray, seed_q: np.ndarray) -> tuple[np.ndarray | None, str]:
        """`ArmPlanner.solve_ik`: a collision-free configuration reaching `target`, near `seed_q`."""
        return self.planning.solve_ik(target, seed_q)

    def plan_command(self, command: Command) -> Plan:
        """`ArmPlanner.plan_command`: joint path home -> targets (not yet back), or the reason it does not exist."""
        return self.planning.plan_command(command)

    # --- simulation ---------------------------------------------------------------------------------------
    def _object_poses(self) -> np.ndarray:
        return np.array([np.concatenate([e.pose.p, e.pose.q]) for e in self._object_entities])

    def _at_rest(self) -> bool:
        v = self.settings.rest_speed
        return all(
            row_norm(b.linear_velocity) < v and row_norm(b.angular_velocity) < 10 * v for b in self._object_bodies
        )

    def warm_up(self) -> None:
        """Render one frame: the first one compiles the renderer's shaders (about 9 s on lavapipe). Then leave
        every Python object alive so far (the simulator, the libraries: millions of them) out of garbage
        collection. Each rollout rebuilds the scene (`reset`), and the objects that creates set off full
        collections that would otherwise walk all of those every time: 0.14 s of a 0.17 s reset, a third of
        a typical rollout (``benchmarks/bench_pipeline.py`` shows the reset's share)."""
        self._render_views(self._others, head=True)  # every camera and kind once
        gc.freeze()

    def _render(self) -> np.ndarray:
        """The head camera's colour image of the scene as it is now."""
        return self._render_views([], head=True)["head"]["rgb"]

    def _render_views(self, names: list[str], head: bool) -> dict[str, dict[str, np.ndarray]]:
        """Every named camera's images (the head camera's too with ``head``) of the scene as it is now."""
        self.sim.scene.update_render()
        names = (["head"] if head else []) + names
        self.cameras.capture(names)
        return {name: self.cameras.read(name) for name in names}

    def _touching(self) -> np.ndarray:
        """Which objects the arm touches now, each recorded pair's impulse added up meanwhile
        (`ContactReader.touching`)."""
        return self._contacts.touching()

    def _timed_path(self, path: np.ndarray) -> np.ndarray:
        """Joint targets at the control rate along a piecewise-linear path at max_joint_speed."""
        return timed_path(path, self.settings)

    def reset(self, start: np.ndarray | None = None, objects: tuple[ObjectSpec, ...] | None = None) -> None:
        """Robot at home, every object at its start pose (the task's, or the varied start ``start``: (n_objects,
        3) x, y, yaw, resting on the table, or (n_objects, 7) whole poses of a scene an earlier movement made; not
        settled yet: `settle_start`), with no physical memory of earlier rollouts: the scene is rebuilt, with the
        start's own ``objects`` in the slots when it drew them (else the task's).

        Setting poses and velocities is not enough. PhysX keeps state that no API shows (contact pair order,
        friction anchors, broadphase structures), so after other contact-rich rollouts the same command could
        end up to 60 cm differently (measured: 4 of 180 re-runs of 30 contact genomes differed, even with
        every object taken out of the scene for a step and the arm's velocities, accelerations and forces
        zeroed). A rebuilt scene makes the outcome a function of the command alone (0 of 180), for about
        0.1 s per rollout.
        """
        if objects is not None and [o.name for o in objects] != self.object_names:
            raise ValueError(f"a start's objects fill the slots {self.object_names}, got {[o.name for o in objects]}")
        self.scene_objects = objects or self.task.objects
        self.env.reset(options={"reconfigure": True, "objects": self.scene_objects})
        self._bind_scene()
        if start is not None:
            start = np.asarray(start, dtype=np.float64)
            # a made start's whole poses, or a layout resting on the table
            poses = start if start.shape[1] == 7 else layout_poses(self.task, start, objects)
            for entity, pose in zip(self._object_entities, poses, strict=True):
                entity.set_pose(sapien.Pose(pose[:3], pose[3:]))

    def settle_start(self) -> str:
        """Let a varied start come to rest with the arm held at home, before its first frame: at least 0.1 s, then
        until every object is at rest, at most ``start_settle_seconds``. Returns "" when it did and every object
        is still on the table, else the reason the start is not used (a key of ``REASONS``)."""
        s = self.settings
        px, substeps = self.sim.scene.px, s.sim_freq // s.control_freq
        least = max(1, s.control_freq // 10)
        self._drive(self.home)
        for step in range(max(int(round(s.start_settle_seconds * s.control_freq)), least)):
            for substep in range(substeps):
                if substep and self._drive_joints is None:
                    self.agent.before_simulation_step()
                px.step()
            if step + 1 >= least and self._at_rest():
                break
        else:
            return "start_not_at_rest"
        t = self.task.table
        poses = self._object_poses()
        inside = np.all(np.abs(poses[:, :2] - np.asarray(t.center[:2])) <= np.asarray(t.half_extents[:2]), axis=1)
        if not np.all(inside & (poses[:, 2] > self.task.table_top)):
            return "start_off_table"
        return ""

    def rollout(self, command: Command, defer_render: bool = False) -> Rollout:
        """Plan and, if feasible, execute and record one command. The scene is reset first.

        The first and last frames are rendered during the movement (the last is the behaviour image); the
        others after it, from their recorded joint positions and object poses (`render_frames`). Rendering a
        frame from its recorded state rather than from the live simulation makes its pixels a function of what
        the episode records, wherever and whenever it is rendered: with ``defer_render`` they are left to the
        caller (``frames.images`` is None, ``frames.end_images`` holds the two). Rendering is half of a typical
        rollout; a worker that defers it returns the movement sooner and renders when it would otherwise wait
        for the others."""
        t_start = time.perf_counter()
        out_path, reason, targets, planner, timings, approach = self.plan_command(command)
        if out_path is None:
            timings["total"] = time.perf_counter() - t_start
            return Rollout(command, False, reason, ee_targets=targets, timings=timings)
        s = self.settings
        out = self._timed_path(out_path)
        if too_long(out, out_path, approach, s):
            timings["total"] = time.perf_counter() - t_start
            return Rollout(command, False, "too_long", ee_targets=targets, timings=timings)
        home_path = way_home(
            out_path, self.home, s, lambda a, b: self.planner.model.motion_free(a, b, self.planner.resolution)
        )
        schedule = movement_schedule(out, home_path, self.home, s)
        per_frame = frames_per_step(s)
        extra_settle = max(int(round((s.max_settle_seconds - s.settle_seconds) * s.fps)), 0) * per_frame

        t_reset = time.perf_counter()
        self.reset(command.start, command.objects)
        not_used = self.settle_start() if command.start is not None else ""
        timings["reset"] = time.perf_counter() - t_reset
        if not_used:
            timings["total"] = time.perf_counter() - t_start
            return Rollout(command, False, not_used, ee_targets=targets, timings=timings)
        start = self._object_poses()  # displacements are measured from the episode's own start
        substeps = s.sim_freq // s.control_freq
        keys = ("state", "action", "ee_pos", "object_poses", "contacts", "object_contacts", "images", "time")
        rec = {k: [] for k in keys}
        t_sim = t_render = 0.0
        touched_since = np.zeros(len(self._object_entities), dtype=bool)

        head_ends: list[dict[str, np.ndarray]] = []

        def record(step: int, render: bool = False) -> None:
            nonlocal t_render, touched_since
            if render:
                t0 = time.perf_counter()
                head_ends.append(self._render_views([], head=True)["head"])  # with its depth and ids, if recorded
                rec["images"].append(head_ends[-1].pop("rgb"))
                t_render += time.perf_counter() - t0
            rec["state"].append(np.asarray(self._arm.qpos, dtype=np.float32))
            rec["time"].append(step / s.control_freq)
            rec["ee_pos"].append(np.asarray(self._tool.entity_pose.p, dtype=np.float32))
            rec["object_poses"].append(self._object_poses().astype(np.float32))
            rec["contacts"].append(touched_since.astype(np.float32))
            touched_since = np.zeros_like(touched_since)
            rec["object_contacts"].append(self._contacts.take_impulses())

        self._contacts.take_impulses()  # counted from the first frame
        record(0, render=True)
        px = self.sim.scene.px
        touched_any = np.zeros_like(touched_since)
        t0 = time.perf_counter()
        i, n = 0, len(schedule)
        while i < n:
            target = schedule[i]
            i += 1
            self._drive(target)
            for substep in range(substeps):
                if substep and self._drive_joints is None:
                    self.agent.before_simulation_step()
                px.step()
                touching = self._touching()
                touched_since |= touching
                touched_any |= touching
            if i == n and extra_settle > 0 and not self._at_rest():
                # keep settling, one frame at a time, while something still moves (a rolling can, a falling box)
                schedule = np.concatenate([schedule, np.repeat(self.home[None], per_frame, axis=0)])
                n, extra_settle = n + per_frame, extra_settle - per_frame
            if i % per_frame == 0 and i < n:
                t_sim += time.perf_counter() - t0
                record(i)
                t0 = time.perf_counter()
        # The behaviour image is taken with the arm exactly at home, so only the scene's change shows.
        self._arm.qpos = self.home
        self._arm.qvel = np.zeros(self.kin.dof)
        t_sim += time.perf_counter() - t0
        record(n, render=True)
        rec["action"] = list(recorded_actions(schedule, len(rec["state"]), self.home, s))

        ends = np.stack(rec.pop("images"))
        frames = Frames(**{k: np.stack(v) for k, v in rec.items()}, images=None, end_images=ends)
        frames.objects = command.objects
        if head_ends[0]:
            frames.end_views = {k: np.stack([e[k] for e in head_ends]) for k in head_ends[0]}
        if not defer_render:
            t_render += self.render_frames(frames)
        final = frames.object_poses[-1].astype(np.float64)
        timings.update(sim=t_sim, render=t_render, total=time.perf_counter() - t_start)
        return Rollout(
            command,
            True,
            ee_targets=targets,
            joint_path=np.concatenate([out_path, home_path[1:]]),
            planner=planner,
            frames=frames,
            touched=touched_any,
            displacement=row_norm(final[:, :3] - start[:, :3]),
            final_poses=final,
            start_poses=start,
            timings=timings,
        )

    def render_frames(self, frames: Frames) -> float:
        """Fill in ``frames.images`` of a rollout made with ``defer_render`` (by this World or another): each
        frame between the first and last is rendered from its recorded joint positions and object poses. Leaves
        the arm and objects where the last frame recorded them. Returns the seconds spent."""
        t0 = time.perf_counter()
        for _ in self.render_frames_stepwise(frames):
            pass
        return time.perf_counter() - t0

    def render_frames_stepwise(self, frames: Frames, frames_per_step: int = 4) -> Iterator[None]:
        """`render_frames` a few frames at a time, pausing (``yield``) after each few: the World may run other
        rollouts in the pauses, since each frame is rendered from its own recorded state. The head camera's
        first and last frames are the ones rendered with the movement; every other camera renders every frame
        here, and a moving one records where it was (``frames.camera_poses``)."""
        if frames.images is not None:
            return
        n = len(frames)
        head = [{"rgb": frames.end_images[0], **{k: v[0] for k, v in (frames.end_views or {}).items()}}]
        others: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name in self._others}
        poses: dict[str, list[np.ndarray]] = {name: [] for name in self._moving}
        for t in range(n):
            inside = 0 < t < n - 1
            if not inside and not self._others:
                continue
            self._hold_objects(frames.objects)  # again after every pause: a rollout in it rebuilt the scene
            self._pose_scene(frames, t)
            images = self._render_views(self._others, head=inside)
            if inside:
                head.append(images.pop("head"))
            for name, got in images.items():
                others[name].append(got)
            for name in self._moving:
                poses[name].append(self.cameras.parameters(name)["cam2world"])
            if inside and t % frames_per_step == 0:
                yield
        head.append({"rgb": frames.end_images[-1], **{k: v[-1] for k, v in (frames.end_views or {}).items()}})
        frames.images, frames.end_images = np.stack([h.pop("rgb") for h in head]), None
        views = {name: {k: np.stack([f[k] for f in got]) for k in got[0]} for name, got in others.items() if got}
        if head[0]:
            views["head"] = {k: np.stack([h[k] for h in head]) for k in head[0]}
        frames.views, frames.end_views = views or None, None
        frames.camera_poses = {name: np.stack(p) for name, p in poses.items()} or None
        self._pose_scene(frames, n - 1)

    def _hold_objects(self, objects: tuple[ObjectSpec, ...] | None) -> None:
        """The scene rebuilt with ``objects`` (None: the task's) unless it holds them already: an episode is
        rendered in a scene of its own objects, wherever and after whatever it is rendered."""
        wanted = objects or self.task.objects
        if wanted != self.scene_objects:
            self.reset(None, objects)

    def _pose_scene(self, frames: Frames, t: int) -> None:
        """Put the arm and the objects where frame ``t`` recorded them."""
        self._arm.qpos = frames.state[t]
        for entity, pose in zip(self._object_entities, frames.object_poses[t], strict=True):
            entity.set_pose(sapien.Pose(pose[:3], pose[3:]))

    def rollout_batch(self, commands: list[Command]) -> list[Rollout]:
        """Several commands, in order (the interface a batched GPU backend would implement at once)."""
        return [self.rollout(c) for c in commands]

    def close(self) -> None:
        self.env.close()
        gc.unfreeze()  # collectable again, so the bindings find nothing left alive at exit
