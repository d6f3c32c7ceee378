"""What a run writes: its sinks, in the order they receive an attempt, and their per-episode work in the workers.

Where the run meets the exporters (`babblegen/assembly.py` builds the search; this builds the outputs), so that
adding a sink is one change here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from babblegen.config import RunConfig
from babblegen.dataset.lerobot import import_lerobot
from babblegen.dataset.schema import features, with_default_features
from babblegen.exporters.dataset_card import DatasetCardSink
from babblegen.exporters.lerobot import LeRobotSink
from babblegen.exporters.lerobot_encoding import EpisodeEncoder
from babblegen.exporters.rerun import JpegFrames, RerunSink
from babblegen.exporters.sidecar import SidecarSink
from babblegen.scene import TaskSpec


@dataclass
class RunOutputs:
    """The sinks of a run writing to ``out`` and the preparations they want from the workers."""

    out: Path
    config: RunConfig
    task: TaskSpec
    joint_names: list[str]

    @property
    def task_text(self) -> str:
        """Every episode's task, in the dataset."""
        return f"{self.config.explorer} babbling in {self.config.task}"

    def import_libraries(self) -> None:
        """Import what the sinks need (seconds: done while worker processes start)."""
        import_lerobot()
        if self.config.rerun:
            # before Rerun's logger starts: the sink reports its own failures, in one line (`RerunSink`)
            os.environ.setdefault("RUST_LOG", "off")
            import rerun  # noqa: F401
            import rerun.blueprint  # noqa: F401

    def features(self) -> dict:
        """The LeRobot dataset's features."""
        world = self.config.world
        shape = (world.camera_height, world.camera_width)
        return features(self.joint_names, self.task.object_names, *shape, world.cameras, self.task, world)

    def preparers(self):
        """The sinks' per-episode work, done by the worker that ran the movement: the LeRobot episode's video
        and statistics, the Rerun recording's JPEG frames."""
        from babblegen.evaluation import Preparers  # the simulator's module: imported when a run starts

        cfg = self.config
        steps = {"lerobot": EpisodeEncoder(cfg.world.fps, with_default_features(self.features()), cfg.video_codec)}
        if cfg.rerun:
            steps["rerun"] = JpegFrames(frames=cfg.rerun_frames)
        return Preparers(steps)

    def sinks(self, repo_id: str, resumed_counters: dict[str, int] | None = None) -> list[tuple[str, Any]]:
        """The run's outputs, in the order they receive each attempt (the sidecar row records the LeRobot
        write time, so it comes after it; the card is refreshed after the dataset's metadata).
        ``resumed_counters``: a resumed run's counters, read when a sink is built."""
        cfg, out, task_text = self.config, self.out, self.task_text
        create = {"fps": cfg.world.fps, "feats": self.features(), "robot_type": self.task.robot_uid}
        makers: list[tuple[str, Any]] = [
            ("lerobot", lambda state: LeRobotSink(state, out, repo_id, task_text, create, cfg.video_codec)),
            ("sidecar", lambda state: SidecarSink(state, out)),
        ]
        if cfg.rerun:

            def rerun(state: dict | None) -> RerunSink:
                if state is None and resumed_counters is not None:  # the run was made without recordings: start here
                    state = {"episodes": resumed_counters["executed"], "attempts": resumed_counters["attempts"]}
                return RerunSink(out, self.task, self.joint_names, state, frames=cfg.rerun_frames)

            makers.append(("rerun", rerun))
        makers.append(("card", lambda state: DatasetCardSink(state, out)))
        return makers
