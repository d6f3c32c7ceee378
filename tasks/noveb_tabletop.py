"""The NovEB paper's scene: a table in front of the robot with a gray box (left), a can (front centre),
a blue box (right) and a ball (back centre, beyond the arm's reach: it moves only when pushed by
another object). Objects are light enough to move on contact."""

from __future__ import annotations

from babblegen.scene import CameraSpec, PlacementRegion, StartDistribution, TaskSpec, WorkspaceBox
from babblegen.shapes import Box, ObjectSpec

from .registry import register_task

TABLE_TOP = 0.70

SPEC = register_task(
    TaskSpec(
        name="noveb_tabletop",
        env_id="NovEBTabletop-v1",
        description=__doc__,
        # x 0.45..1.35 (depth), y -0.6..0.6 (width), top at 0.70 m
        table=Box("table", (0.90, 0.0, TABLE_TOP / 2), (0.45, 0.60, TABLE_TOP / 2)),
        objects=(
            ObjectSpec("gray_box", "box", (0.05, 0.05, 0.05), (0.45, 0.45, 0.45, 1.0), 0.20, (0.78, 0.22)),
            ObjectSpec("can", "cylinder", (0.033, 0.06), (0.85, 0.1, 0.1, 1.0), 0.10, (0.72, -0.08)),
            ObjectSpec("blue_box", "box", (0.05, 0.05, 0.05), (0.1, 0.25, 0.85, 1.0), 0.20, (0.78, -0.38)),
            ObjectSpec("ball", "sphere", (0.04,), (0.95, 0.8, 0.1, 1.0), 0.05, (1.10, -0.08)),
        ),
        # the normalised [0,1]^3 box: over the table, from the table top to 0.3 m above it
        workspace=WorkspaceBox(low=(0.45, -0.55, TABLE_TOP), high=(1.05, 0.35, TABLE_TOP + 0.30)),
        # PR2's head camera: 0.38 m above the shoulders, tilted down at the table
        camera=CameraSpec(eye=(0.05, 0.0, 1.32), target=(0.88, -0.08, TABLE_TOP), fov=0.92),
        # varied starts: each object anywhere in a wide region around its place in the paper's scene (the regions
        # overlap; footprints keep 2 cm apart), any yaw, always whole in the head camera's view (the search sees
        # nothing else); the ball stays in the back, beyond the arm's reach
        starts=StartDistribution(
            regions=(
                PlacementRegion(x=(0.64, 0.95), y=(0.02, 0.22)),  # gray box: left
                PlacementRegion(x=(0.58, 0.92), y=(-0.32, 0.14)),  # can: front centre
                PlacementRegion(x=(0.60, 0.95), y=(-0.33, -0.12)),  # blue box: right
                PlacementRegion(x=(0.98, 1.25), y=(-0.40, 0.25)),  # ball: back
            ),
        ),
    )
)
