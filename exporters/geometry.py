"""Top-view outlines shared by the report's figures and the Rerun overview: a static box's footprint and the
robot base's, and the table top's height, from the task description stored in run.json."""

from __future__ import annotations

from typing import Any

import numpy as np

from babblegen.tasks import get_robot
from babblegen.world.kinematics import UrdfModel


def table_top(task: dict[str, Any]) -> float:
    """The table top's height (m): its box's centre plus half its height."""
    t = task["table"]
    return float(t["center"][2] + t["half_extents"][2])


def box_footprint(box: dict[str, Any]) -> np.ndarray:
    """A (possibly rotated) box's outline seen from above: the convex hull of its corners' x, y,
    counter-clockwise."""
    from scipy.spatial import ConvexHull

    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    rot = np.asarray(box.get("rotation", np.eye(3)), dtype=float)
    corners = (np.asarray(box["center"], dtype=float) + (signs * box["half_extents"]) @ rot.T)[:, :2]
    points = np.unique(np.round(corners, 9), axis=0)
    if len(points) < 3:
        return points
    return points[ConvexHull(points).vertices]


def robot_footprint(task: dict[str, Any]) -> np.ndarray:
    """Corners of the robot base's largest box seen from above (x, y); a 0.6 m square when the base has
    no box."""
    robot = get_robot(task.get("robot_uid", "pr2_like_arm"))
    boxes = [s for s in UrdfModel.load(robot.urdf).links.get(robot.base_link, []) if s.kind == "box"]
    if not boxes:
        return np.array([[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]])
    b = max(boxes, key=lambda s: s.size[0] * s.size[1])
    (cx, cy), (hx, hy) = b.origin[:2, 3], b.size[:2] / 2
    return np.array([[cx - hx, cy - hy], [cx + hx, cy - hy], [cx + hx, cy + hy], [cx - hx, cy + hy]])
