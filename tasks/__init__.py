"""Scenes: the PR2-like arm and the tabletop tasks, each registered with ManiSkill and with babblegen."""

from __future__ import annotations

from babblegen.scene import TaskSpec

from . import noveb_tabletop, wall_tabletop  # noqa: F401  (register the scenes)
from .registry import TASKS

DEFAULT_TASK = "noveb_tabletop"


def get_task(name: str) -> TaskSpec:
    """The registered task called `name`; a ValueError lists the valid names otherwise."""
    if name not in TASKS:
        raise ValueError(f"unknown task {name!r}; choose one of: {', '.join(sorted(TASKS))}")
    return TASKS[name]


__all__ = ["DEFAULT_TASK", "TASKS", "get_task"]
