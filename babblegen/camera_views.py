"""The cameras a run can record: `CameraView` (where a camera stands or rides, what it sees, which images it gives)
and the presets ``--cameras`` names. Plain data, importable without the simulator: the settings hold the run's views
(`babblegen.world.settings.WorldSettings.cameras`), and the tasks' env mounts them (`babblegen.tasks.tabletop`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

MAX_CAMERA_SIDE = 2048  # pixels: larger frames exhaust the CPU renderer and the video encoder
MOUNTS = ("head", "fixed", "wrist")


class CameraSize(Protocol):
    """The run's camera size (`babblegen.world.settings.WorldSettings`): a view's own sides default to it."""

    camera_width: int
    camera_height: int


@dataclass(frozen=True)
class CameraView:
    """One camera a run records. ``mount``: ``"head"`` is the task's head camera, the behaviour camera whose
    last frame the search hashes (always recorded, under the name ``head``); ``"fixed"`` stands at ``eye``
    looking at ``target`` (world frame, metres); ``"wrist"`` rides on the tool link, looking along the gripper,
    so its extrinsics change every frame. ``width`` and ``height`` default to the run's camera size; ``fov`` is
    the vertical field of view (radians). ``depth`` and ``segmentation`` add those images to its colour ones."""

    name: str
    mount: str = "fixed"
    eye: tuple[float, float, float] | None = None
    target: tuple[float, float, float] | None = None
    fov: float = 1.0
    width: int | None = None
    height: int | None = None
    depth: bool = False
    segmentation: bool = False

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"a camera name must be a plain identifier (letters, digits, _), got {self.name!r}")
        if self.mount not in MOUNTS:
            raise ValueError(f"camera {self.name!r}: unknown mount {self.mount!r}; choose one of {', '.join(MOUNTS)}")
        if (self.mount == "head") != (self.name == "head"):
            raise ValueError("the camera named 'head' is the task's head camera (mount 'head'), and only it")
        if self.mount == "fixed":
            if self.eye is None or self.target is None:
                raise ValueError(f"fixed camera {self.name!r} needs an eye and a target (x, y, z in metres)")
            object.__setattr__(self, "eye", tuple(float(v) for v in self.eye))
            object.__setattr__(self, "target", tuple(float(v) for v in self.target))
            if len(self.eye) != 3 or len(self.target) != 3 or self.eye == self.target:
                raise ValueError(f"camera {self.name!r}: eye and target must be two different (x, y, z) points")
        if not 0.05 < float(self.fov) < 3.0:
            raise ValueError(f"camera {self.name!r}: fov must be in (0.05, 3.0) radians, got {self.fov}")
        for side in (self.width, self.height):
            if side is not None and not 16 <= side <= MAX_CAMERA_SIDE:
                raise ValueError(f"camera {self.name!r}: sides must be 16 to {MAX_CAMERA_SIDE} pixels, got {side}")

    def size(self, settings: CameraSize) -> tuple[int, int]:
        """(height, width) in pixels."""
        return (self.height or settings.camera_height, self.width or settings.camera_width)


# The cameras `--cameras` names. "front" faces the robot across the table from above its far edge, and sees the
# table top, the arm and the floor where objects land in front of and beside the table.
CAMERA_PRESETS: dict[str, CameraView] = {
    "head": CameraView("head", mount="head"),
    "front": CameraView("front", eye=(1.75, -0.1, 1.45), target=(0.75, -0.1, 0.62), fov=1.05),
    "side": CameraView("side", eye=(0.75, -1.65, 1.35), target=(0.75, -0.1, 0.62), fov=1.05),
    "wrist": CameraView("wrist", mount="wrist", fov=1.4),
}
