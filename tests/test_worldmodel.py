"""The world-model evaluation's parts without the simulator: the arm filter, the step network's inputs and targets,
the outcome strata and the scores, each against numbers worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from babblegen.worldmodel.episodes import STRATA, EpisodeSet, Scene, outcomes
from babblegen.worldmodel.metrics import mean_displacement, score
from babblegen.worldmodel.model import ArmFilter, apply, features, object_state, targets

SCENE = Scene(
    task="t",
    objects=("box", "can", "ball"),
    shapes=("box", "cylinder", "sphere"),
    sizes=((0.05, 0.05, 0.05), (0.03, 0.06), (0.04,)),
    table=(0.45, 1.35, -0.6, 0.6),
    top=0.7,
    robot="pr2_like_arm",
)


def pose(x: float, y: float, z: float, yaw: float = 0.0, tilt: float = 0.0) -> list[float]:
    """x, y, z and the quaternion of a yaw about z, then a tilt about x."""
    cy, sy, ct, st = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(tilt / 2), np.sin(tilt / 2)
    return [x, y, z, cy * ct, cy * st, sy * st, sy * ct]


def episodes(first: list[list[list[float]]], final: list[list[list[float]]]) -> EpisodeSet:
    """Two-frame episodes from first and final poses."""
    n = len(first)
    poses = [np.array([a, b], dtype=np.float64) for a, b in zip(first, final, strict=True)]
    return EpisodeSet(
        scene=SCENE,
        source=np.array(["d"] * n),
        attempt=np.arange(n),
        explorer=np.array(["x"] * n),
        identity=np.array([str(i) for i in range(n)]),
        layout=np.array(["task"] * n),
        commands=[{"kind": "ee_waypoints", "genome": [[0.5, 0.5, 0.5]], "layout": None}] * n,
        actions=[np.zeros((2, 7))] * n,
        states=[np.zeros((2, 7))] * n,
        poses=poses,
    )


REST = [pose(0.8, 0.2, 0.75), pose(0.7, -0.1, 0.76), pose(1.1, -0.1, 0.74)]


def test_the_arm_filter_recovers_a_known_response():
    """Joints made by a known filter from random commands: the fit finds its coefficients and replays them."""
    rng = np.random.default_rng(0)
    coef = np.tile([0.5, 0.1, 0.3], (7, 1)) + rng.normal(0, 0.05, (7, 3))
    truth = ArmFilter(coef)
    actions = [rng.uniform(-1, 1, (40, 7)) for _ in range(5)]
    states = [truth.run(a, np.zeros(7)) for a in actions]
    fitted = ArmFilter.fit(actions, states)
    np.testing.assert_allclose(fitted.coef, coef, atol=1e-9)
    np.testing.assert_allclose(fitted.run(actions[0], np.zeros(7)), states[0], atol=1e-9)


def test_targets_and_apply_undo_each_other():
    rng = np.random.default_rng(1)
    now = object_state(np.array([REST]))
    after = now + rng.normal(0, 0.02, now.shape)
    after[..., 1:, 3] = now[..., 1:, 3]  # round objects keep no yaw
    motion, moving = targets(SCENE, now, after)
    assert moving.all()
    np.testing.assert_allclose(apply(SCENE, now, motion), after, atol=1e-6)


def test_features_see_the_scene_from_each_object():
    """Moving the whole scene, arm and objects alike, changes only the table's edges; turning a cube by its
    symmetry (90 degrees) changes nothing."""
    rng = np.random.default_rng(2)
    now = object_state(np.array([REST]))
    before = now - 0.003
    arm0, arm1 = rng.uniform(0.5, 1.0, (1, 6, 3)), rng.uniform(0.5, 1.0, (1, 6, 3))
    radii = np.full(6, 0.03)
    x, gap = features(SCENE, radii, now, before, arm0, arm1)
    shift = np.array([0.05, -0.03, 0.0, 0.0])
    x2, gap2 = features(SCENE, radii, now + shift, before + shift, arm0 + shift[:3], arm1 + shift[:3])
    k = len(SCENE.objects)
    edges = slice(k + 5, k + 9)  # after "which object" (k) and its own motion and height (5)
    keep = np.ones(x.shape[-1], dtype=bool)
    keep[edges] = False
    np.testing.assert_allclose(x[..., keep], x2[..., keep], atol=1e-4)
    np.testing.assert_allclose(gap, gap2, atol=1e-9)
    turned = now.copy()
    turned[:, 0, 3] += np.pi / 2
    before_turned = before.copy()
    before_turned[:, 0, 3] += np.pi / 2
    x3, _ = features(SCENE, radii, turned, before_turned, arm0, arm1)
    np.testing.assert_allclose(x3, x, atol=1e-4)


def test_outcome_strata():
    still = episodes([REST], [REST])
    one = episodes([REST], [[pose(0.85, 0.2, 0.75), REST[1], REST[2]]])
    two = episodes([REST], [[pose(0.85, 0.2, 0.75), pose(0.7, -0.05, 0.76), REST[2]]])
    toppled = episodes([REST], [[REST[0], pose(0.7, -0.1, 0.73, tilt=np.pi / 2), REST[2]]])
    rolled = episodes([REST], [[REST[0], REST[1], pose(1.2, -0.1, 0.74)]])
    off = episodes([REST], [[pose(1.5, 0.2, 0.05), REST[1], REST[2]]])
    got = [int(outcomes(e)[1][0]) for e in (still, one, two, toppled, rolled, off)]
    assert [STRATA[g] for g in got] == [
        "nothing_moved", "one_object", "several_objects", "toppled_rolled_off", "toppled_rolled_off",
        "toppled_rolled_off",
    ]  # fmt: skip
    assert outcomes(two)[0].tolist() == [[True, True, False]]


def test_scores_by_hand():
    """Two episodes: in the first the box moves 10 cm along x; in the second nothing moves. A prediction of 6 cm
    for the box errs 4 cm where "nothing moves" errs 10; a false move of the can in the second episode counts."""
    moved_box = [pose(0.9, 0.2, 0.75), REST[1], REST[2]]
    test = episodes([REST, REST], [moved_box, REST])
    pred = object_state(
        np.array([[pose(0.86, 0.2, 0.75), REST[1], REST[2]], [REST[0], pose(0.7, -0.05, 0.76), REST[2]]])
    )
    s = score(pred, test, mean=np.zeros((3, 2)))
    assert s["all"]["err_cm"] == pytest.approx(4.0)
    assert s["all"]["nothing_cm"] == pytest.approx(10.0)
    assert s["all"]["ratio"] == pytest.approx(0.4)
    # moves: truth {box in ep 0}, predicted {box in ep 0, can in ep 1}: F1 = 2 * 1 / (2 + 1)
    assert s["all"]["f1"] == pytest.approx(2 / 3)
    assert s["all"]["false_moves"] == pytest.approx(1 / 5)
    assert s["nothing_moved"]["false_moves"] == pytest.approx(1 / 3)
    assert s["one_object"]["f1"] == pytest.approx(1.0)
    assert s["macro"]["f1"] == pytest.approx(1.0)
    # against the training set's mean displacement: 8 cm along x for the box errs 2 cm
    train = episodes([REST], [[pose(0.88, 0.2, 0.75), REST[1], REST[2]]])
    np.testing.assert_allclose(mean_displacement(train)[0], [0.08, 0.0], atol=1e-9)
    s = score(pred, test, mean=mean_displacement(train))
    assert s["all"]["mean_cm"] == pytest.approx(2.0)
    assert s["all"]["mean_skill"] == pytest.approx(1 - 4.0 / 2.0)


def test_take_and_union_keep_episodes_together():
    a = episodes([REST, REST], [REST, REST])
    b = episodes([REST], [REST])
    both = EpisodeSet.union([a, b])
    assert len(both) == 3 and len(both.poses) == 3 and len(both.commands) == 3
    picked = both.take(np.array([2, 0]))
    assert picked.attempt.tolist() == [0, 0] and len(picked.actions) == 2


class StillModel:
    """Predicts that nothing moves."""

    def rollout(self, first, actions, joints0):
        return np.stack(first)


class Oracle(StillModel):
    """Predicts each candidate's true end (the candidates' actions carry their index)."""

    def __init__(self, task):
        self.task = task

    def rollout(self, first, actions, joints0):
        out = np.stack(first).copy()
        for i, a in enumerate(actions):
            g, c = int(a[0, 0]), int(a[0, 1])
            out[i, self.task.goal_object[g], :2] = self.task.final_xy[g, c]
        return out


def test_planning_scores_by_hand():
    """Two goals of four candidates: goal 0 is reached by candidates 0 and 2, goal 1 by candidate 0 alone, and
    candidate 3 of goal 1 is infeasible. A model that predicts nothing moves chooses at random among all (as
    expected success: 2/4 and 1/3); the oracle-like model always succeeds."""
    from babblegen.worldmodel.planning import PlanningSettings, PlanningTask, plan_scores

    first = object_state(np.array([REST, REST]))
    final = np.array(
        [[[0.9, 0.2], [0.5, 0.5], [0.91, 0.2], [0.6, 0.6]], [[0.7, 0.0], [0.7, -0.1], [0.2, 0.2], [np.nan] * 2]]
    )
    feasible = ~np.isnan(final[..., 0])
    actions = [[np.array([[g, c, 0, 0, 0, 0, 0]] * 3, dtype=float) for c in range(4)] for g in range(2)]
    task = PlanningTask(
        source=np.array(["d", "d"]),
        start=[None, None],
        goal_object=np.array([0, 1]),
        goal_xy=np.array([[0.9, 0.2], [0.7, 0.0]]),
        first=first,
        joints0=np.zeros((2, 7)),
        strata={"arm": np.array([True, False]), "object": np.array([False, True]), "far": np.array([False, False])},
        mutations=1,
        feasible=feasible,
        actions=actions,
        final_xy=final,
    )
    settings = PlanningSettings(planner="rank", candidates=4)
    still = plan_scores(StillModel(), task, settings)
    assert still["oracle"] == 1.0
    assert still["random"] == pytest.approx((2 / 4 + 1 / 3) / 2)
    assert still["model"] == pytest.approx(still["random"])
    assert still["strata"]["arm"]["rate"] == pytest.approx(2 / 4) and still["strata"]["object"]["rate"] == 1 / 3
    assert plan_scores(Oracle(task), task, settings)["model"] == 1.0
