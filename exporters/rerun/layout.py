"""Recording streams and the viewer's default layout (blueprint)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .columns import view_entity
from .scene import HEAD_IMAGE

if TYPE_CHECKING:
    import rerun as rr
    import rerun.blueprint as rrb

APP_ID = "babblegen"


def new_recording(recording_id: str) -> rr.RecordingStream:
    """A recording stream whose only timelines are the ones babblegen sets."""
    import rerun as rr

    rec = rr.RecordingStream(APP_ID, recording_id=recording_id, send_properties=False)
    rec.set_log_tick_enabled(False)
    rec.set_log_time_enabled(False)
    return rec


def camera_views(cameras: list[dict[str, Any]] | None) -> rrb.Container | rrb.SpaceView:
    """One 2D view per camera and kind recorded (the head camera's colour alone for runs without the setting):
    colour, depth (Rerun's depth colour map) and instance masks (named by the annotation context)."""
    import rerun.blueprint as rrb

    views = []
    for cam in cameras or [{"name": "head"}]:
        kinds = ["rgb"] + [k for k in ("depth", "segmentation") if cam.get(k)]
        for kind in kinds:
            label = {"rgb": "camera", "depth": "depth", "segmentation": "masks"}[kind]
            entity = HEAD_IMAGE if (cam["name"], kind) == ("head", "rgb") else view_entity(cam["name"], kind)
            views.append(
                rrb.Spatial2DView(origin=entity.rsplit("/", 1)[0], contents=[entity], name=f"{cam['name']} {label}")
            )
    return views[0] if len(views) == 1 else rrb.Grid(*views, grid_columns=min(3, len(views)))


def blueprint(timeline: str = "index", cameras: list[dict[str, Any]] | None = None) -> rrb.Blueprint:
    """3D scene, the cameras' images and the overview of final positions, with plots that have data on
    ``timeline``: one episode (``frame_index``) gets its contacts and joint state, many also the per-attempt
    plots. ``cameras``: the run's (``world.cameras`` in run.json)."""
    import rerun.blueprint as rrb

    so_far = [
        rrb.VisibleTimeRange(tl, start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.cursor_relative())
        for tl in ("attempt", "episode_index", "index")
    ]
    if timeline == "frame_index":  # one episode: every plot has data on the frame timeline
        plots = rrb.Vertical(
            rrb.TimeSeriesView(origin="contacts", name="Contacts per frame"),
            rrb.TimeSeriesView(origin="state", name="Joint state"),
        )
    else:  # per-attempt series live on the attempt, episode and index timelines
        plots = rrb.Vertical(
            rrb.TimeSeriesView(origin="contacts", name="Contacts per frame"),
            rrb.TimeSeriesView(origin="attempts/contacts", name="Accumulated contacts"),
            rrb.Tabs(
                rrb.TimeSeriesView(
                    origin="attempts",
                    contents=["attempts/novelty", "attempts/archived", "attempts/feasible"],
                    name="Per attempt",
                ),
                rrb.TimeSeriesView(origin="state", name="Joint state"),
            ),
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                origin="world",
                name="Scene",
                eye_controls=rrb.EyeControls3D(
                    position=(-0.9, -1.9, 2.1), look_target=(0.75, 0.0, 0.7), eye_up=(0, 0, 1)
                ),
            ),
            rrb.Vertical(
                camera_views(cameras),
                rrb.Spatial3DView(
                    origin="overview",
                    name="Final tool and object positions, from above",
                    eye_controls=rrb.EyeControls3D(
                        position=(0.45, 0.0, 3.6), look_target=(0.45, 0.0, 0.7), eye_up=(1, 0, 0)
                    ),
                    time_ranges=so_far,
                ),
            ),
            plots,
            column_shares=[3, 2, 2],
        ),
        rrb.TimePanel(timeline=timeline),
    )
