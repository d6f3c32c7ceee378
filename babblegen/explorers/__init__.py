"""Explorers: NovEB and the random motor babbling control, behind one ask/tell interface."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import is_dataclass
from typing import Any

import numpy as np

from babblegen.explorers.base import Candidate, Evaluation, Explorer
from babblegen.explorers.noveb import NovEB, NovEBConfig
from babblegen.explorers.random_babbling import (
    RandomBabbling,
    RandomBabblingConfig,
    RandomWaypoints,
    RandomWaypointsConfig,
)

__all__ = [
    "EXPLORERS",
    "Candidate",
    "Evaluation",
    "Explorer",
    "NovEB",
    "NovEBConfig",
    "RandomBabbling",
    "RandomBabblingConfig",
    "RandomWaypoints",
    "RandomWaypointsConfig",
    "make_explorer",
]

EXPLORERS: dict[str, type[Explorer]] = {
    "noveb": NovEB,
    "random": RandomBabbling,
    "random_waypoints": RandomWaypoints,
}


def make_explorer(
    name: str,
    config: Any = None,
    rng_seed: int = 0,
    joint_limits: np.ndarray | None = None,
    start_norm: np.ndarray | None = None,
    starts: Any = None,
    in_reach: Callable[[np.ndarray], bool] | None = None,
) -> Explorer:
    """Build a registered explorer.

    ``config`` is ``None`` (defaults), a dict of options, or the explorer's config dataclass. NovEB needs
    ``start_norm`` (the start pose in normalised workspace coordinates), random babbling ``joint_limits``
    (``(7, 2)`` radians); each ignores the other. ``starts`` (a `babblegen.starts.StartSampler`) draws varied
    starts; None runs every attempt from the task's fixed scene. ``in_reach`` (NovEB's ``reach_redraws``) tells
    whether a normalised waypoint is within the arm's reach.
    """
    try:
        cls = EXPLORERS[name]
    except KeyError:
        raise ValueError(f"unknown explorer {name!r}; known: {sorted(EXPLORERS)}") from None
    if config is not None and not isinstance(config, dict) and not is_dataclass(config):
        raise TypeError(f"config must be None, a dict or a config dataclass, got {type(config).__name__}")
    if cls is NovEB and start_norm is None:
        raise ValueError("explorer 'noveb' needs start_norm")
    if issubclass(cls, RandomBabbling) and joint_limits is None:
        raise ValueError(f"explorer {name!r} needs joint_limits")
    extra = {"in_reach": in_reach} if cls is NovEB else {}
    return cls(config, rng_seed, joint_limits=joint_limits, start_norm=start_norm, starts=starts, **extra)  # type: ignore[call-arg]
