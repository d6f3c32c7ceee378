"""The arm as the world models see it: its joints predicted from the commands alone (`ArmFilter`), and the
collision spheres of those joints (`ArmSpheres`, the planner's model of its links)."""

from __future__ import annotations

import numpy as np

from babblegen.tasks import get_robot
from babblegen.world.collision import SphereCollisionModel
from babblegen.world.kinematics import ArmKinematics, UrdfModel


class ArmFilter:
    """Per joint j: ``s[t+1] - s[t] = c0 (a[t] - s[t]) + c1 (s[t] - s[t-1]) + c2 (a[t-1] - s[t])``, where ``a`` is
    the commanded target and ``s`` the joint; fitted by least squares, run from the first frame's joints. The joint
    controller lags its targets by about two frames; the filter predicts the arm's joints from the commands alone to
    about a millimetre at the tool."""

    def __init__(self, coef: np.ndarray):
        self.coef = np.asarray(coef, dtype=np.float64)  # (7, 3)

    @staticmethod
    def _terms(a: np.ndarray, s: np.ndarray, s_prev: np.ndarray, a_prev: np.ndarray) -> np.ndarray:
        return np.stack([a - s, s - s_prev, a_prev - s], axis=-1)

    @classmethod
    def fit(cls, actions: list[np.ndarray], states: list[np.ndarray]) -> ArmFilter:
        terms, steps = [], []
        for a, s in zip(actions, states, strict=True):
            s_prev = np.vstack([s[:1], s[:-2]])
            a_prev = np.vstack([s[:1], a[:-2]])
            terms.append(cls._terms(a[:-1], s[:-1], s_prev, a_prev))
            steps.append(s[1:] - s[:-1])
        x, y = np.concatenate(terms), np.concatenate(steps)
        return cls(np.stack([np.linalg.lstsq(x[:, j], y[:, j], rcond=None)[0] for j in range(x.shape[1])]))

    def run(self, actions: np.ndarray, first: np.ndarray) -> np.ndarray:
        """(..., T, 7) predicted joints for commands (..., T, 7), starting at ``first`` (..., 7)."""
        actions = np.asarray(actions, dtype=np.float64)
        out = np.empty_like(actions)
        out[..., 0, :] = s_prev = a_prev = first
        for t in range(actions.shape[-2] - 1):
            s = out[..., t, :]
            out[..., t + 1, :] = s + (self._terms(actions[..., t, :], s, s_prev, a_prev) * self.coef).sum(-1)
            s_prev, a_prev = s, actions[..., t, :]
        return out


class ArmSpheres:
    """The arm's collision spheres (the planner's model of its links) for joint configurations."""

    def __init__(self, robot_uid: str):
        robot = get_robot(robot_uid)
        self.model = SphereCollisionModel(
            ArmKinematics(UrdfModel.load(robot.urdf), robot.base_link, robot.tool_link), []
        )
        self.radii = self.model.radii

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """(T, S, 3) sphere centres, world frame."""
        return self.model.sphere_centres(np.asarray(q, dtype=np.float64))

    def paths(self, arm: ArmFilter, actions: list[np.ndarray], joints0: list[np.ndarray], horizon: int) -> np.ndarray:
        """(E, horizon, S, 3) the spheres along each episode's predicted joints (held at the last frame's beyond
        its end)."""
        padded = np.stack([np.vstack([a, np.repeat(a[-1:], horizon - len(a), axis=0)]) for a in actions])
        q = arm.run(padded, np.stack(joints0))  # (E, horizon, 7)
        for i, a in enumerate(actions):  # held at the last frame's joints beyond the episode's end
            q[i, len(a) :] = q[i, len(a) - 1]
        return self(q.reshape(-1, q.shape[-1])).reshape(len(actions), horizon, len(self.radii), 3)
