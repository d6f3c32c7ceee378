"""Scene registry: task name -> TaskSpec. A scene module calls `register_task` at import."""

from __future__ import annotations

from babblegen.scene import TaskSpec

TASKS: dict[str, TaskSpec] = {}


def register_task(spec: TaskSpec) -> TaskSpec:
    if spec.name in TASKS:
        raise ValueError(f"task {spec.name!r} is already registered")
    TASKS[spec.name] = spec
    return spec
