"""ManiSkill environments for the registered scenes. Importing this module (SAPIEN, ManiSkill, torch) registers
every registered robot's agent and, for every task, a `TabletopEnv` subclass carrying its spec under the
task's `env_id`, so that `gym.make(env_id)` builds it. The specs themselves (`babblegen.tasks`) import
without it."""

from __future__ import annotations

from mani_skill.utils.registration import register_env

from .registry import ROBOTS, TASKS
from .tabletop import TabletopEnv

ENV_CLASSES: dict[str, type[TabletopEnv]] = {}


def register_envs() -> dict[str, type[TabletopEnv]]:
    """Register an env for each task not registered yet (scenes registered after this module was imported
    included); returns env id -> env class."""
    for robot in ROBOTS.values():
        robot.register_agent()
    for spec in TASKS.values():
        if spec.env_id not in ENV_CLASSES:
            name = "".join(ch for ch in spec.env_id.split("-")[0] if ch.isalnum()) + "Env"
            body = {
                "task_spec": spec,
                "SUPPORTED_ROBOTS": [spec.robot_uid],
                "__module__": __name__,
                "__doc__": spec.description,
            }
            cls = type(name, (TabletopEnv,), body)
            ENV_CLASSES[spec.env_id] = register_env(spec.env_id, max_episode_steps=100_000)(cls)
    return ENV_CLASSES


register_envs()
