"""The learned simulator against answers known by construction, without the physics simulator: episodes where the
real arm (its kinematics and collision spheres) sweeps its tool through a box, and the box moves by a scripted rule
(pushed ahead of every sphere that reaches its rear face, when light; not at all, when heavy). A tiny ensemble
trained on a few of them must say where held-out pushes send the box."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from synthetic import episode_set

from babblegen.shapes import ObjectSpec
from babblegen.tasks import get_robot, get_task
from babblegen.world.planning import ArmPlanner
from babblegen.world.settings import WorldSettings
from babblegen.worldmodel import contact_graph as cg
from babblegen.worldmodel.arm import ArmSpheres
from babblegen.worldmodel.episodes import EpisodeSet, EvaluationError, Scene, object_vector
from babblegen.worldmodel.poses import quat_multiply, rotate
from babblegen.worldmodel.simulator import FORMAT, GraphSettings, LearnedSimulator, first_moving_frames, surfaces

TASK = get_task("noveb_tabletop")
ROBOT = get_robot(TASK.robot_uid)
HOME = np.asarray(ROBOT.home_qpos, dtype=np.float64)
TOP = TASK.table_top
HALF = 0.04  # the cube's half extent
GRAY = (0.5, 0.5, 0.5, 1.0)
FAR = ObjectSpec("far", "sphere", (0.03,), GRAY, 0.1, (0, 0))
SCENE = Scene(
    task="t",
    specs=(ObjectSpec("box", "box", (HALF, HALF, HALF), GRAY, 0.1, (0.8, 0.0)), FAR),
    table=(0.45, 1.35, -0.6, 0.6),
    top=TOP,
    robot=TASK.robot_uid,
)
LIGHT, HEAVY = 0.5, 2.0  # kg: a cube lighter than 1 kg is pushed, a heavier one stays


@pytest.fixture(scope="module")
def planner() -> ArmPlanner:
    return ArmPlanner(TASK, ROBOT, HOME, WorldSettings())


def cube(mass: float) -> ObjectSpec:
    return ObjectSpec("box", "box", (HALF, HALF, HALF), GRAY, mass, (0, 0))


def push(planner: ArmPlanner, centre: tuple[float, float], angle: float, mass: float, offset: float = 0.0) -> dict:
    """One episode: the tool sweeps at the cube's mid-height along ``angle`` (radians, seen from above) through its
    centre (shifted sideways by ``offset``), 16 cm from 12 cm before it; the cube (yaw ``angle``: a face towards the
    push) is pushed ahead of every arm sphere that reaches its rear face, when lighter than 1 kg."""
    d = np.array([np.cos(angle), np.sin(angle), 0.0])
    side = np.array([-d[1], d[0], 0.0])
    box = np.array([*centre, TOP + HALF])
    line = [box + side * offset + d * s for s in np.linspace(-0.14, 0.04, 12)]
    q, joints = HOME, []
    for target in [box + side * offset - d * 0.2 + [0, 0, 0.1]] + line:  # above and behind, then the sweep
        solved, reason = planner.solve_ik(target, q)
        assert solved is not None, reason
        q = solved
        joints.append(q)
    joints = np.array(joints)
    spheres = ArmSpheres(TASK.robot_uid)
    radii = spheres.radii
    track = [box.copy()]
    for c in spheres(joints)[1:]:
        pos = track[-1].copy()
        rel = c - pos
        along, across, up = rel @ d, rel @ side, rel[:, 2]
        behind = (along < 0) & (np.abs(across) < HALF + radii) & (np.abs(up) < HALF + radii)
        reach = np.max(np.where(behind, along + radii + HALF, 0.0), initial=0.0)
        if mass < 1.0 and reach > 0:
            pos = pos + d * reach
        track.append(pos)
    quat = np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])
    far = np.array([1.25, 0.5, TOP + 0.03, 1.0, 0.0, 0.0, 0.0])
    poses = np.array([[[*p, *quat], far] for p in track])
    actions = np.vstack([joints[1:], joints[-1:]])  # action[t] leads to state[t + 1]
    return {"actions": actions, "states": joints, "poses": poses, "objects": np.stack([object_vector(cube(mass)),
            object_vector(FAR)])}  # fmt: skip


def episodes(items: list[dict]) -> EpisodeSet:
    return episode_set(
        SCENE, [e["poses"] for e in items], [e["actions"] for e in items], [e["states"] for e in items],
        [str(i) for i in range(len(items))], [], np.stack([e["objects"] for e in items]),
    )  # fmt: skip


@pytest.fixture(scope="module")
def trained(planner: ArmPlanner) -> LearnedSimulator:
    """A tiny ensemble trained on light cubes pushed from many directions and places, and heavy ones that stay."""
    rng = np.random.default_rng(0)
    items = []
    for i in range(48):
        centre = (rng.uniform(0.7, 0.9), rng.uniform(-0.25, 0.05))
        items.append(push(planner, centre, rng.uniform(-0.6, 0.9), LIGHT if i % 3 else HEAVY, rng.uniform(-0.02, 0.02)))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return LearnedSimulator.fit(
            episodes(items), GraphSettings(members=2, hidden=32, steps=1500, check=250, patience=3, seed=1)
        )
    finally:
        torch.set_num_threads(threads)


def test_a_scripted_push_moves_the_box_along_the_push(planner: ArmPlanner, trained: LearnedSimulator):
    """Pushes the model never saw (other places and directions): the light cube ends where the script sends it,
    along the push, to within a fifth of the distance."""
    tests = [push(planner, (0.78, -0.12), 0.3, LIGHT), push(planner, (0.84, -0.02), -0.2, LIGHT)]
    e = episodes(tests)
    pred = trained.predict(e)
    for k, item in enumerate(tests):
        truth = item["poses"][-1, 0, :2] - item["poses"][0, 0, :2]
        moved = pred[k, 0, :2] - item["poses"][0, 0, :2]
        assert np.linalg.norm(truth) > 0.05
        assert moved @ truth / (np.linalg.norm(moved) * np.linalg.norm(truth)) > 0.95
        assert np.linalg.norm(moved - truth) < 0.2 * np.linalg.norm(truth)
        np.testing.assert_allclose(pred[k, 1, :3], item["poses"][0, 1, :3], atol=1e-9)  # nothing near: stays


def test_light_cubes_slide_and_heavy_ones_stay(planner: ArmPlanner, trained: LearnedSimulator):
    """The same push of an unseen light (0.4 kg) and an unseen heavy (2.5 kg) cube: the light one is pushed over
    5 cm, the heavy one moves under 1 cm."""
    e = episodes([push(planner, (0.8, -0.1), 0.2, 0.4), push(planner, (0.8, -0.1), 0.2, 2.5)])
    moved = np.linalg.norm(trained.predict(e)[:, 0, :2] - e.first[:, 0, :2], axis=-1)
    assert moved[0] > 0.05 and moved[1] < 0.01


def test_turning_the_scene_about_the_vertical_turns_the_prediction(planner: ArmPlanner, trained: LearnedSimulator):
    """Turning the arm's pan joint turns the whole arm about the pan axis; turning the objects about the same axis
    by the same angle turns the model's whole prediction (where the cube ends, its yaw), away from the table's
    edges: every input is read in the objects' push frames, and the table's edges only within 10 cm of them."""
    item = push(planner, (0.8, -0.1), 0.2, LIGHT)
    axis = np.asarray(planner.shell.pan_xy)
    pan = np.eye(7)[0] * 0.15
    tool0 = planner.kin.tool_position(item["states"][:1])[0]
    tool1 = planner.kin.tool_position(item["states"][:1] + pan)[0]
    turn = np.arctan2(*(tool1[:2] - axis)[::-1]) - np.arctan2(*(tool0[:2] - axis)[::-1])
    assert abs(turn) > 0.1
    c, s = np.cos(turn), np.sin(turn)
    rot = np.array([[c, -s], [s, c]])
    poses = item["poses"].copy()
    poses[..., :2] = (poses[..., :2] - axis) @ rot.T + axis
    poses[..., 3:] = quat_multiply(np.array([np.cos(turn / 2), 0.0, 0.0, np.sin(turn / 2)]), poses[..., 3:])
    turned = {**item, "actions": item["actions"] + pan, "states": item["states"] + pan, "poses": poses}
    pred = trained.predict(episodes([item, turned]))
    assert np.linalg.norm(pred[0, 0, :2] - item["poses"][0, 0, :2]) > 0.03  # it is a push
    np.testing.assert_allclose((pred[1, :, :2] - axis) @ rot + axis, pred[0, :, :2], atol=2e-4)
    assert np.angle(np.exp(1j * (pred[1, 0, 3] - pred[0, 0, 3] - turn))) == pytest.approx(0.0, abs=2e-3)


def test_surfaces_in_the_graph_are_the_objects_own():
    """The graph places each object's surface points by its pose: a cube's points lie on its faces in the world."""
    e = episodes([push_free()])
    surf = surfaces(e.objects)
    world = rotate(e.poses[0][0, 0, 3:], surf.points[0, 0]) + e.poses[0][0, 0, :3]
    rel = world - e.poses[0][0, 0, :3]
    np.testing.assert_allclose(np.abs(rel).max(axis=1), HALF, atol=1e-9)


def push_free() -> dict:
    """A still scene: the arm at home, nothing moves."""
    joints = np.repeat(HOME[None], 3, axis=0)
    far = np.array([1.25, 0.5, TOP + 0.03, 1.0, 0.0, 0.0, 0.0])
    box = np.array([0.8, -0.1, TOP + HALF, 1.0, 0.0, 0.0, 0.0])
    return {"actions": joints, "states": joints, "poses": np.array([[box, far]] * 3),
            "objects": np.stack([object_vector(cube(LIGHT)), object_vector(FAR)])}  # fmt: skip


def test_arm_edges_read_where_the_sphere_goes_the_frame_after_and_came_from_the_frame_before():
    """A sphere comes up to a cube's face this frame: its edges carry its next frame's motion and how near that
    sweep passes each edge's point, worked out here from the segment and the point. Going on into the cube, the
    sweep passes through the face (a negative gap); going back, it passes no nearer than where it is now. They also
    carry the frame before's motion, how near that sweep passed the point where the cube was then, and when."""
    e = episodes([push_free()])
    surf = surfaces(e.objects)
    box = e.poses[0][:1]  # (1, K, 7), the cube unturned
    r = np.array([0.02])
    x_face = box[0, 0, 0] - HALF
    a0 = np.array([[[x_face - 0.05, box[0, 0, 1], box[0, 0, 2]]]])
    a1 = np.array([[[x_face - 0.021, box[0, 0, 1], box[0, 0, 2]]]])  # 1 mm from the face
    ap = a0 - [0.03, 0.0, 0.01]  # the frame before: coming from further back and below
    for step in (0.06, -0.06):
        a2 = a1 + [step, 0.0, 0.0]
        g = cg.build(box, box, a0, a1, a2, r, surf.take(np.array([0])), SCENE.table, SCENE.top, ap)
        assert g.frame[0, 0] == pytest.approx(0.0, abs=1e-6)  # the push frame is the world's: the sphere comes from -x
        feats = g.arm[0, 0][g.arm_mask[0, 0]]
        assert len(feats) == cg.ARM_EDGES
        after, before = feats[:, 15:19], feats[:, 19:]  # the frame after's motion and gap; the frame before's
        came = np.tile([0.03 * cg.POS, 0, 0.01 * cg.POS], (len(feats), 1))
        np.testing.assert_allclose(before[:, :3], came, atol=1e-5)
        np.testing.assert_allclose(after[:, :3], np.tile([step * cg.POS, 0, 0], (len(feats), 1)), atol=1e-5)
        points = box[0, 0, :3] + feats[:, :3] / cg.POS  # each edge's surface point, from its own feature
        seg = a2[0, 0] - a1[0, 0]
        along = np.clip((points - a1[0, 0]) @ seg / (seg @ seg), 0, 1)
        gaps = np.linalg.norm(points - (a1[0, 0] + along[:, None] * seg), axis=1) - r[0]
        np.testing.assert_allclose(after[:, 3], np.minimum(gaps, cg.NEXT_NEAR) * cg.VEL, atol=1e-3)
        now = np.linalg.norm(points - a1[0, 0], axis=1) - r[0]
        if step > 0:
            assert after[:, 3].min() < -1.0  # through the face: over 1 cm inside the sphere's sweep
        else:
            np.testing.assert_allclose(after[:, 3], np.minimum(now, cg.NEXT_NEAR) * cg.VEL, atol=1e-3)
        seg = a0[0, 0] - ap[0, 0]
        when = np.clip((points - ap[0, 0]) @ seg / (seg @ seg), 0, 1)
        gaps = np.linalg.norm(points - (ap[0, 0] + when[:, None] * seg), axis=1) - r[0]
        np.testing.assert_allclose(before[:, 3], np.minimum(gaps, cg.NEXT_NEAR) * cg.VEL, atol=1e-3)
        np.testing.assert_allclose(before[:, 4], when, atol=1e-5)
        assert (before[:, 3] > 0).all() and (when == 1).all()  # it came up to the face: nearest at the frame's end


def test_a_saved_model_loads_back_and_predicts_the_same(planner: ArmPlanner, trained: LearnedSimulator, tmp_path):
    """`save` then `load` gives the same predictions and gate; a model saved in another format is refused with
    what to do about it."""
    path = trained.save(tmp_path / "model.pt")
    back = LearnedSimulator.load(path)
    e = episodes([push(planner, (0.8, -0.1), 0.3, LIGHT), push(planner, (0.75, -0.2), -0.4, HEAVY)])
    np.testing.assert_array_equal(back.predict(e), trained.predict(e))
    assert back.gate == trained.gate and back.trained_steps == trained.trained_steps
    old = torch.load(path, weights_only=False)
    old["format"] = FORMAT - 1
    torch.save(old, tmp_path / "old.pt")
    with pytest.raises(EvaluationError, match=f"format {FORMAT - 1}; this babblegen reads format {FORMAT}: train"):
        LearnedSimulator.load(tmp_path / "old.pt")
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(EvaluationError, match="is not a babblegen learned simulator"):
        LearnedSimulator.load(tmp_path / "other.pt")


def test_replayed_frames_move_an_object_as_recorded(planner: ArmPlanner, trained: LearnedSimulator):
    """`rollout_poses` with ``replay``: every frame replayed ends each object exactly where it was recorded. With the
    model's gate shut (it moves nothing), a push's first F frames of motion replayed leave the cube at its first
    pose plus the recorded shift over those F frames, worked out here from the poses; the far sphere, which never
    moves, has no frame marked and stays."""
    item = push(planner, (0.8, -0.1), 0.2, LIGHT)
    e = episodes([item])
    poses = item["poses"]
    args = ([poses[0]], e.actions, [item["states"][0]], e.objects)
    every = np.ones((len(poses) - 1, 2), dtype=bool)
    final, _ = trained.rollout_poses(*args, replay=(e.poses, [every]))
    np.testing.assert_allclose(final[0], poses[-1], atol=1e-9)

    still = copy.copy(trained)
    still.gate = np.inf
    start = int(np.flatnonzero(np.linalg.norm(np.diff(poses[:, 0, :3], axis=0), axis=-1) > 0)[0])
    for count in (1, 3):
        frames = first_moving_frames(poses, count)
        assert np.flatnonzero(frames[:, 0]).tolist() == list(range(start, start + count))
        assert not frames[:, 1].any()
        final, _ = still.rollout_poses(*args, replay=(e.poses, [frames]))
        shift = poses[start + count, 0, :3] - poses[start, 0, :3]
        assert np.linalg.norm(shift) > 0.005
        np.testing.assert_allclose(final[0, 0, :3], poses[0, 0, :3] + shift, atol=1e-9)
        np.testing.assert_allclose(final[0, 1], poses[0, 1], atol=1e-12)
    final, _ = still.rollout_poses(*args, replay=(e.poses, [first_moving_frames(poses, 0)]))
    np.testing.assert_allclose(final[0], poses[0], atol=1e-12)
