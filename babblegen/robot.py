"""What babblegen needs to know about a robot arm, importable without the simulator."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class RobotSpec:
    """An arm: its URDF, the kinematic chain babblegen moves, its home pose and the collision exemptions of
    its planning model. ``register_agent`` builds and registers its ManiSkill agent class (called once, when
    the simulator is loaded); the agent's ``uid`` must equal ``uid``.

    The World's reach test assumes the chain's first two joints are a shoulder pan and a shoulder lift.
    """

    uid: str
    urdf: Path
    base_link: str
    tool_link: str
    joints: tuple[str, ...]
    home_qpos: tuple[float, ...]
    register_agent: Callable[[], Any] = field(compare=False, repr=False)
    body_exempt_links: tuple[str, ...] = ()  # links allowed to touch the robot's own base (the shoulder)
    self_exempt_pairs: tuple[tuple[str, str], ...] = ()  # link pairs allowed to touch each other

    def __post_init__(self) -> None:
        if len(self.home_qpos) != len(self.joints):
            raise ValueError(f"{self.uid}: home_qpos has {len(self.home_qpos)} values for {len(self.joints)} joints")

    def to_dict(self) -> dict[str, Any]:
        """The description stored in run.json (the viewer and the report read the arm from it)."""
        return {
            "uid": self.uid,
            "urdf": self.urdf.name,
            "base_link": self.base_link,
            "tool_link": self.tool_link,
            "joints": list(self.joints),
            "home_qpos": list(self.home_qpos),
        }
