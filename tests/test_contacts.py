"""Contact quality with the default contacts: PhysX's persistent contact manifolds (PCM) on, the scene's boxes
colliding as convex hulls (so no pair of boxes meets PCM's box-box generator, whose approximate-reciprocal
instructions differ between CPU makers; docs/reproducibility.md).

The arm pushes only what it reaches (checked against distances worked out from the shapes' boxes; PhysX's box-box
generator without PCM pushes from centimetres away); objects at rest stay at rest; a push moves the gray box; the
can topples and the ball rolls; and nothing sinks into the table or into another object deeper than PhysX's contact
offset (0.02 m). One World per setting, at 64 x 64 pixels, and rollouts without their frames in between rendered.
"""

from __future__ import annotations

import numpy as np
import pytest
import sapien
from scipy.optimize import minimize
from watch import WatchedWorld

from babblegen.evaluation import seeded_rollout
from babblegen.tasks import get_task
from babblegen.world.rollout import Command, Rollout
from babblegen.world.world import World, WorldSettings

pytestmark = pytest.mark.filterwarnings("ignore:__array_wrap__ must accept context:DeprecationWarning")

GRAY, CAN, BLUE, BALL = range(4)
CONTACT_OFFSET = 0.02  # metres: ManiSkill's SceneConfig default, where PhysX starts generating contacts
# Seed 1's first NovEB attempt (one waypoint): the arm's gripper comes down on the gray box and presses it into the
# table. Without PCM, PhysX's box-box generator pushed the box 6.9 cm sideways through contacts whose boxes stood up to
# 3.4 cm apart; the boxes as hulls, only where they touch (the box turns and slides 0.7 cm).
GRAY_PRESS = (Command("ee_waypoints", np.array([[0.5118216247002567, 0.9504636963259353, 0.14415961271963373]])), 1, 0)
# The tool to 7 cm above the table beside the gray box, then along -y: it slides the box 17 cm, alone.
GRAY_PUSH = ([[0.78, 0.34, 0.77], [0.78, 0.14, 0.77]], 0, 0)
# One waypoint in front of the can, low: the arm hits the can's upper half and it falls over (NovEB, seed 1).
TOPPLE = (Command("ee_waypoints", np.array([[0.3847810797564037, 0.620355840732748, 0.17298424917803137]])), 1, 46)
# A varied start with the ball in reach and nothing in front of it, and the tool from 12 cm behind the ball through
# it along +x, 1 cm above its centre: the ball rolls 42 cm and stays on the table.
BALL_LAYOUT = np.array([[0.78, 0.22, 0.0], [0.65, 0.05, 0.0], [0.78, -0.38, 0.0], [0.86, -0.12, 0.0]])
ROLL = ([[0.74, -0.12, 0.75], [0.92, -0.12, 0.75]], 0, 0)


class GapWorld(WatchedWorld):
    """Also records, every physics substep, for each contact between an arm link and an object that pushes (a point
    with an impulse) and joins two boxes (PhysX's, or hulls of a box's eight corners), how far apart the two boxes
    are, worked out from their poses and half sizes (`box_gap`)."""

    def _bind_scene(self) -> None:
        super()._bind_scene()
        self.gaps: list[float] = []

    def _touching(self) -> np.ndarray:
        touched = super()._touching()
        arm, objects = self._contacts.arm_bodies, self._contacts.object_of_body
        for contact in self.sim.scene.px.get_contacts():
            a, b = contact.bodies
            if not ((a in arm and b in objects) or (b in arm and a in objects)):
                continue
            if not any(p.impulse.any() for p in contact.points):
                continue
            (sa, sb), halves = contact.shapes, [half_sizes(s) for s in contact.shapes]
            if halves[0] is not None and halves[1] is not None:
                where = [
                    (body.entity_pose * shape.local_pose).to_transformation_matrix()
                    for body, shape in ((a, sa), (b, sb))
                ]
                self.gaps.append(box_gap(where[0], halves[0], where[1], halves[1]))
        return touched


def half_sizes(shape) -> np.ndarray | None:
    """A box shape's half sizes, or a convex hull's of a box's eight corners; None for any other shape."""
    if isinstance(shape, sapien.physx.PhysxCollisionShapeBox):
        return np.asarray(shape.half_size, dtype=np.float64)
    if isinstance(shape, sapien.physx.PhysxCollisionShapeConvexMesh):
        corners = np.abs(np.asarray(shape.get_vertices(), dtype=np.float64) * np.asarray(shape.scale))
        half = corners.max(axis=0)
        if len(corners) == 8 and np.allclose(corners, half, atol=1e-6):
            return half
    return None


def box_gap(pose_a: np.ndarray, half_a: np.ndarray, pose_b: np.ndarray, half_b: np.ndarray) -> float:
    """The distance between two boxes (4x4 world poses, half sizes), 0 where they overlap: the least distance between
    a point of one and a point of the other, a convex problem over the points' box coordinates."""
    ra, ta, rb, tb = pose_a[:3, :3], pose_a[:3, 3], pose_b[:3, :3], pose_b[:3, 3]

    def squared(x: np.ndarray) -> tuple[float, np.ndarray]:
        d = ra @ x[:3] + ta - rb @ x[3:] - tb
        return float(d @ d), np.concatenate([2 * ra.T @ d, -2 * rb.T @ d])

    bounds = [(-h, h) for h in (*half_a, *half_b)]
    best = minimize(squared, np.zeros(6), jac=True, method="L-BFGS-B", bounds=bounds, options={"ftol": 1e-15})
    return float(np.sqrt(max(best.fun, 0.0)))


def test_box_gap_is_the_distance_between_two_boxes():
    unit = np.ones(3)
    shifted = np.eye(4)
    shifted[:3, 3] = [3.0, 0.5, 0.0]  # face to face, 1 apart
    assert box_gap(np.eye(4), unit, shifted, unit) == pytest.approx(1.0, abs=1e-6)
    turned = np.eye(4)
    c = s = np.sqrt(0.5)
    turned[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]  # an edge towards the other's face, sqrt(2) from its centre
    turned[:3, 3] = [1 + np.sqrt(2) + 0.25, 0.0, 0.0]
    assert box_gap(np.eye(4), unit, turned, unit) == pytest.approx(0.25, abs=1e-6)
    turned[:3, 3] = [2.0, 0.0, 0.0]
    assert box_gap(np.eye(4), unit, turned, unit) == pytest.approx(0.0, abs=1e-9)  # overlapping


@pytest.fixture(scope="module")
def worlds():
    """The default contacts, and PhysX's boxes without PCM (the contacts of runs made before them)."""
    task = get_task("noveb_tabletop")
    made = {
        "default": GapWorld(task, WorldSettings(camera_width=64, camera_height=64)),
        "boxes without pcm": GapWorld(
            task, WorldSettings(camera_width=64, camera_height=64, pcm=False, box_hulls=False)
        ),
    }
    yield made
    for w in made.values():
        w.close()


def command(w: World, spec, start: np.ndarray | None = None) -> tuple[Command, int, int]:
    """(command, run seed, attempt) from a command or world-frame waypoints."""
    what, seed, attempt = spec
    if not isinstance(what, Command):
        what = Command("ee_waypoints", w.task.workspace.to_norm(np.asarray(what)), start)
    return what, seed, attempt


def run(w: WatchedWorld, spec, start: np.ndarray | None = None) -> Rollout:
    cmd, seed, attempt = command(w, spec, start)
    r = seeded_rollout(w, cmd, seed, attempt, defer_render=True)
    assert r.feasible, r.reason
    return r


def hold(w: World, seconds: float) -> np.ndarray:
    """Simulate ``seconds`` more with the arm held at home; how far each object's centre moved (metres)."""
    before = w._object_poses()
    w._drive(w.home)
    for _ in range(int(round(seconds * w.settings.sim_freq))):
        w.sim.scene.px.step()
    return np.linalg.norm(w._object_poses()[:, :3] - before[:, :3], axis=1)


def tilt(q: np.ndarray) -> float:
    """Degrees between the object's z axis and the world's."""
    w, x, y, z = q
    return float(np.degrees(np.arccos(np.clip(1 - 2 * (x * x + y * y), -1.0, 1.0))))


def lowest_points(w: World, poses: np.ndarray) -> np.ndarray:
    """(T, n_objects) the height of each object's lowest point, from its recorded poses and shape."""
    q = poses[..., 3:].astype(np.float64)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    # the third row of each rotation matrix: how the object's axes point up
    up = np.stack([2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)], axis=-1)
    low = np.empty(poses.shape[:2])
    for i, obj in enumerate(w.task.objects):
        s = np.asarray(obj.size)
        if obj.shape == "box":
            reach = np.abs(up[:, i]) @ s
        elif obj.shape == "cylinder":
            az = np.abs(up[:, i, 2])
            reach = az * s[1] + s[0] * np.sqrt(np.clip(1 - az**2, 0, 1))
        else:
            reach = np.full(len(poses), s[0])
        low[:, i] = poses[:, i, 2] - reach
    return low


def assert_nothing_sinks(w: WatchedWorld, r: Rollout) -> None:
    """No contact deeper than the contact offset, no object below the table top over the table, no two objects'
    centres closer than their inscribed radii."""
    assert w.deepest > -CONTACT_OFFSET, f"a contact {-w.deepest * 1000:.1f} mm deep"
    poses = r.frames.object_poses.astype(np.float64)
    t = w.task.table
    over = np.all(np.abs(poses[..., :2] - np.asarray(t.center[:2])) < np.asarray(t.half_extents[:2]), axis=-1)
    low = lowest_points(w, poses)
    assert np.all(low[over] > w.task.table_top - CONTACT_OFFSET), low[over].min()
    inner = np.array([min(o.size) for o in w.task.objects])
    for a in range(len(inner)):
        for b in range(a + 1, len(inner)):
            gap = np.linalg.norm(poses[:, a, :3] - poses[:, b, :3], axis=1) - inner[a] - inner[b]
            assert gap.min() > -CONTACT_OFFSET, (w.task.objects[a].name, w.task.objects[b].name, gap.min())


def test_objects_at_rest_stay_at_rest(worlds):
    w = worlds["default"]
    w.reset()
    moved = hold(w, 2.0)
    assert moved.max() < 1e-3, moved
    w.reset(BALL_LAYOUT)
    assert w.settle_start() == ""
    moved = hold(w, 2.0)
    assert moved.max() < 1e-3, moved


def test_the_arm_pushes_only_what_it_reaches(worlds):
    gaps = {}
    for name, w in worlds.items():
        r = run(w, GRAY_PRESS)
        assert r.touched[GRAY] and w.gaps, name
        gaps[name] = np.asarray(w.gaps)
        assert_nothing_sinks(w, r)
    assert gaps["default"].max() < 2e-3, f"pushed from {gaps['default'].max() * 1000:.1f} mm away"
    # the check can fail: PhysX's box-box generator without PCM pushes from over a centimetre
    assert (gaps["boxes without pcm"] > 0.01).sum() > 10 and gaps["boxes without pcm"].max() > 0.03


def test_a_push_moves_the_gray_box_alone(worlds):
    w = worlds["default"]
    r = run(w, GRAY_PUSH)
    others = np.arange(4) != GRAY
    assert r.displacement[GRAY] > 0.1 and (r.displacement[others] < 0.01).all(), r.displacement
    assert abs(r.final_poses[GRAY][2] - r.start_poses[GRAY][2]) < 1e-3  # upright on the table
    assert max(w.gaps) < 2e-3
    assert_nothing_sinks(w, r)


def test_the_can_topples_and_lies_still(worlds):
    w = worlds["default"]
    r = run(w, TOPPLE)
    assert r.touched[CAN] and tilt(r.final_poses[CAN, 3:]) > 80
    can = w.task.objects[CAN]
    assert abs(r.final_poses[CAN, 2] - (w.task.table_top + can.size[0])) < 2e-3  # on its side, on the table
    assert_nothing_sinks(w, r)
    assert hold(w, 2.0).max() < 1e-3


def test_the_ball_rolls(worlds):
    w = worlds["default"]
    r = run(w, ROLL, BALL_LAYOUT)
    assert r.touched[BALL]
    path = r.frames.object_poses[:, BALL].astype(np.float64)
    travelled = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1)
    assert travelled.sum() > 0.1
    assert np.abs(path[:, 2] - path[0, 2]).max() < 1e-3  # on the table all the way
    # it turns as far as a ball rolling that far without slipping: the angle between frames times its radius (it
    # slides a little while the tool strikes it)
    q = path[:, 3:]
    turned = 2 * np.arccos(np.clip(np.abs((q[1:] * q[:-1]).sum(axis=1)), 0, 1)) * w.task.objects[BALL].size[0]
    moving = travelled > 1e-3
    assert abs(np.median(turned[moving] / travelled[moving]) - 1) < 0.1
    assert abs(turned[moving].sum() / travelled[moving].sum() - 1) < 0.15
    assert_nothing_sinks(w, r)


# The canonical rollout that pushes the blue box into the can (tests/reference/make_reference.py): the arm first
# touches the blue box at frame 7 and the box then hits the can; the gray box stands within PhysX's contact offset
# of the blue box but is never pushed.
BLUE_INTO_CAN = (
    [[0.7143345840533009, 0.5931833203475035, 0.1520972178810357]],
    np.array(
        [
            [0.7171300292176821, 0.07577778841060984, -0.30301337838367504],
            [0.7894718902198021, -0.03888690125265548, 0.5697390716175126],
            [0.7510270494746655, -0.17338552842258695, -0.8827742835629269],
            [1.0995614578541069, -0.18842237203178394, -1.5315537316308678],
        ]
    ),
    1,
    361,
)
GRAVITY = 9.81  # m/s^2, ManiSkill's scene default


def test_one_object_pushed_into_another_is_a_contact_event(worlds):
    from babblegen.contact_events import contact_events, pair_names

    w = worlds["default"]
    waypoints, layout, seed, attempt = BLUE_INTO_CAN
    r = seeded_rollout(w, Command("ee_waypoints", np.asarray(waypoints), layout), seed, attempt, defer_render=True)
    assert r.feasible, r.reason
    impulses = r.frames.object_contacts
    names = pair_names(w.object_names)
    assert impulses.shape == (len(r.frames), 14) and impulses.dtype == np.float32
    assert (impulses[0] == 0).all()  # nothing happened before the first frame
    column = dict(zip(names, impulses.T, strict=True))

    arm_first = int(np.flatnonzero(r.frames.contacts[:, BLUE])[0])
    hit = np.flatnonzero(column["can|blue_box"] > 0)
    assert arm_first < hit[0] < len(r.frames) - 1, (arm_first, hit)
    assert column["can|blue_box"].sum() > 0
    for name in names:  # no other two objects touched, nothing fell to the floor
        if name != "can|blue_box" and not name.endswith("|table"):
            assert (column[name] == 0).all(), name
    # the objects the arm never touched rest on the table: its impulse per frame is their weight times 1 / fps
    for i in (GRAY, BALL):
        weight = w.task.objects[i].mass * GRAVITY / w.settings.fps
        rest = column[f"{w.object_names[i]}|table"][1:]
        np.testing.assert_allclose(rest, weight, rtol=0.01)
    events = contact_events(impulses, w.object_names)
    assert list(events) == ["can|blue_box"]  # the table's contacts were there from the start
    assert events["can|blue_box"]["first_frame"] == hit[0]

    # reusing sleeping objects' impulses records what reading every contact records, to the bit
    scan = w._touching
    w._touching = lambda: (w._contacts.asleep.clear(), scan())[1]
    try:
        again = seeded_rollout(
            w, Command("ee_waypoints", np.asarray(waypoints), layout), seed, attempt, defer_render=True
        )
    finally:
        del w._touching
    np.testing.assert_array_equal(again.frames.object_contacts, impulses)
    np.testing.assert_array_equal(again.frames.object_poses, r.frames.object_poses)
