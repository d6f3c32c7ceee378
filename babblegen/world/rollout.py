"""What one attempted movement produced: the command, whether it was feasible, and what was recorded."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

# Why an attempt was not executed.
REASONS = {
    "out_of_reach": "a target is farther from the shoulder than the arm can reach",
    "no_ik": "inverse kinematics found no joint configuration for a target",
    "target_in_collision": "every configuration reaching a target collides with the table, floor or robot",
    "no_plan": "the planner found no collision-free path in its time limit",
    "too_long": "the movement out would take longer than max_move_seconds at the arm's speed",
    "start_not_at_rest": "the drawn start's objects were still moving when its settling time ran out",
    "start_off_table": "an object of the drawn start left the table while it settled",
}


@dataclass
class Command:
    """What the arm is asked to do: end-effector waypoints (normalised workspace coordinates) or one
    joint-space target (radians)."""

    kind: str  # "ee_waypoints" or "joint_target"
    values: np.ndarray  # (n, 3) or (dof,)
    # a varied start (babblegen.starts): (n_objects, 3) x, y, yaw, or (n_objects, 7) whole poses of a made start;
    # None: the task's
    start: np.ndarray | None = None
    # the start's own objects, one per slot, when its object set draws them (babblegen.objects); None: the task's
    objects: tuple | None = None


@dataclass
class Frames:
    """Per-frame recordings, frame 0 is the scene before the movement and the last frame after it."""

    state: np.ndarray  # (T, dof) joint positions
    action: np.ndarray  # (T, dof) joint targets sent after frame t (LeRobot's convention: they lead to t + 1)
    ee_pos: np.ndarray  # (T, 3) tool point, world frame
    object_poses: np.ndarray  # (T, n_objects, 7) x, y, z, qw, qx, qy, qz
    contacts: np.ndarray  # (T, n_objects) 1 where the arm touched that object since the previous frame
    images: np.ndarray | None  # (T, H, W, 3) uint8 head camera; None until rendered when rendering is deferred
    time: np.ndarray | None = None  # (T,) simulated seconds since the movement began; t / fps by construction
    # (2, H, W, 3): frames 0 and T - 1, rendered with the movement when the others are deferred (`World.rollout`)
    end_images: np.ndarray | None = None
    # every other image of the episode, by camera and kind, once rendered: "head" -> {"depth": (T, H, W) uint16 mm,
    # "segmentation": (T, H, W) uint8 instance ids}, "<other>" -> {"rgb": (T, H, W, 3) uint8, "depth", ...}
    views: dict[str, dict[str, np.ndarray]] | None = None
    # the head camera's depth and ids at frames 0 and T - 1, rendered with the movement (as ``end_images``)
    end_views: dict[str, np.ndarray] | None = None
    # (T, 4, 4) OpenCV cam2world per frame of each camera that moves (a wrist camera)
    camera_poses: dict[str, np.ndarray] | None = None
    # the objects the episode ran with, when its start drew them (None: the task's): what its frames are rendered of
    objects: tuple | None = None
    # (T, n_pairs) N s: each pair's summed contact impulse since the previous frame (frame 0: zeros), the pairs of
    # `babblegen.contact_events.contact_pairs` (every two objects, each object with the table, with the floor)
    object_contacts: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.state)


@dataclass
class Rollout:
    command: Command
    feasible: bool
    reason: str = ""  # a key of REASONS when infeasible
    ee_targets: np.ndarray | None = None  # (n, 3) world targets, for waypoint commands
    joint_path: np.ndarray | None = None  # (m, dof) planned joint waypoints, out and back
    planner: str = ""  # how the path was found: "direct", "rrtconnect" (for any segment)
    frames: Frames | None = None
    touched: np.ndarray | None = None  # (n_objects,) bool: the arm touched the object at some point
    displacement: np.ndarray | None = None  # (n_objects,) metres between the episode's start and final position
    start_poses: np.ndarray | None = None  # (n_objects, 7) the objects at the first frame (a varied start, settled)
    final_poses: np.ndarray | None = None  # (n_objects, 7)
    timings: dict[str, float] = field(default_factory=dict)  # seconds: ik, plan, sim, render, total
    prepared: dict[str, Any] = field(default_factory=dict)  # sink name -> what it needs, made where the rollout ran
    code: np.ndarray | None = None  # behaviour descriptor of the after image, computed where the rollout ran

    @property
    def before_image(self) -> np.ndarray | None:
        return self._end_image(0)

    @property
    def after_image(self) -> np.ndarray | None:
        return self._end_image(-1)

    def _end_image(self, end: int) -> np.ndarray | None:
        if self.frames is None:
            return None
        return (self.frames.images if self.frames.images is not None else self.frames.end_images)[end]
