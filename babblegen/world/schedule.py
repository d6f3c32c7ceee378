"""When the arm is where: the control-rate joint targets of a movement (out along its planned path, a dwell, back
home, settling) and the commanded joints each recorded frame holds (the dataset's ``action`` column).

`World.rollout` executes this schedule; a planner that scores movements without simulating them
(`babblegen/worldmodel/planning_cem.py`) calls the same functions, so the two cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from babblegen.world.settings import WorldSettings


def timed_path(path: np.ndarray, settings: WorldSettings) -> np.ndarray:
    """Joint targets at the control rate along a piecewise-linear joint path (n, dof) at ``max_joint_speed`` on the
    fastest joint of each segment."""
    dt = 1.0 / settings.control_freq
    seg = np.abs(np.diff(path, axis=0)).max(axis=1) / settings.max_joint_speed
    t_knots = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.arange(0.0, t_knots[-1] + dt, dt)
    return np.stack([np.interp(t, t_knots, path[:, j]) for j in range(path.shape[1])], axis=1)


def too_long(out: np.ndarray, out_path: np.ndarray, approach: int, settings: WorldSettings) -> bool:
    """Whether the movement out (``out``, timed from ``out_path``) exceeds ``max_move_seconds``: counting all of
    its control steps with ``count_approach``, else those after the first target, which the path reaches at knot
    ``approach``."""
    s = settings
    if not s.max_move_seconds:
        return False
    steps = float(len(out))
    if not s.count_approach:
        approach_s = np.abs(np.diff(out_path[: approach + 1], axis=0)).max(axis=1).sum() / s.max_joint_speed
        steps = len(out) - approach_s * s.control_freq
    return steps > s.max_move_seconds * s.control_freq + 1e-9


def way_home(
    out_path: np.ndarray, home: np.ndarray, settings: WorldSettings, motion_free: Callable[..., bool]
) -> np.ndarray:
    """The joint path from the end of ``out_path`` back home (`WorldSettings.return_home`): straight when
    ``return_home`` is "direct" and ``motion_free(last, home)`` says that segment is free, else the way out
    reversed."""
    if settings.return_home == "direct":
        last = out_path[-1]
        if motion_free(last, home):
            return np.stack([last, home])
    return out_path[::-1]


def frames_per_step(settings: WorldSettings) -> int:
    """Control steps per recorded frame."""
    return settings.control_freq // settings.fps


def movement_schedule(out: np.ndarray, home_path: np.ndarray, home: np.ndarray, settings: WorldSettings) -> np.ndarray:
    """The control-rate targets of a movement: ``out`` (timed), the dwell at its end, the way home along
    ``home_path``, the settling at home, padded with home to a whole frame (the last frame is exactly 1 / fps after
    the one before, as its timestamp says)."""
    s = settings
    dwell = np.repeat(out[-1:], max(int(round(s.dwell_seconds * s.control_freq)), 0), axis=0)
    back = timed_path(home_path, s)
    settle = np.repeat(home[None], max(int(round(s.settle_seconds * s.control_freq)), 1), axis=0)
    schedule = np.concatenate([out, dwell, back, settle])
    return np.concatenate([schedule, np.repeat(home[None], -len(schedule) % frames_per_step(s), axis=0)])


def recorded_actions(schedule: np.ndarray, frames: int, home: np.ndarray, settings: WorldSettings) -> np.ndarray:
    """(frames, dof) float32, the ``action`` column of an episode of ``frames`` frames executing ``schedule``:
    ``action[t]`` is the target in force when frame t + 1 is taken (sent after observing frame t, LeRobot's
    convention); after the last frame the arm holds home."""
    per_frame = frames_per_step(settings)
    picked = [schedule[k * per_frame - 1].astype(np.float32) for k in range(1, frames)]
    return np.stack([*picked, home.astype(np.float32)])


def planned_actions(
    out_path: np.ndarray, home: np.ndarray, settings: WorldSettings, motion_free: Callable[..., bool], approach: int = 1
) -> np.ndarray | None:
    """(T, dof) float32, the ``action`` column `World.rollout` records for a movement along ``out_path`` (home ->
    targets), without the settling it adds while objects still move; None where the movement out is too long."""
    out = timed_path(out_path, settings)
    if too_long(out, out_path, approach, settings):
        return None
    schedule = movement_schedule(out, way_home(out_path, home, settings, motion_free), home, settings)
    return recorded_actions(schedule, len(schedule) // frames_per_step(settings) + 1, home, settings)
