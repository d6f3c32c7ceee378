"""A harder tabletop: objects that answer a push differently, and a low wall the arm must plan around.

On the left a heavy crate (80 kg) that a push shifts by a few centimetres at most; front centre a light, tall
bottle that topples (and often rolls off the table); three small light cubes on the right, one of them behind a
low wall (6 cm high, 2 cm thick, 30 cm long) standing across the right of the table. The wall is a static actor
in the simulation and a planning obstacle: trajectories pass over or around it, and the cube behind it is
reached only by coming down behind the wall or sweeping in from its open end.
"""

from __future__ import annotations

from babblegen.scene import CameraSpec, PlacementRegion, StartDistribution, TaskSpec
from babblegen.shapes import Box, ObjectSpec

from .noveb_tabletop import SPEC as PAPER_SCENE
from .registry import register_task

TABLE_TOP = PAPER_SCENE.table_top
WALL_HEIGHT = 0.06

SPEC = register_task(
    TaskSpec(
        name="wall_tabletop",
        env_id="WallTabletop-v1",
        description=__doc__,
        table=PAPER_SCENE.table,  # x 0.45..1.35 (depth), y -0.6..0.6 (width), top at 0.70 m
        objects=(
            ObjectSpec("crate", "box", (0.07, 0.07, 0.06), (0.25, 0.32, 0.22, 1.0), 80.0, (0.76, 0.20)),
            ObjectSpec("bottle", "cylinder", (0.022, 0.10), (0.95, 0.8, 0.1, 1.0), 0.06, (0.70, -0.02)),
            ObjectSpec("cube_orange", "box", (0.025, 0.025, 0.025), (0.95, 0.5, 0.1, 1.0), 0.04, (0.60, -0.40)),
            ObjectSpec("cube_green", "box", (0.025, 0.025, 0.025), (0.2, 0.7, 0.3, 1.0), 0.04, (0.68, -0.22)),
            ObjectSpec("cube_purple", "box", (0.025, 0.025, 0.025), (0.6, 0.3, 0.8, 1.0), 0.04, (0.87, -0.35)),
        ),
        workspace=PAPER_SCENE.workspace,  # the same normalised [0,1]^3 box: over the table, up to 0.3 m above it
        camera=CameraSpec(eye=(0.05, 0.0, 1.32), target=(0.88, -0.08, TABLE_TOP), fov=0.92),
        # x 0.77..0.79, y -0.50..-0.20, from the table top up 6 cm
        default_objects="paper",  # the crate, the bottle and the cubes around the wall are the point of the scene
        extra_obstacles=(Box("wall", (0.78, -0.35, TABLE_TOP + WALL_HEIGHT / 2), (0.01, 0.15, WALL_HEIGHT / 2)),),
        # varied starts: wide regions around each object's place (none overlapping the wall), whole in the head
        # camera's view; the purple cube stays behind the wall, the others in front of it
        starts=StartDistribution(
            regions=(
                PlacementRegion(x=(0.64, 0.98), y=(0.0, 0.18)),  # crate
                PlacementRegion(x=(0.58, 0.92), y=(-0.18, 0.18)),  # bottle
                PlacementRegion(x=(0.55, 0.74), y=(-0.37, -0.15)),  # orange cube, in front of the wall
                PlacementRegion(x=(0.55, 0.74), y=(-0.32, 0.02)),  # green cube
                PlacementRegion(x=(0.83, 1.02), y=(-0.50, -0.20)),  # purple cube, behind the wall
            ),
        ),
    )
)
