"""Rerun recordings of babbling runs: the 3D scene per episode, the head camera, contacts, and the paper's
overview of final tool and object positions (Figs. 2-3), built from numpy arrays so that the run loop (live
rollouts) and `babblegen view` (a finished LeRobot dataset) log the same entities.

Timelines follow LeRobot's column names: `frame_index` and `timestamp` (seconds) count within an episode,
`index` counts frames over the whole dataset, `episode_index` is the episode, and `attempt` numbers every
attempted movement, infeasible ones included (per-attempt scalars live there: novelty, archived, feasible,
accumulated contacts).

Entities:
    world/table, world/obstacles/<name>                                     the static scene
    world/robot/base/*, world/robot/arm/{box,sphere,cylinder}              the arm (posed per frame by FK)
    world/objects/<name> (pose per frame), world/objects/<name>/shape       objects in their own colours
    world/objects/<slot>/part<k>_<kind>                                     objects drawn per start: each episode's
                                                                            parts, at its first frame
    world/head_camera (pose and pinhole frustum), head_camera/image        head-camera frames (JPEG)
    world/tool (red while touching), world/tool_path, world/tool_waypoints  the tool point, its path, its targets
    world/object_paths, world/contact_events                                object paths, where contacts happened
    world/start                                                             the objects at each episode's frame 0
    contacts, state                                                         per-frame scalars (object, joint)
    attempts/{novelty,archived,feasible}, attempts/contacts/*              per-attempt scalars
    overview/final_tool, overview/final_objects/<name>, overview/outlines  final positions seen from above

`RerunSink` writes the run's recordings to DIR/babblegen/rerun/ as one .rrd per commit segment; all segments share one
recording id, so `rerun DIR/babblegen/rerun/*.rrd` opens them as a single recording. By default (`rerun_frames =
"ends"`) they log each episode's first and last frame, every view, and the whole paths of the movement; `view` logs
every frame of the episodes asked for, from the dataset.

Modules: `scene` (static geometry and its logging), `columns` (episodes as Rerun columns), `attempts` (per-attempt
scalars and the overview), `layout` (recording streams and the viewer layout), `sink` (the run's crash-safe segment
writer), `view` (a recording from a finished dataset). Importing this package loads neither Rerun nor the simulator.
"""

from __future__ import annotations

from .columns import JpegFrames
from .scene import Scene
from .sink import INDEX, RerunSink, recording_files
from .view import ViewerError, default_view_file, view_dataset

__all__ = [
    "INDEX",
    "JpegFrames",
    "RerunSink",
    "Scene",
    "ViewerError",
    "default_view_file",
    "recording_files",
    "view_dataset",
]
