"""The arm's kinematic model, IK, sphere collision model and planner, checked against the simulator and
against each other. One World per module (building it costs a few seconds; nothing here renders)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from babblegen.tasks import get_task
from babblegen.world.planner import JointPlanner
from babblegen.world.rollout import REASONS, Command
from babblegen.world.world import World

TABLE_TARGET = np.array([0.7, -0.2, 0.65])  # 5 cm below the table top
FAR_TARGET = np.array([1.4, 0.0, 0.8])  # about 1.4 m from the shoulder, the arm is 0.9 m long
# Reachable (pan the shoulder towards it: 0.86 m from the shoulder-lift joint) and collision-free, though
# 0.967 m from where the shoulder-lift joint sits at the *home* pan angle (a reach check must pan).
REACHABLE_IN_FRONT = np.array([0.95, -0.15, 0.85])


@pytest.fixture(scope="module")
def world():
    w = World(get_task("noveb_tabletop"), seed=0)
    yield w
    w.close()


def random_configs(w: World, n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(w.kin.lower, w.kin.upper, (n, w.kin.dof))


def within_limits(w: World, q: np.ndarray) -> bool:
    return bool(np.all(q >= w.kin.lower - 1e-9) and np.all(q <= w.kin.upper + 1e-9))


def dense(path: np.ndarray, step: float = 0.005) -> np.ndarray:
    """States along a piecewise-linear joint path, at most `step` radians apart on any joint."""
    pieces = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        n = max(int(np.ceil(np.abs(b - a).max() / step)), 1)
        pieces.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.concatenate(pieces)


# --- forward kinematics and Jacobian -------------------------------------------------------------------
def test_fk_matches_simulator(world):
    w = world
    links = {link.entity.name: link for link in w._arm.links}
    chain = [name for name in w.kin.link_names if name in links]
    assert w.kin.link_names[-1] in chain and len(chain) == len(w.kin.link_names)
    qs = random_configs(w, 20, seed=1)
    try:
        for q in qs:
            w._arm.qpos = q
            np.testing.assert_allclose(w._tool.entity_pose.p, w.kin.tool_position(q)[0], atol=1e-3)
            rot, pos = w.kin.link_frames(q)
            for li, name in enumerate(w.kin.link_names):
                pose = links[name].entity_pose
                np.testing.assert_allclose(pose.p, pos[0, li], atol=1e-3, err_msg=name)
                np.testing.assert_allclose(pose.to_transformation_matrix()[:3, :3], rot[0, li], atol=1e-3)
    finally:
        w.reset()
    np.testing.assert_allclose(w._tool.entity_pose.p, w.kin.tool_position(w.home)[0], atol=1e-3)


def test_fk_batch_equals_single(world):
    qs = random_configs(world, 16, seed=2)
    batch = world.kin.tool_position(qs)
    single = np.concatenate([world.kin.tool_position(q) for q in qs])
    np.testing.assert_allclose(batch, single, atol=1e-12)


def test_jacobian_matches_finite_differences(world):
    kin = world.kin
    qs = random_configs(world, 10, seed=3)
    jac, tool = kin.jacobian(qs)
    assert jac.shape == (10, 3, kin.dof)
    np.testing.assert_allclose(tool, kin.tool_position(qs), atol=1e-12)
    eps = 1e-6
    for j in range(kin.dof):
        dq = np.zeros(kin.dof)
        dq[j] = eps
        fd = (kin.tool_position(qs + dq) - kin.tool_position(qs - dq)) / (2 * eps)
        np.testing.assert_allclose(jac[:, :, j], fd, atol=1e-6, err_msg=f"joint {j}")


# --- inverse kinematics ----------------------------------------------------------------------------------
def reachable_targets(w: World, n: int, seed: int) -> np.ndarray:
    """Tool positions of random collision-free configurations at least 5 cm above the table top."""
    qs = random_configs(w, 40 * n, seed)
    pos = w.kin.tool_position(qs)
    keep = (pos[:, 2] > w.task.table_top + 0.05) & ~w.collision.in_collision(qs)
    assert keep.sum() >= n
    return pos[keep][:n]


def test_ik_round_trip(world):
    w = world
    targets = reachable_targets(w, 80, seed=4)
    failures: Counter[str] = Counter()
    for target in targets:
        q, reason = w.solve_ik(target, w.home)
        if q is None:
            failures[reason] += 1
            continue
        err = np.linalg.norm(w.kin.tool_position(q)[0] - target)
        if err > 0.01:
            failures["error > 1 cm"] += 1
        elif not within_limits(w, q):
            failures["outside joint limits"] += 1
        elif w.collision.in_collision(q[None])[0]:
            failures["in collision"] += 1
    rate = 1 - sum(failures.values()) / len(targets)
    assert rate >= 0.9, f"IK round trip succeeded for {rate:.0%} of {len(targets)} targets; failures {failures}"


def test_reach_check_accepts_reachable_targets(world):
    w = world
    # The target is reachable: plain IK converges to a collision-free configuration ...
    seeds = np.vstack([w.home, random_configs(w, 15, seed=5)])
    q, err = w.kin.inverse_position(REACHABLE_IN_FRONT, seeds, tol=1e-3)
    ok = (err < w.settings.ik_tolerance) & ~w.collision.in_collision(q)
    assert ok.any()
    # ... and every tool position of a valid configuration should pass the reach check.
    targets = reachable_targets(w, 200, seed=6)
    outside = w.shoulder_distance(targets) > w.reach
    q, reason = w.solve_ik(REACHABLE_IN_FRONT, w.home)
    assert q is not None, f"solve_ik: {reason}"
    assert not outside.any(), f"{outside.mean():.0%} of reachable targets fail the reach check"


def test_ik_solution_stays_near_seed(world):
    """IK prefers the converged configuration nearest its seed: a target at a seed's own tool position
    returns (nearly) that seed."""
    w = world
    q0 = w.home + np.array([0.2, 0.1, 0.0, 0.2, 0.0, 0.1, 0.0])
    target = w.kin.tool_position(q0)[0]
    q, reason = w.solve_ik(target, q0)
    assert q is not None, reason
    assert np.abs(q - q0).max() < 0.05


def test_batched_ik_gives_each_target_its_own_answer(world):
    """`ArmPlanner.solve_iks` checks every target's candidates for collisions in one batch; each target still gets
    exactly what it gets alone: the same configuration to the bit, or the same reason there is none."""
    w = world
    rng = np.random.default_rng(7)
    targets = np.vstack([
        w.task.workspace.to_world(rng.random((24, 3))), TABLE_TARGET, FAR_TARGET, REACHABLE_IN_FRONT
    ])  # fmt: skip
    seeds = np.vstack([np.broadcast_to(w.home, (14, w.kin.dof)), random_configs(w, len(targets) - 14, 8)])
    batched = w.planning.solve_iks(targets, seeds)
    reasons = Counter(r for _, r in batched)
    assert reasons[""] >= 12 and reasons["target_in_collision"] + reasons["no_ik"] >= 1, reasons
    assert reasons["out_of_reach"] >= 1, reasons
    for (q, reason), target, seed in zip(batched, targets, seeds, strict=True):
        alone, alone_reason = w.solve_ik(target, seed)
        assert reason == alone_reason
        assert (q is None and alone is None) or np.array_equal(q, alone)


def test_collision_answers_do_not_depend_on_the_batch(world):
    """Large batches are checked in chunks (`collision.CHUNK`): every configuration's sphere centres and collision
    answer are those it has alone, across chunk borders."""
    from babblegen.world.collision import CHUNK

    w = world
    q = random_configs(w, 2 * CHUNK + 37, 9)
    hit = w.collision.in_collision(q)
    assert 0.2 < hit.mean() < 0.9  # both answers occur
    alone = np.array([any(v[0] for v in w.collision.collisions(c[None]).values()) for c in q])
    assert np.array_equal(hit, alone)
    centres = w.collision.sphere_centres(q)
    for i in (0, CHUNK - 1, CHUNK, 2 * CHUNK + 36):
        assert np.array_equal(centres[i], w.collision.sphere_centres(q[i : i + 1])[0])


# --- infeasible commands ----------------------------------------------------------------------------------
def test_target_inside_table_is_in_collision(world):
    w = world
    q, reason = w.solve_ik(TABLE_TARGET, w.home)
    assert q is None and reason == "target_in_collision"
    r = w.rollout(Command("ee_waypoints", w.task.workspace.to_norm(TABLE_TARGET)[None]))
    assert not r.feasible and r.reason == "target_in_collision" and r.frames is None
    np.testing.assert_allclose(r.ee_targets, TABLE_TARGET[None], atol=1e-12)


def test_target_out_of_reach(world):
    w = world
    assert w.shoulder_distance(FAR_TARGET) > 1.2 * w.reach
    r = w.rollout(Command("ee_waypoints", w.task.workspace.to_norm(FAR_TARGET)[None]))
    assert not r.feasible and r.reason == "out_of_reach" and r.frames is None
    # a reachable first waypoint does not rescue an unreachable second one
    two = np.array([[0.7, -0.3, 0.98], FAR_TARGET])
    r = w.rollout(Command("ee_waypoints", w.task.workspace.to_norm(two)))
    assert not r.feasible and r.reason == "out_of_reach"


def test_joint_target_hitting_table_is_infeasible(world):
    w = world
    qs = random_configs(w, 500, seed=7)
    hits = w.collision.collisions(qs)
    only_table = hits["table"] & ~np.logical_or.reduce([v for k, v in hits.items() if k != "table"])
    assert only_table.any()
    goal = qs[only_table][0]
    assert w.kin.tool_position(goal)[0, 2] < w.task.table_top + 0.2
    r = w.rollout(Command("joint_target", goal))
    assert not r.feasible and r.reason == "target_in_collision" and r.frames is None
    assert r.reason in REASONS


def test_joint_target_outside_limits_is_rejected(world):
    w = world
    goal = w.home.copy()
    goal[1] = w.kin.upper[1] + 0.1
    with pytest.raises(ValueError, match="limits"):
        w.rollout(Command("joint_target", goal))


# --- collision model -------------------------------------------------------------------------------------
def test_home_pose_is_collision_free(world):
    hits = world.collision.collisions(world.home[None])
    assert {"table", "floor", "self"} <= hits.keys()
    assert not any(v[0] for v in hits.values()), {k: bool(v[0]) for k, v in hits.items()}


def test_buried_tool_collides_with_table(world):
    w = world
    seeds = np.vstack([w.home, random_configs(w, 15, seed=8)])
    q, err = w.kin.inverse_position(TABLE_TARGET, seeds, tol=1e-3)
    assert (err < 2e-3).any(), "IK (ignoring collisions) did not reach the point inside the table"
    buried = q[err < 2e-3]
    assert w.collision.collisions(buried)["table"].all()
    assert w.collision.in_collision(buried).all()


def test_collision_model_separates_table_contact(world):
    """The tool just above the table top is free, and the same arm pushed down into the table collides."""
    w = world
    above = np.array([0.7, -0.3, w.task.table_top + 0.12])
    q, reason = w.solve_ik(above, w.home)
    assert q is not None, reason
    assert not w.collision.in_collision(q[None])[0]
    seeds = q[None]
    down, err = w.kin.inverse_position(above - [0, 0, 0.2], seeds, tol=1e-3)
    assert err[0] < 2e-3
    assert w.collision.collisions(down)["table"][0]


# --- planner -----------------------------------------------------------------------------------------------
def table_crossing_pair(w: World) -> tuple[np.ndarray, np.ndarray]:
    """Two collision-free configurations with the tool low over the table whose straight joint-space
    motion cuts through the table."""
    qs = random_configs(w, 3000, seed=9)
    pos = w.kin.tool_position(qs)
    low = qs[~w.collision.in_collision(qs) & (pos[:, 2] < w.task.table_top + 0.15) & (pos[:, 0] > 0.5)]
    t = np.linspace(0.0, 1.0, 200)[:, None]
    for i in range(len(low)):
        for j in range(i + 1, len(low)):
            a, b = low[i], low[j]
            hits = w.collision.collisions(a + t * (b - a))
            if hits["table"].mean() > 0.3:
                return a, b
    raise AssertionError("no table-crossing pair found")


def test_planner_goes_around_the_table(world):
    w = world
    a, b = table_crossing_pair(w)
    assert not w.collision.motion_free(a, b)
    res = w.planner.plan(a, b)
    assert res.path is not None, f"no plan in {res.seconds:.2f} s"
    assert res.planner == "rrtconnect"
    np.testing.assert_allclose(res.path[0], a, atol=1e-9)
    np.testing.assert_allclose(res.path[-1], b, atol=1e-9)
    states = dense(res.path)
    assert within_limits(w, states)
    hits = w.collision.collisions(states)
    assert not any(v.any() for v in hits.values()), {k: int(v.sum()) for k, v in hits.items()}


def test_planner_is_deterministic_whatever_ran_before(world):
    """Same query, same path: OMPL is seeded from the motion, bounded by iterations, not wall time, and its
    one-time set-up is absorbed, so a resumed run or another worker plans exactly as the original did."""
    w = world
    a, b = table_crossing_pair(w)
    first = w.planner.plan(a, b).path
    w.planner.plan(b, a)  # something else in between
    w.planner.plan(a, w.home)
    again = w.planner.plan(a, b).path
    assert first is not None and len(first) >= 3
    np.testing.assert_array_equal(first, again)
    # a planner whose very first query this is (a fresh worker process) plans it the same way
    fresh = JointPlanner(w.collision, max_iterations=w.planner.max_iterations, time_limit=w.planner.time_limit)
    np.testing.assert_array_equal(fresh.plan(a, b).path, first)


def test_planner_direct_when_free(world):
    w = world
    goal = w.home + np.array([0.1, 0.05, 0.0, 0.1, 0.2, 0.0, 0.3])
    assert not w.collision.in_collision(goal[None])[0]
    res = w.planner.plan(w.home, goal)
    assert res.planner == "direct" and len(res.path) == 2
    np.testing.assert_allclose(res.path, [w.home, goal])


def test_the_explorers_reach_test_is_the_planners(world):
    """`arm_info`'s ``in_reach`` (from the URDF alone, on normalised waypoints) refuses exactly the waypoints the
    planner would refuse as out of reach, so a redrawn mutation never spends an attempt on one."""
    from babblegen.assembly import arm_info

    w = world
    in_reach = arm_info(w.task)["in_reach"]
    points = np.random.default_rng(4).uniform(-0.6, 1.6, (400, 3))  # the workspace box and well beyond it
    verdicts = np.array([in_reach(p) for p in points])
    refused = w.shoulder_distance(w.task.workspace.to_world(points)) > w.reach
    np.testing.assert_array_equal(verdicts, ~refused)
    assert 0.1 < verdicts.mean() < 0.9, "the sample has waypoints on both sides of the reach"
    for p in points[~verdicts][:5]:
        assert w.solve_ik(w.task.workspace.to_world(p), w.home)[1] == "out_of_reach"
