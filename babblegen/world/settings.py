"""Simulation, rendering and planning settings: a plain dataclass, importable without the simulator."""

from __future__ import annotations

from dataclasses import asdict, dataclass

MAX_CAMERA_SIDE = 2048  # pixels: larger frames exhaust the CPU renderer and the video encoder


@dataclass(frozen=True)
class WorldSettings:
    """Simulation, rendering and planning choices (all recorded with every dataset)."""

    camera_width: int = 128
    camera_height: int = 128
    fps: int = 10  # recorded frames per second of simulated time
    control_freq: int = 20  # joint targets per second
    sim_freq: int = 100  # physics steps per second
    max_joint_speed: float = 1.5  # rad/s on the fastest joint along the path
    dwell_seconds: float = 0.2  # pause at the final waypoint before returning
    settle_seconds: float = 0.5  # at least this long after the return, before the after image ...
    max_settle_seconds: float = 3.0  # ... and longer, up to this, while an object still moves
    rest_speed: float = 0.005  # m/s (and 10x that in rad/s): an object slower than this is at rest
    plan_iterations: int = 20_000  # RRTConnect iterations per segment (deterministic, load-independent)
    plan_time_limit: float = 30.0  # seconds per segment: a safety net only
    ik_tolerance: float = 0.005  # metres
    ik_seeds: int = 8
    collision_margin: float = 0.01  # metres kept from table, floor and robot body

    def __post_init__(self):
        if self.control_freq % self.fps or self.sim_freq % self.control_freq:
            raise ValueError("need fps | control_freq | sim_freq (e.g. 10, 20, 100)")
        if min(self.camera_width, self.camera_height) < 16:
            raise ValueError("camera resolution must be at least 16x16")
        if max(self.camera_width, self.camera_height) > MAX_CAMERA_SIDE:
            raise ValueError(
                f"camera resolution must be at most {MAX_CAMERA_SIDE}x{MAX_CAMERA_SIDE}, "
                f"got {self.camera_width}x{self.camera_height}"
            )

    def to_dict(self) -> dict:
        return asdict(self)
