"""The world-model evaluation's parts without the simulator: the arm filter, the step network's inputs and targets,
the outcome strata and the scores, each against numbers worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic import episode_set

from babblegen.shapes import ObjectSpec
from babblegen.worldmodel.arm import ArmFilter
from babblegen.worldmodel.baseline import apply, features, push_frame, targets
from babblegen.worldmodel.episodes import (
    PROPERTIES,
    PROPERTY,
    STRATA,
    EpisodeSet,
    Scene,
    episode_objects,
    object_vector,
    outcomes,
)
from babblegen.worldmodel.metrics import in_true_units, mean_displacement, score
from babblegen.worldmodel.poses import object_state

GRAY = (0.5, 0.5, 0.5, 1.0)
CUBE = ObjectSpec("box", "box", (0.05, 0.05, 0.05), GRAY, 0.2, (0.8, 0.2))
SCENE = Scene(
    task="t",
    specs=(
        CUBE,
        ObjectSpec("can", "cylinder", (0.03, 0.06), GRAY, 0.1, (0.7, -0.1)),
        ObjectSpec("ball", "sphere", (0.04,), GRAY, 0.05, (1.1, -0.1)),
    ),
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
    return episode_set(SCENE, poses, [np.zeros((2, 7))] * n, [np.zeros((2, 7))] * n, ["task"] * n, [[0.5, 0.5, 0.5]])


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
    frame = rng.uniform(-np.pi, np.pi, now.shape[:2])
    motion, moving = targets(SCENE, now, after, None, frame)
    assert moving.all()
    np.testing.assert_allclose(apply(now, motion, frame), after, atol=1e-6)


def test_features_see_the_scene_from_each_object():
    """Moving the whole scene, arm and objects alike, changes only the table's edges; turning a cube by its
    symmetry (90 degrees) changes nothing."""
    rng = np.random.default_rng(2)
    now = object_state(np.array([REST]))
    before = now - 0.003
    arm0, arm1 = rng.uniform(0.5, 1.0, (1, 6, 3)), rng.uniform(0.5, 1.0, (1, 6, 3))
    radii = np.full(6, 0.03)
    yaw = push_frame(now, arm0, arm1, radii)
    x, gap = features(SCENE, radii, now, before, arm0, arm1, None, yaw)
    shift = np.array([0.05, -0.03, 0.0, 0.0])
    x2, gap2 = features(SCENE, radii, now + shift, before + shift, arm0 + shift[:3], arm1 + shift[:3], None, yaw)
    k = len(SCENE.objects)
    edges = slice(k + 7, k + 11)  # after "which object" (k), its own motion, height and turn (7)
    keep = np.ones(x.shape[-1], dtype=bool)
    keep[edges] = False
    np.testing.assert_allclose(x[..., keep], x2[..., keep], atol=1e-4)
    np.testing.assert_allclose(gap, gap2, atol=1e-9)
    turned = now.copy()
    turned[:, 0, 3] += np.pi / 2
    before_turned = before.copy()
    before_turned[:, 0, 3] += np.pi / 2
    x3, _ = features(SCENE, radii, turned, before_turned, arm0, arm1, None, yaw)
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
    assert s["all"]["along"] == pytest.approx(0.6)  # 6 of the box's 10 cm along x
    assert s["nothing_moved"]["false_moves"] == pytest.approx(1 / 3)
    assert s["one_object"]["f1"] == pytest.approx(1.0)
    assert s["macro"]["f1"] == pytest.approx(1.0)
    # by shape, each shape's objects alone: the box moved once and was predicted to (F1 1, error 4 of 10 cm); the
    # can never moved and was predicted to move in one episode of two; the ball neither
    box, can, ball = (s["shapes"][k] for k in ("box", "cylinder", "sphere"))
    assert set(s["shapes"]) == {"box", "cylinder", "sphere"}
    assert (box["moved"], box["f1"], box["ratio"], box["false_moves"]) == (1, 1.0, pytest.approx(0.4), 0.0)
    assert can["moved"] == 0 and np.isnan(can["f1"]) and can["false_moves"] == pytest.approx(0.5)
    assert ball["moved"] == 0 and ball["false_moves"] == 0.0 and box["episodes"] == can["episodes"] == 2
    # against the training set's mean displacement: 8 cm along x for the box errs 2 cm
    train = episodes([REST], [[pose(0.88, 0.2, 0.75), REST[1], REST[2]]])
    np.testing.assert_allclose(mean_displacement(train)[0], [0.08, 0.0], atol=1e-9)
    s = score(pred, test, mean=mean_displacement(train))
    assert s["all"]["mean_cm"] == pytest.approx(2.0)
    assert s["all"]["mean_skill"] == pytest.approx(1 - 4.0 / 2.0)


def test_ends_in_units_of_the_true_move():
    """A true move of 10 cm along +y: a prediction of 5 cm along it is half way, one of 2 cm along -x is across it to
    the right (negative), one of 20 cm along -y is twice as far the wrong way."""
    true = np.array([0.0, 0.1])
    predicted = np.array([[0.0, 0.05], [-0.02, 0.0], [0.0, -0.2], [0.03, 0.1]])
    units = in_true_units(predicted, np.broadcast_to(true, predicted.shape))
    np.testing.assert_allclose(units, [[0.5, 0.0], [0.0, 0.2], [-2.0, 0.0], [1.0, -0.3]], atol=1e-12)


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


def vector(spec: ObjectSpec) -> dict[str, float]:
    return dict(zip(PROPERTIES, object_vector(spec).tolist(), strict=True))


def test_the_property_vector_of_known_objects():
    """A cube of 0.05 m half extents (10 cm edges) and 0.2 kg: 1 litre, density 200 kg/m^3, a footprint of radius
    0.05 * sqrt(2), the same after a quarter turn; PhysX's default material."""
    v = vector(CUBE)
    assert [name for name in PROPERTIES if name.startswith("shape_") and v[name]] == ["shape_box"]
    assert sum(v[f"shape_{s}"] for s in ("box", "cylinder", "sphere", "capsule", "dumbbell", "ell", "tee", "hull")) == 1
    assert v["footprint_radius"] == pytest.approx(0.0707107, abs=1e-6)
    assert v["half_height"] == pytest.approx(0.05)
    assert [v["half_extent_x"], v["half_extent_y"], v["half_extent_z"]] == pytest.approx([0.05, 0.05, 0.05])
    assert v["volume"] == pytest.approx(1e-3)
    assert v["mass"] == pytest.approx(0.2)
    assert v["density"] == pytest.approx(200.0)
    assert (v["static_friction"], v["dynamic_friction"], v["restitution"]) == pytest.approx((0.3, 0.3, 0.0))
    assert v["yaw_symmetry"] == pytest.approx(np.pi / 2)
    # a flat box 8 x 4 x 6 cm of 0.096 kg, own material: 192 cm^3, 500 kg/m^3, the same after a half turn only
    flat = vector(ObjectSpec("b", "box", (0.04, 0.02, 0.03), GRAY, 0.096, (0, 0), 0.8, 0.5, 0.4))
    assert flat["footprint_radius"] == pytest.approx(np.hypot(0.04, 0.02))
    assert flat["volume"] == pytest.approx(1.92e-4) and flat["density"] == pytest.approx(500.0)
    assert (flat["static_friction"], flat["dynamic_friction"], flat["restitution"]) == (0.8, 0.5, 0.4)
    assert flat["yaw_symmetry"] == pytest.approx(np.pi)
    # an upright can of radius 3 cm, 12 cm tall: pi * 9 * 12 cm^3, turns freely
    can = vector(SCENE.specs[1])
    assert can["volume"] == pytest.approx(np.pi * 0.03**2 * 0.12)
    assert [can["half_extent_x"], can["half_extent_y"], can["half_extent_z"]] == pytest.approx([0.03, 0.03, 0.06])
    assert can["half_height"] == pytest.approx(0.06) and can["yaw_symmetry"] == 0.0
    # a capsule lying along x, radius 2 cm, straight part 6 cm: 8 cm from end to end, the same after a half turn
    capsule = vector(ObjectSpec("c", "capsule", (0.02, 0.03), GRAY, 0.1, (0, 0)))
    assert [capsule["half_extent_x"], capsule["half_extent_y"], capsule["half_extent_z"]] == pytest.approx(
        [0.05, 0.02, 0.02]
    )
    assert capsule["footprint_radius"] == pytest.approx(0.05) and capsule["half_height"] == pytest.approx(0.02)
    assert capsule["volume"] == pytest.approx(np.pi * 0.02**2 * 0.06 + 4 / 3 * np.pi * 0.02**3)
    assert capsule["yaw_symmetry"] == pytest.approx(np.pi)
    # a tee: a bar 10 x 2 cm along x, one 2 x 6 cm along y from its middle, 4 cm tall; its bounding box (10 x 8 cm)
    # centred: the bar along x spans y -4 to -2 cm, so its far corners are sqrt(5^2 + 4^2) cm out; no symmetry
    tee = vector(ObjectSpec("t", "tee", (0.05, 0.03, 0.01, 0.02), GRAY, 0.1, (0, 0)))
    assert [tee["half_extent_x"], tee["half_extent_y"], tee["half_extent_z"]] == pytest.approx([0.05, 0.04, 0.02])
    assert tee["footprint_radius"] == pytest.approx(np.hypot(0.05, 0.04))
    assert tee["volume"] == pytest.approx(8 * 0.05 * 0.01 * 0.02 + 8 * 0.01 * 0.03 * 0.02)
    assert tee["half_height"] == pytest.approx(0.02) and tee["yaw_symmetry"] == pytest.approx(2 * np.pi)


def test_rows_made_before_objects_were_recorded_read_as_the_task_objects():
    """A run.json task of old (no materials: PhysX's default) and rows with and without their own objects."""
    run = {
        "task": {
            "name": "t",
            "robot_uid": "pr2_like_arm",
            "table": {"center": [0.9, 0.0, 0.35], "half_extents": [0.45, 0.6, 0.35]},
            "objects": [
                {"name": n, "shape": o.shape, "size": list(o.size), "color": list(GRAY), "mass": o.mass, "xy": [0, 0]}
                for n, o in zip(SCENE.objects, SCENE.specs, strict=True)
            ],
        }
    }
    scene = Scene.from_run(run)
    assert scene.objects == SCENE.objects and scene.table == SCENE.table and scene.top == pytest.approx(0.7)
    np.testing.assert_allclose(scene.properties, SCENE.properties)
    light = ObjectSpec("can", "cylinder", (0.02, 0.04), GRAY, 0.01, (0, 0), 0.9, 0.6, 0.5)
    own = [CUBE.factors(), light.factors(), SCENE.specs[2].factors()]
    got = episode_objects(scene, [{"attempt": 0}, {"attempt": 1, "objects": own}])
    assert got.shape == (2, 3, len(PROPERTIES))
    np.testing.assert_allclose(got[0], SCENE.properties)
    np.testing.assert_allclose(got[1, 1], object_vector(light))
    assert got[1, 1, PROPERTY["restitution"]] == 0.5 and got[0, 1, PROPERTY["restitution"]] == 0.0
    # an EpisodeSet made without objects has the scene's in every episode; its rest heights and symmetries follow
    e = episodes([REST, REST], [REST, REST])
    np.testing.assert_allclose(e.half_heights, [[0.05, 0.06, 0.04]] * 2)
    np.testing.assert_allclose(e.yaw_symmetry, [[np.pi / 2, 0.0, 0.0]] * 2)


def test_each_episode_s_objects_set_its_frames_heights_and_strata():
    """The same poses with a flat box (symmetric under a half turn only) in the first slot instead of the cube:
    turning it a quarter turn changes what it sees, not the cube's; its property inputs differ. Ending 3.5 cm below
    the cube's resting height, the cube has left the table top (over 2 cm below it); the flat box, 6 cm tall, rests
    2 cm lower than the cube and has only moved; starting there, the cube has not left."""
    flat = ObjectSpec("box", "box", (0.04, 0.02, 0.03), GRAY, 0.096, (0, 0))
    props = np.stack([SCENE.properties, SCENE.properties])
    props[1, 0] = object_vector(flat)
    now = object_state(np.array([REST, REST]))
    before = now - 0.003
    rng = np.random.default_rng(3)
    arm0, arm1 = rng.uniform(0.5, 1.0, (1, 6, 3)).repeat(2, 0), rng.uniform(0.5, 1.0, (1, 6, 3)).repeat(2, 0)
    radii = np.full(6, 0.03)
    yaw = push_frame(now, arm0, arm1, radii)
    x, _ = features(SCENE, radii, now, before, arm0, arm1, props, yaw)
    turned, before_turned = now.copy(), before.copy()
    turned[:, 0, 3] += np.pi / 2
    before_turned[:, 0, 3] += np.pi / 2
    x2, _ = features(SCENE, radii, turned, before_turned, arm0, arm1, props, yaw)
    np.testing.assert_allclose(x2[0], x[0], atol=1e-4)  # the cube: the same
    assert np.abs(x2[1, 0] - x[1, 0]).max() > 0.1  # the flat box: not
    assert np.abs(x[1, 0] - x[0, 0]).max() > 0.1
    low = pose(0.8, 0.2, 0.715)
    e = episodes([REST, REST], [[low, REST[1], REST[2]]] * 2)
    e.objects = props
    assert [STRATA[s] for s in outcomes(e)[1]] == ["toppled_rolled_off", "one_object"]
    # a cube that settled 3.5 cm below its upright resting height (as a hull may, on another face) and stays there
    e = episodes([[low, REST[1], REST[2]]], [[low, REST[1], REST[2]]])
    assert STRATA[outcomes(e)[1][0]] == "nothing_moved"


def sliding(masses: list[float], rng: np.random.Generator, frames: int = 6) -> EpisodeSet:
    """Episodes where the arm stands still and, in a slot drawn at random, a cube of the given mass slides 1 cm a
    frame along x when lighter than 0.2 kg and stays when heavier; the other slots hold the scene's objects."""
    first_poses, poses, objects = [], [], []
    for mass in masses:
        slot = int(rng.integers(3))
        props = SCENE.properties.copy()
        props[slot] = object_vector(ObjectSpec("x", "box", (0.05, 0.05, 0.05), GRAY, mass, (0, 0)))
        xy = np.array([[0.6, -0.4], [0.9, 0.0], [1.2, 0.4]]) + rng.uniform(-0.05, 0.05, (3, 2))
        start = [pose(x, y, 0.7 + props[k, PROPERTY["half_height"]]) for k, (x, y) in enumerate(xy)]
        track = np.repeat(np.array([start]), frames, axis=0)
        if mass < 0.2:
            track[:, slot, 0] += 0.01 * np.arange(frames)
        first_poses.append(start)
        poses.append(track)
        objects.append(props)
    e = episodes(first_poses, first_poses)
    e.poses, e.objects = poses, np.stack(objects)
    e.actions = e.states = [np.zeros((frames, 7))] * len(masses)
    return e


def test_a_model_tells_objects_apart_by_their_properties():
    """Trained on cubes of 0.05 to 0.1 kg (they slide 5 cm) and 0.4 to 0.8 kg (they stay), in any slot, the baseline
    model predicts that an unseen 0.07 kg cube slides and an unseen 0.6 kg one in the same place stays."""
    import torch

    from babblegen.worldmodel.baseline import TrainSettings, WorldModel

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a network this small trains fastest on one thread, as the evaluation's workers do
    rng = np.random.default_rng(4)
    masses = np.where(rng.random(40) < 0.5, rng.uniform(0.05, 0.1, 40), rng.uniform(0.4, 0.8, 40))
    train = sliding(masses.tolist(), rng)
    # the same scene twice, the cube in the same slot and place: light, then heavy
    test = EpisodeSet.union([sliding([0.07], np.random.default_rng(5)), sliding([0.6], np.random.default_rng(5))])
    slot = int(np.flatnonzero(test.objects[0, :, PROPERTY["mass"]] == 0.07)[0])
    np.testing.assert_array_equal(test.poses[0][0], test.poses[1][0])
    try:
        model = WorldModel.fit(train, TrainSettings(steps=400, check=100, patience=3, hidden=64, batch=256))
        moved = model.predict(test)[:, slot, 0] - test.first[:, slot, 0]
    finally:
        torch.set_num_threads(threads)
    assert moved[0] == pytest.approx(0.05, abs=0.01) and abs(moved[1]) < 0.005
    # the same model, asked with the scene's objects instead (rollout's default), sees other objects
    first = [p[0] for p in test.poses]
    assert model.rollout(first, test.actions, [s[0] for s in test.states]).shape == (2, 3, 4)


def turn_about(v: np.ndarray, centre: np.ndarray, angle: float) -> np.ndarray:
    """(..., >=2) points turned by ``angle`` about the vertical through ``centre`` (x, y); a fourth column, a yaw,
    turns with them."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.array(v, dtype=np.float64, copy=True)
    dx, dy = v[..., 0] - centre[0], v[..., 1] - centre[1]
    out[..., 0], out[..., 1] = centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy
    if v.shape[-1] == 4:
        out[..., 3] = v[..., 3] + angle
    return out


def test_the_push_frame_points_from_the_arm_to_the_object_and_turns_with_the_scene():
    """A sphere passing 8 cm on the object's +x side pushes it along -x: its push frame points along -x (yaw pi).
    Turning the whole scene (objects, their yaws, the arm) about an object's centre changes nothing it sees in that
    frame but the table's edges, round or not, and its motion in that frame neither."""
    radii = np.array([0.03, 0.02])
    now = object_state(np.array([REST]))
    arm0 = now[:, :1, :3] + np.array([[[0.08, 0.0, 0.0], [0.3, 0.3, 0.3]]])
    assert abs(push_frame(now, arm0, arm0, radii)[0, 0]) == pytest.approx(np.pi)
    rng = np.random.default_rng(6)
    before = now - rng.uniform(-0.003, 0.003, now.shape)
    arm0 = now[:, 1:2, :3] + rng.uniform(-0.1, 0.1, (1, 2, 3))
    arm1 = arm0 + rng.uniform(-0.02, 0.02, (1, 2, 3))
    after = now + rng.normal(0, 0.01, now.shape)
    after[..., 1:, 3] = now[..., 1:, 3]  # round objects keep no yaw
    k = len(SCENE.objects)
    edges = np.zeros(features(SCENE, radii, now, before, arm0, arm1, None, np.zeros((1, k)))[0].shape[-1], dtype=bool)
    edges[k + 7 : k + 11] = True  # after "which object" (k), its own motion, height and turn (7)
    for slot in range(k):  # the cube, the can, the ball
        centre = now[0, slot, :2]
        angle = 0.7 + slot
        turned = [turn_about(v, centre, angle) for v in (now, before, arm0, arm1, after)]
        seen = []
        for state, last, a0, a1, end in ((now, before, arm0, arm1, after), turned):
            yaw = push_frame(state, a0, a1, radii)
            x, gap = features(SCENE, radii, state, last, a0, a1, None, yaw)
            seen.append((x[0, slot, ~edges], targets(SCENE, state, end, None, yaw)[0][0, slot], gap))
            np.testing.assert_allclose(apply(state, targets(SCENE, state, end, None, yaw)[0], yaw), end, atol=1e-6)
        np.testing.assert_allclose(seen[0][0], seen[1][0], atol=1e-4)
        np.testing.assert_allclose(seen[0][1][:3], seen[1][1][:3], atol=1e-4)
        np.testing.assert_allclose(seen[0][2], seen[1][2], atol=1e-9)


def test_a_goal_is_a_place_on_the_table_toppled_or_not():
    """Planning goals: each episode's most-moved object, moved at least 5 cm and ended on the table (its centre
    inside the table's edges and above its top), upright or toppled; one that fell to the floor, left the table's
    edges or moved too little is none."""
    from babblegen.worldmodel.planning import PlanningSettings, choose_goals

    ends = {
        "upright": pose(0.9, 0.2, 0.75),
        "toppled": pose(0.9, 0.2, 0.75, tilt=np.pi / 2),  # a 10 cm cube on its side rests as high as upright
        "toppled_low": pose(0.9, 0.2, 0.715, tilt=0.7),  # leaning on another face, lower than upright by 3.5 cm
        "fell": pose(1.2, 0.2, 0.05),  # on the floor, below the top, still over the table's footprint
        "off_edge": pose(1.4, 0.2, 0.75),
        "short": pose(0.83, 0.2, 0.75),  # 3 cm
    }
    e = episodes([REST] * len(ends), [[end, *REST[1:]] for end in ends.values()])
    none = np.zeros((len(e), 3), dtype=bool)
    goals = choose_goals(e, PlanningSettings(goals=10, object_share=0.0), flags=(none, none))
    assert goals == [(0, 0), (1, 0), (2, 0)]


def test_the_training_bar_counts_each_model_s_latest_steps_and_a_finished_model_whole():
    """The workers tell (model, steps taken); a count that arrives late and smaller changes nothing, and a model that
    stopped early counts all its steps once it is done."""
    from multiprocessing import get_context

    from babblegen.worldmodel.experiment import _StepsBar

    steps = _StepsBar(2, 100, get_context("spawn"))
    try:
        for item in [(0, 40), (1, 20), (0, 80), (0, 40)]:
            steps.queue.put(item)
        steps.wait()
        assert steps.bar.n == 80 + 20
        steps.finished(1, "  [1/2] a model")
        assert steps.bar.n == 80 + 100
    finally:
        steps.close()
