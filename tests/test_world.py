"""Rollouts in the simulated tabletop: contacts, object motion, head-camera images, frame recording, resets.

One World per module: its first camera render compiles shaders (about 10 s on the CPU renderer).
"""

from __future__ import annotations

import numpy as np
import pytest
import sapien

from babblegen.descriptors import PHash
from babblegen.tasks import get_task
from babblegen.world.reference import ManiSkillDrivenWorld
from babblegen.world.rollout import REASONS, Command, Rollout
from babblegen.world.world import World, WorldSettings

# ManiSkill's action check trips a NumPy 2 deprecation warning on every control step.
pytestmark = pytest.mark.filterwarnings("ignore:__array_wrap__ must accept context:DeprecationWarning")

CAN = 1  # index of the can in the task's objects
# Tool from 10 cm in front of the can through its centre and 12 cm beyond, 1 cm above the table top.
PUSH_THROUGH_CAN = np.array([[0.62, -0.08, 0.77], [0.84, -0.08, 0.77]])
FREE_AIR = np.array([[0.7, -0.3, 0.98]])
TABLE_TARGET = np.array([[0.7, -0.2, 0.65]])
FAR_TARGET = np.array([[1.4, 0.0, 0.8]])
# Three contact-rich movements. After the pose-only reset this project once had, A's outcome depended on which
# of B or C ran before it (the can ended 63 cm apart).
SWEEP_A = np.array([[0.726, 0.025, 0.747]])
SWEEP_B = np.array([[0.88, 0.127, 0.743], [0.7, -0.392, 0.737]])
SWEEP_C = np.array([[0.676, -0.413, 0.748], [0.481, 0.275, 0.758], [0.62, -0.144, 0.741]])


@pytest.fixture(scope="module")
def world():
    w = World(get_task("noveb_tabletop"), seed=0)
    yield w
    w.close()


def waypoints(w: World, points: np.ndarray) -> Command:
    return Command("ee_waypoints", w.task.workspace.to_norm(points))


@pytest.fixture(scope="module")
def push(world) -> Rollout:
    r = world.rollout(waypoints(world, PUSH_THROUGH_CAN))
    assert r.feasible, r.reason
    return r


def project(w: World, points: np.ndarray) -> np.ndarray:
    """Pixel coordinates (column, row) of world points in the head camera image."""
    params = w._camera.get_params()
    k, ext = params["intrinsic_cv"][0].numpy(), params["extrinsic_cv"][0].numpy()
    cam = np.atleast_2d(points) @ ext[:3, :3].T + ext[:3, 3]
    uv = cam @ k.T
    return uv[:, :2] / uv[:, 2:]


def changed_mask(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1) > 0


def bbox(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    return cols.min(), rows.min(), cols.max(), rows.max()


# --- contacts and object motion ------------------------------------------------------------------------
def test_push_through_can_touches_and_moves_it(world, push):
    w, r = world, push
    assert r.touched.dtype == bool and r.touched.shape == (len(w.object_names),)
    assert r.touched[CAN], r.touched
    assert r.frames.contacts[:, CAN].max() == 1.0
    np.testing.assert_array_equal(r.touched, r.frames.contacts.max(axis=0) > 0)
    assert r.frames.contacts[0].sum() == 0  # nothing touched before the movement
    assert r.displacement[CAN] > 0.005, r.displacement
    others = np.arange(len(w.object_names)) != CAN
    assert not r.touched[others].any()
    assert (r.displacement[others] < 2e-3).all(), r.displacement  # the can rolls 25 cm and grazes the gray box
    np.testing.assert_allclose(
        r.displacement, np.linalg.norm(r.final_poses[:, :3] - w.start_poses[:, :3], axis=1), atol=1e-9
    )


def test_push_through_can_changes_image_around_the_can(world, push):
    w, r = world, push
    before, after = r.before_image, r.after_image
    assert np.abs(before.astype(float) - after.astype(float)).mean() > 0.2
    phash = PHash()
    changed_hash = not np.array_equal(phash(before), phash(after))
    mask = changed_mask(before, after)
    col, row = project(w, w.start_poses[CAN, :3])[0].round().astype(int)
    window = mask[max(row - 6, 0) : row + 7, max(col - 6, 0) : col + 7]
    assert window.mean() > 0.2, "the pixels where the can stood did not change"
    # nothing changed around the objects that were not touched
    for i in np.flatnonzero(~r.touched):
        c, rw = project(w, w.start_poses[i, :3])[0].round().astype(int)
        assert not mask[max(rw - 4, 0) : rw + 5, max(c - 4, 0) : c + 5].any(), w.object_names[i]
    assert changed_hash or window.mean() > 0.5


def test_free_air_touches_nothing(world):
    w = world
    r = w.rollout(waypoints(w, FREE_AIR))
    assert r.feasible, r.reason
    assert not r.touched.any()
    assert (r.frames.contacts == 0).all()
    assert (r.displacement < 1e-4).all(), r.displacement  # resting objects settle by micrometres
    # Without PCM the can settles by 5 um (1 um with it), which moves a pixel or two at its edge by one level
    diff = np.abs(r.after_image.astype(np.int16) - r.before_image.astype(np.int16)).max(axis=-1)
    assert diff.max() <= 1 and (diff > 0).sum() <= 3, (diff.max(), (diff > 0).sum())
    # the tool really went there (within the IK tolerance plus the controller's tracking error)
    err = np.linalg.norm(r.frames.ee_pos - FREE_AIR[0], axis=1).min()
    assert err < 0.02, err


# --- head camera -------------------------------------------------------------------------------------------
def test_head_image_is_a_real_render(world):
    w = world
    h, width = w.settings.camera_height, w.settings.camera_width
    w.reset()
    scene = w._render()
    assert scene.shape == (h, width, 3) and scene.dtype == np.uint8
    assert scene.std() > 20, scene.std()
    assert len(np.unique(scene.reshape(-1, 3), axis=0)) > 20
    np.testing.assert_array_equal(w._render(), scene)  # rendering the same scene twice is stable
    can_pixel = project(w, w.start_poses[CAN, :3])[0]
    assert (can_pixel >= 0).all() and (can_pixel < [width, h]).all()
    try:
        w._object_entities[CAN].pose = sapien.Pose(p=[3.0, 3.0, 0.1])
        without_can = w._render()
    finally:
        w.reset()
    mask = changed_mask(scene, without_can)
    assert mask.sum() > 30, "removing the can changed (almost) nothing"
    c0, r0, c1, r1 = bbox(mask)
    assert (c1 - c0 + 1) * (r1 - r0 + 1) < 0.05 * h * width, (c0, r0, c1, r1)
    assert c0 - 1 <= can_pixel[0] <= c1 + 1 and r0 - 1 <= can_pixel[1] <= r1 + 1, (can_pixel, (c0, r0, c1, r1))
    np.testing.assert_array_equal(w._render(), scene)  # reset put the can back


def test_deferred_frames_render_to_the_same_pixels_even_with_other_rollouts_in_between(world):
    """Worker processes render most frames after the movement, from the recorded states, pausing for other
    movements: the episode's pixels are those of a rollout rendered in one go, in a contact-rich movement."""
    w = world
    w.rng = np.random.default_rng(5)
    whole = w.rollout(waypoints(w, SWEEP_A))
    w.rng = np.random.default_rng(5)
    deferred = w.rollout(waypoints(w, SWEEP_A), defer_render=True)
    assert whole.touched.any() and deferred.frames.images is None and len(deferred.frames.end_images) == 2
    np.testing.assert_array_equal(deferred.after_image, whole.after_image)
    np.testing.assert_array_equal(deferred.frames.state, whole.frames.state)
    steps = w.render_frames_stepwise(deferred.frames, frames_per_step=3)
    next(steps)
    w.rollout(waypoints(w, SWEEP_B))  # in a pause: the scene is rebuilt and the objects pushed elsewhere
    assert list(steps) == [None] * ((len(whole.frames) - 2) // 3 - 1)
    assert deferred.frames.end_images is None
    np.testing.assert_array_equal(deferred.frames.images, whole.frames.images)


def test_before_image_is_the_reset_scene(world):
    w = world
    w.reset()
    scene = w._render()
    r = w.rollout(waypoints(w, FREE_AIR))
    np.testing.assert_array_equal(r.before_image, scene)


# --- frame recording ---------------------------------------------------------------------------------------
def test_frames_are_recorded_consistently(world, push):
    w, r, s = world, push, world.settings
    f = r.frames
    n_obj, dof = len(w.object_names), w.kin.dof
    t = len(f)
    assert t >= 3
    # the schedule: out along the path, dwell, back, settle, one frame every control_freq / fps steps
    m = (len(r.joint_path) + 1) // 2
    out, back = r.joint_path[:m], r.joint_path[m - 1 :]
    np.testing.assert_allclose(back, out[::-1])
    steps = (
        len(w._timed_path(out))
        + round(s.dwell_seconds * s.control_freq)
        + len(w._timed_path(back))
        + max(round(s.settle_seconds * s.control_freq), 1)
    )
    # padded to end on a frame; settling goes on, a frame at a time, up to max_settle_seconds while an object
    # still moves
    extra_frames = round((s.max_settle_seconds - s.settle_seconds) * s.fps)
    per_frame = s.control_freq // s.fps
    frames = 1 + -(-steps // per_frame)
    assert frames <= t <= frames + extra_frames
    # every frame is taken exactly t / fps into the movement (LeRobot's timestamps)
    np.testing.assert_allclose(f.time, np.arange(t) / s.fps, atol=1e-9)
    assert f.state.shape == (t, dof) and f.action.shape == (t, dof) and f.ee_pos.shape == (t, 3)
    assert f.object_poses.shape == (t, n_obj, 7) and f.contacts.shape == (t, n_obj)
    assert f.images.shape == (t, s.camera_height, s.camera_width, 3) and f.images.dtype == np.uint8
    assert set(np.unique(f.contacts)) <= {0.0, 1.0}
    np.testing.assert_allclose(f.state[0], w.home, atol=1e-4)
    np.testing.assert_allclose(f.state[-1], w.home, atol=1e-4)
    np.testing.assert_allclose(f.state[-2], w.home, atol=1e-2)  # settled before the final snap home
    # action[t] is sent after observing frame t and leads to frame t + 1 (LeRobot's convention): the first
    # already moves the arm, the state catches up with it one frame later, and the arm holds home at the end
    assert np.abs(f.action[0] - w.home).max() > 1e-3
    assert np.abs(f.state[1:] - f.action[:-1]).mean() < 0.5 * np.abs(f.state[:-1] - f.action[:-1]).mean()
    np.testing.assert_allclose(f.action[-2:], np.stack([w.home, w.home]), atol=1e-6)
    assert (f.action >= w.kin.lower - 1e-5).all() and (f.action <= w.kin.upper + 1e-5).all()
    # the recorded tool position is the model's FK of the recorded joint state
    np.testing.assert_allclose(f.ee_pos, w.kin.tool_position(f.state.astype(np.float64)), atol=2e-3)
    np.testing.assert_allclose(f.object_poses[0], w.start_poses, atol=1e-6)
    np.testing.assert_allclose(f.object_poses[-1], r.final_poses, atol=1e-6)
    # the arm went where it was sent: near the last waypoint in some frame
    assert np.linalg.norm(f.ee_pos - PUSH_THROUGH_CAN[-1], axis=1).min() < 0.03
    assert r.planner in ("direct", "rrtconnect")
    assert {"ik", "plan", "sim", "render", "total"} <= r.timings.keys()


def test_reset_restores_start_poses(world):
    w = world
    r = w.rollout(waypoints(w, PUSH_THROUGH_CAN))
    assert r.feasible and r.displacement[CAN] > 0.005
    np.testing.assert_allclose(w._object_poses()[CAN], r.final_poses[CAN], atol=1e-6)
    w.reset()
    np.testing.assert_allclose(w._object_poses(), w.start_poses, atol=1e-6)
    np.testing.assert_allclose(w._arm.qpos, w.home, atol=1e-6)
    rest = np.array(w.task.rest_pose(w.task.objects[CAN]))
    np.testing.assert_allclose(w.start_poses[CAN], rest, atol=1e-6)


# --- varied starts ----------------------------------------------------------------------------------------------
def test_fixed_start_is_the_task_scene_exactly(world, push):
    assert np.array_equal(push.start_poses, world.start_poses), "displacements from the same start as before"


def test_varied_starts_settle_in_their_layout_and_record_changes_from_their_own_start(world):
    from babblegen.scene import layout_poses
    from babblegen.starts import StartSampler

    w, sampler = world, StartSampler(world.task, seed=4)
    radius = np.array([o.footprint_radius for o in w.task.objects])
    touched_some = False
    for attempt in range(12):
        start = sampler.draw(attempt)
        command = waypoints(w, PUSH_THROUGH_CAN)
        r = w.rollout(Command(command.kind, command.values, start.layout))
        assert r.feasible, r.reason
        f = r.frames
        # settled where it was placed: within a millimetre, resting on the table top, before the first frame
        np.testing.assert_allclose(r.start_poses[:, :3], layout_poses(w.task, start.layout)[:, :3], atol=1e-3)
        np.testing.assert_allclose(f.object_poses[0], r.start_poses, atol=1e-6)
        untouched = ~f.contacts[:2].any(axis=0)
        first_step = np.linalg.norm(f.object_poses[1, :, :3] - f.object_poses[0, :, :3], axis=1)
        assert first_step[untouched].max(initial=0) <= 0.005, "no untouched object moves in the first two frames"
        np.testing.assert_allclose(
            r.displacement, np.linalg.norm(r.final_poses[:, :3] - r.start_poses[:, :3], axis=1), atol=1e-9
        )
        touched_some |= bool(r.touched.any())
        near = np.hypot(*(start.layout[:, None, :2] - start.layout[None, :, :2]).transpose(2, 0, 1))
        assert (near + np.eye(len(radius)) * 9 > radius[:, None] + radius).all()
    # the same push finds the can in some starts and not in others, the point of varying them
    assert touched_some


def test_a_varied_start_is_a_function_of_its_layout_alone(world):
    from babblegen.starts import StartSampler

    start = StartSampler(world.task, seed=5).draw(3)
    command = Command("ee_waypoints", world.task.workspace.to_norm(SWEEP_A), start.layout)
    a = world.rollout(command)
    world.rollout(waypoints(world, SWEEP_B))
    b = world.rollout(command)
    for field in ("images", "state", "object_poses", "contacts"):
        assert np.array_equal(getattr(a.frames, field), getattr(b.frames, field)), field


def test_a_start_that_does_not_settle_is_not_used(world):
    layout = np.array([[0.7, 0.25, 0.0], [0.7, -0.1, 0.0], [0.8, -0.4, 0.0], [1.5, 0.0, 0.0]])  # the ball in the air
    r = world.rollout(Command("ee_waypoints", world.task.workspace.to_norm(FREE_AIR), layout))
    assert not r.feasible and r.reason in ("start_not_at_rest", "start_off_table") and r.frames is None
    assert r.reason in REASONS


# --- joint-space babbling and infeasible commands -----------------------------------------------------------
def test_outcome_depends_on_the_command_alone(world):
    """A, B, A, C, A, all with contact: every run of A gives identical frames, whatever ran before."""
    runs = [world.rollout(waypoints(world, g)) for g in (SWEEP_A, SWEEP_B, SWEEP_A, SWEEP_C, SWEEP_A)]
    assert all(r.feasible and r.touched.any() for r in runs), [(r.reason, r.touched) for r in runs]
    first = runs[0].frames
    for again in (runs[2].frames, runs[4].frames):
        assert len(again) == len(first)
        for field in ("images", "state", "action", "ee_pos", "object_poses", "contacts"):
            assert np.array_equal(getattr(again, field), getattr(first, field)), field
    assert not np.array_equal(runs[1].final_poses, runs[0].final_poses)  # B really did something else


def test_joint_target_executes_and_returns_home(world):
    w = world
    rng = np.random.default_rng(3)
    for _ in range(50):
        goal = rng.uniform(w.kin.lower, w.kin.upper)
        if not w.collision.in_collision(goal[None])[0]:
            break
    else:
        pytest.fail("no collision-free joint target in 50 draws")
    r = w.rollout(Command("joint_target", goal))
    assert r.feasible, r.reason
    assert r.ee_targets is None and r.planner in ("direct", "rrtconnect")
    np.testing.assert_allclose(r.joint_path[0], w.home)
    np.testing.assert_allclose(r.joint_path[-1], w.home)
    assert np.abs(r.joint_path - goal).max(axis=1).min() < 1e-9
    f = r.frames
    assert np.abs(f.state - goal).max(axis=1).min() < 0.05  # tracked to the target during the dwell
    np.testing.assert_allclose(f.state[-1], w.home, atol=1e-4)
    np.testing.assert_allclose(f.state[-2], w.home, atol=1e-2)
    assert (f.action >= w.kin.lower - 1e-5).all() and (f.action <= w.kin.upper + 1e-5).all()


def test_joint_target_rollout_is_repeatable(world):
    w = world
    goal = w.home + np.array([0.6, 0.5, 0.4, 0.5, 0.3, 0.3, 0.2])
    a = w.rollout(Command("joint_target", goal))
    b = w.rollout(Command("joint_target", goal))
    assert a.feasible and b.feasible
    np.testing.assert_array_equal(a.frames.state, b.frames.state)
    np.testing.assert_array_equal(a.frames.images, b.frames.images)


@pytest.mark.parametrize(
    ("kind", "values", "reason"),
    [
        ("ee_waypoints", TABLE_TARGET, "target_in_collision"),
        ("ee_waypoints", FAR_TARGET, "out_of_reach"),
        ("joint_target", None, "target_in_collision"),
    ],
)
def test_infeasible_rollouts_have_no_frames(world, kind, values, reason):
    w = world
    if kind == "ee_waypoints":
        command = waypoints(w, values)
    else:  # the tool 10 cm inside the table
        seeds = np.vstack([w.home, np.random.default_rng(4).uniform(w.kin.lower, w.kin.upper, (15, 7))])
        q, err = w.kin.inverse_position(TABLE_TARGET[0] - [0, 0, 0.05], seeds, tol=1e-3)
        command = Command("joint_target", q[np.argmin(err)])
    r = w.rollout(command)
    assert not r.feasible and r.reason == reason and r.reason in REASONS
    assert r.frames is None and r.before_image is None and r.after_image is None
    assert r.touched is None and r.displacement is None and r.final_poses is None
    assert "total" in r.timings


def test_drive_targets_and_contact_scan_record_what_maniskill_s_controller_does_bit_for_bit(world):
    assert world._drive_joints is not None, "the tabletop arm's controller is driven directly"
    reference = ManiSkillDrivenWorld(get_task("noveb_tabletop"), seed=0)
    try:
        commands = [waypoints(world, p) for p in (PUSH_THROUGH_CAN, SWEEP_A, SWEEP_B, SWEEP_C, FREE_AIR)]
        rng = np.random.default_rng(5)
        commands += [Command("ee_waypoints", rng.uniform(0, 1, (int(rng.integers(1, 3)), 3))) for _ in range(6)]
        touching = 0
        for i, command in enumerate(commands):
            for w in (world, reference):
                w.rng = np.random.default_rng([3, i])
            fast, slow = world.rollout(command), reference.rollout(command)
            assert (fast.feasible, fast.reason) == (slow.feasible, slow.reason)
            if not fast.feasible:
                continue
            touching += bool(slow.touched.any())
            for name in ("state", "action", "ee_pos", "object_poses", "contacts", "images"):
                np.testing.assert_array_equal(getattr(fast.frames, name), getattr(slow.frames, name), err_msg=name)
            np.testing.assert_array_equal(fast.final_poses, slow.final_poses)
            np.testing.assert_array_equal(fast.touched, slow.touched)
        assert touching >= 4, "contact-rich movements among them"
    finally:
        reference.close()


def test_a_direct_return_home_is_shorter_and_ends_home(world):
    """`return_home = "direct"`: after the dwell the arm goes straight home in joint space (where that is free),
    not back through the waypoints; a one-waypoint movement planned as a straight line records the same."""
    direct = World(get_task("noveb_tabletop"), WorldSettings(return_home="direct"), seed=0)
    try:
        tour = waypoints(world, np.array([[0.55, 0.35, 1.05], [0.75, 0.0, 1.1], [0.55, -0.35, 1.05]]))
        a, b = world.rollout(tour), direct.rollout(tour)
        assert a.feasible and b.feasible, (a.reason, b.reason)
        out = a.joint_path[: (len(a.joint_path) + 1) // 2]  # retrace: the path out, then the same path back
        np.testing.assert_array_equal(a.joint_path, np.concatenate([out, out[::-1][1:]]))
        np.testing.assert_array_equal(b.joint_path, np.concatenate([out, world.home[None]]))  # direct: out, home
        assert len(out) > 2 and len(b.frames) < len(a.frames)
        np.testing.assert_allclose(b.frames.state[-1], world.home, atol=1e-4)
        one = waypoints(world, np.array([[0.7, 0.1, 1.0]]))
        c, d = world.rollout(one), direct.rollout(one)
        assert c.planner == "direct" and c.feasible
        for key in ("state", "action", "object_poses", "contacts"):
            np.testing.assert_array_equal(getattr(c.frames, key), getattr(d.frames, key))
    finally:
        direct.close()


@pytest.mark.parametrize("count_approach", [True, False])
def test_a_movement_out_longer_than_max_move_seconds_is_refused_after_planning(world, monkeypatch, count_approach):
    """The bound on an episode's cost: the path out is planned and timed at the arm's speed; longer than
    `max_move_seconds`, the attempt is infeasible ("too_long") without being simulated. With `count_approach =
    false` the way from home to the first waypoint does not count, so a tour starting on the table's far side
    is bounded like one starting near home."""
    import dataclasses

    s = dataclasses.replace(world.settings, count_approach=count_approach)
    monkeypatch.setattr(world, "settings", s)
    points = np.array([[0.55, 0.35, 1.05], [0.75, 0.0, 1.1], [0.55, -0.35, 1.05]])
    tour = waypoints(world, points)
    executed = world.rollout(tour)
    assert executed.feasible, executed.reason
    # its movement out in control steps: the planned path out (retraced back), timed at the arm's speed
    path_out = executed.joint_path[: (len(executed.joint_path) + 1) // 2]
    moving = float(len(world._timed_path(path_out)))
    # the first waypoint is where the tool reaches it first, by forward kinematics
    tool = world.kin.tool_position(path_out)
    first = int(np.argmax(np.linalg.norm(tool - points[0], axis=1) < 2 * s.ik_tolerance))
    assert 0 < first < len(path_out) - 1
    approach = np.abs(np.diff(path_out[: first + 1], axis=0)).max(axis=1).sum() / s.max_joint_speed
    assert approach > 0.5, "the tour starts across the table from home"
    counted = moving if count_approach else moving - approach * s.control_freq
    assert counted > 10
    monkeypatch.setattr(world, "settings", dataclasses.replace(s, max_move_seconds=(counted - 0.5) / s.control_freq))
    refused = world.rollout(tour)
    assert (refused.feasible, refused.reason, refused.frames) == (False, "too_long", None)
    assert "sim" not in refused.timings
    monkeypatch.setattr(world, "settings", dataclasses.replace(s, max_move_seconds=(counted + 0.5) / s.control_freq))
    again = world.rollout(tour)
    assert again.feasible
    np.testing.assert_array_equal(again.frames.state, executed.frames.state)
