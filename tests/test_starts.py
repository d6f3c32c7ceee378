"""Varied starts without the simulator: the layouts drawn, who draws them, how children inherit them, what a
clone is, the descriptor that compares before and after, and the settings that refuse bad input."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from babblegen.config import ConfigError, RunConfig, resumed_config
from babblegen.descriptors import ChangePHash, describe_rollout, make_descriptor
from babblegen.explorers import make_explorer
from babblegen.explorers.base import genome_key
from babblegen.scene import TaskSpec, layout_poses
from babblegen.starts import Start, StartSampler
from babblegen.tasks import get_task
from babblegen.world.settings import WorldSettings

START = np.array([0.5, 0.0, 0.5])
PI = np.pi
LIMITS = np.array([[-2.1, 0.6], [-0.4, 1.3], [-3.9, 0.8], [-2.3, 0.0], [-PI, PI], [-2.0, 0.0], [-PI, PI]])


@pytest.mark.parametrize("name", ["noveb_tabletop", "wall_tabletop"])
def test_layouts_stay_in_their_regions_apart_and_on_the_table(name):
    task = get_task(name)
    sampler = StartSampler(task, seed=3)
    radius = np.array([o.footprint_radius for o in task.objects])
    t = task.table
    for attempt in range(300):
        layout = sampler.draw(attempt).layout
        for (x, y, yaw), region in zip(layout, task.starts.regions, strict=True):
            assert region.x[0] <= x <= region.x[1] and region.y[0] <= y <= region.y[1]
            assert region.yaw[0] <= yaw <= region.yaw[1]
        gaps = np.hypot(*(layout[:, None, :2] - layout[None, :, :2]).transpose(2, 0, 1)) - radius[:, None] - radius
        assert gaps[~np.eye(len(radius), dtype=bool)].min() >= task.starts.gap - 1e-12
        assert np.all(np.abs(layout[:, 0] - t.center[0]) + radius <= t.half_extents[0])
        assert np.all(np.abs(layout[:, 1] - t.center[1]) + radius <= t.half_extents[1])
        for box in task.extra_obstacles:  # nothing starts inside or touching the wall
            dx = np.maximum(np.abs(layout[:, 0] - box.center[0]) - box.half_extents[0], 0)
            dy = np.maximum(np.abs(layout[:, 1] - box.center[1]) - box.half_extents[1], 0)
            assert np.all(np.hypot(dx, dy) >= radius + task.starts.gap - 1e-12)


@pytest.mark.parametrize("name", ["noveb_tabletop", "wall_tabletop"])
def test_every_start_region_lies_whole_in_the_head_camera_s_view(name):
    """The explorer sees the head image alone: an object that starts outside it could never be found."""
    from babblegen.world.cameras import look_at_cam2world, pinhole

    task = get_task(name)
    cam = task.camera
    world2cam = np.linalg.inv(look_at_cam2world(cam.eye, cam.target))
    k = pinhole(128, 128, cam.fov)
    for obj, region in zip(task.objects, task.starts.regions, strict=True):
        r, z = obj.footprint_radius, task.table_top
        corners = [
            (x, y, h)
            for x in (region.x[0] - r, region.x[1] + r)
            for y in (region.y[0] - r, region.y[1] + r)
            for h in (z, z + 2 * obj.half_height)
        ]
        cam_points = np.asarray(corners) @ world2cam[:3, :3].T + world2cam[:3, 3]
        uv = cam_points @ k.T
        uv = uv[:, :2] / uv[:, 2:]
        assert (uv >= 0).all() and (uv <= 128).all(), f"{obj.name} can start outside the image: {uv.round()}"


def test_layouts_are_wide_and_a_function_of_seed_and_attempt_alone():
    task = get_task("noveb_tabletop")
    a, b = StartSampler(task, 5), StartSampler(task, 5)
    assert np.array_equal(a.draw(17).layout, b.draw(17).layout)
    assert np.array_equal(a.draw(17).layout, a.draw(17).layout), "drawing again draws the same"
    assert not np.array_equal(a.draw(17).layout, a.draw(18).layout)
    assert not np.array_equal(a.draw(17).layout, StartSampler(task, 6).draw(17).layout)
    layouts = np.stack([a.draw(i).layout for i in range(500)])
    spread = layouts[:, :, :2].std(axis=0)
    assert spread.min() > 0.05, f"a few millimetres of jitter is not a new scene: std {spread}"


def test_layout_poses_rest_on_the_table_with_the_drawn_yaw():
    task = get_task("noveb_tabletop")
    layout = np.array([[0.7, 0.2, PI / 2], [0.7, -0.1, 0.0], [0.8, -0.4, -PI / 3], [1.1, 0.0, 0.3]])
    poses = layout_poses(task, layout)
    assert np.allclose(poses[:, 2], [task.table_top + o.half_height for o in task.objects])
    assert np.allclose(poses[0, 3:], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)])  # a quarter turn about z
    assert np.allclose(np.linalg.norm(poses[:, 3:], axis=1), 1.0)


def test_start_round_trips_and_identifies_genomes():
    start = Start(np.array([[0.1, 0.2, 0.3]]), 4)
    again = Start.from_dict(start.to_dict())
    assert np.array_equal(again.layout, start.layout) and again.drawn_at == 4
    genome = np.array([[0.5, 0.5, 0.5]])
    other = Start(np.array([[0.1, 0.2, 0.30000001]]), 4)
    assert genome_key("ee_waypoints", genome, start) == genome_key("ee_waypoints", genome, again)
    assert genome_key("ee_waypoints", genome, start) != genome_key("ee_waypoints", genome, other)
    assert genome_key("ee_waypoints", genome, start) != genome_key("ee_waypoints", genome)


def code_of(genome: np.ndarray, start: Start | None) -> np.ndarray:
    """A stand-in world whose outcome depends on the genome and the start."""
    shift = 0 if start is None else int(start.layout[0, 0] * 1000) % 7
    return np.array([1 << ((int(genome[-1, 0] * 40) + shift) % 64)], dtype=np.uint64)


def run_generations(ex, n: int) -> list:
    asked = []
    for _ in range(n):
        cands = ex.ask()
        asked += cands
        ex.tell(cands, [code_of(c.genome, c.start) for c in cands])
    return asked


def test_noveb_children_keep_their_parents_start_unless_a_start_mutation_draws_one():
    task = get_task("noveb_tabletop")
    sampler = StartSampler(task, 1)
    config = {"children": 24, "start_mutation_prob": 0.5, "start_mutation": "move_one"}
    ex = make_explorer("noveb", config, 1, LIMITS, START, starts=sampler)
    asked = run_generations(ex, 12)
    by_index = {c.index: c for c in asked}
    inherited = drawn = moved = 0
    for c in asked:
        assert c.start is not None
        if c.start.drawn_at == c.index and c.start.origin == "drawn":  # the first generation
            drawn += 1
            assert c.parent is None and np.array_equal(c.start.layout, sampler.draw(c.index).layout)
        elif c.start.drawn_at == c.index:  # a start mutation: the parent's layout with one object moved
            moved += 1
            parent = by_index[c.parent].start.layout
            assert (np.abs(c.start.layout - parent).sum(axis=1) > 0).sum() == 1
            assert np.array_equal(c.start.layout, sampler.move_one(by_index[c.parent].start, c.index).layout)
        else:
            inherited += 1
            # an inherited start was drawn for an earlier attempt of the lineage: the parent's own start
            assert c.parent is not None and c.start.drawn_at < c.index
            assert by_index[c.parent].start.drawn_at == c.start.drawn_at
    assert drawn > 0 and inherited > 0 and moved > 0
    keys = [genome_key(c.kind, c.genome, c.start) for c in asked]
    assert len(keys) == len(set(keys)), "the same genome from the same start is never attempted twice"
    clones = ex.last_clones
    assert all(c.start is not None for c in clones)


def test_by_default_only_new_genomes_draw_new_starts_so_copies_stay_free_clones():
    sampler = StartSampler(get_task("noveb_tabletop"), 3)
    ex = make_explorer("noveb", {"children": 24, "start_mutation_prob": 1.0}, 3, LIMITS, START, starts=sampler)
    asked = run_generations(ex, 6)
    genomes = {c.index: c.genome for c in asked}
    later = [c for c in asked if c.parent is not None]
    assert later and all(c.start.drawn_at == c.index for c in later), "every new genome drew a new start"
    assert all(np.array_equal(c.start.layout, sampler.draw(c.index).layout) for c in later), "a whole new layout"
    assert all(not np.array_equal(c.genome, genomes[c.parent]) for c in later if c.parent in genomes)
    assert len(ex.last_clones) > 0 and all(c.start is not None for c in ex.last_clones)
    every = make_explorer(
        "noveb",
        {"children": 24, "start_mutation_prob": 1.0, "start_mutation_of": "all_children"},
        3,
        LIMITS,
        START,
        starts=StartSampler(get_task("noveb_tabletop"), 3),
    )
    run_generations(every, 6)
    assert len(every.last_clones) == 0, "copies of a parent from a new start are new attempts"


def test_start_mutation_zero_keeps_every_lineage_on_its_first_start_and_makes_clones():
    sampler = StartSampler(get_task("noveb_tabletop"), 2)
    ex = make_explorer("noveb", {"children": 24, "start_mutation_prob": 0.0}, 2, LIMITS, START, starts=sampler)
    first = ex.ask()
    ex.tell(first, [code_of(c.genome, c.start) for c in first])
    later = run_generations(ex, 5)
    assert {c.start.drawn_at for c in later} <= {c.index for c in first}
    assert len(ex.last_clones) > 0, "unmutated children from their parent's start are clones, free as before"


def test_random_controls_draw_the_same_start_for_the_same_attempt_index():
    task = get_task("noveb_tabletop")
    kw = {"joint_limits": LIMITS, "start_norm": START}
    noveb = make_explorer("noveb", {"children": 12}, 0, starts=StartSampler(task, 9), **kw)
    random = make_explorer("random", None, 0, starts=StartSampler(task, 9), **kw)
    waypoints = make_explorer("random_waypoints", None, 0, starts=StartSampler(task, 9), **kw)
    a, b, c = noveb.ask(), random.ask(), waypoints.ask()
    for x, y, z in zip(a, b, c, strict=True):
        assert x.index == y.index == z.index
        assert np.array_equal(x.start.layout, y.start.layout) and np.array_equal(x.start.layout, z.start.layout)


def test_random_waypoints_draws_waypoint_lists_in_the_workspace_box_and_selects_nothing():
    ex = make_explorer("random_waypoints", {"population": 50}, 4, LIMITS, START)
    cands = ex.ask()
    assert all(c.kind == "ee_waypoints" and c.start is None and c.parent is None for c in cands)
    lengths = [len(c.genome) for c in cands]
    assert min(lengths) == 1 and max(lengths) == 4
    assert all(((c.genome >= 0) & (c.genome <= 1)).all() for c in cands)
    ex.tell(cands, [code_of(c.genome, None) for c in cands])
    assert all(c.parent is None for c in ex.ask()), "no selection: nothing descends from anything"


def test_checkpoint_holds_the_starts_and_a_resumed_explorer_continues_exactly():
    def make():
        sampler = StartSampler(get_task("noveb_tabletop"), 8)
        return make_explorer("noveb", {"children": 16, "lag": 1}, 8, LIMITS, START, starts=sampler)

    a = make()
    run_generations(a, 4)
    extra = a.ask()  # an open batch at the commit point
    import json

    state = json.loads(json.dumps(a.state_dict(), default=lambda o: o.tolist()))
    b = make()
    b.load_state_dict(state)
    assert [(c.index, c.start.drawn_at) for c in b.open_batches()[0]] == [(c.index, c.start.drawn_at) for c in extra]
    for ex in (a, b):
        ex.tell(extra, [code_of(c.genome, c.start) for c in extra])
    nxt_a, nxt_b = run_generations(a, 3), run_generations(b, 3)
    assert [(c.index, genome_key(c.kind, c.genome, c.start)) for c in nxt_a] == [
        (c.index, genome_key(c.kind, c.genome, c.start)) for c in nxt_b
    ]


def test_fixed_starts_draw_nothing_new():
    ex = make_explorer("noveb", {"children": 12}, 7, LIMITS, START)
    asked = run_generations(ex, 4)
    assert all(c.start is None for c in asked)


class _Rollout:
    def __init__(self, before, after):
        self.before_image, self.after_image = before, after


def test_change_descriptor_gates_flicker_and_measures_the_change():
    rng = np.random.default_rng(0)
    before = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    desc = ChangePHash(hash_size=8)
    nothing = describe_rollout(desc, _Rollout(before, before.copy()))
    assert not nothing.any(), "nothing changed: the one shared code"
    flicker = before.copy()
    flicker[10, 10:12] ^= 0xFF  # two pixels
    assert not describe_rollout(desc, _Rollout(before, flicker)).any(), "a 2-pixel flicker is not a change"
    faint = before.astype(np.int16)
    faint[20:40, 20:40] += 5  # a large but faint change (lighting noise), under the threshold
    assert not describe_rollout(desc, _Rollout(before, np.clip(faint, 0, 255).astype(np.uint8))).any()
    moved_left, moved_right = before.copy(), before.copy()
    moved_left[20:30, 5:15] = 0
    moved_right[20:30, 45:55] = 0
    left = describe_rollout(desc, _Rollout(before, moved_left))
    right = describe_rollout(desc, _Rollout(before, moved_right))
    assert left.any() and right.any() and not np.array_equal(left, right)
    # the same change on another background (another start) hashes the same: it is the change that counts
    other = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    other_moved = other.copy()
    other_moved[20:30, 5:15] = np.where(other[20:30, 5:15] > 127, 0, 255)
    ref = before.copy()
    ref[20:30, 5:15] = np.where(before[20:30, 5:15] > 127, 0, 255)
    a = describe_rollout(desc, _Rollout(before, ref))
    b = describe_rollout(desc, _Rollout(other, other_moved))
    assert np.bitwise_count(a ^ b).sum() <= 8
    with pytest.raises(ValueError, match="pass both"):
        desc(moved_left)
    assert make_descriptor(**desc.config()).config() == desc.config()


def test_auto_descriptor_follows_the_starts():
    assert RunConfig().descriptor_config() == {"name": "change16"}, "varied starts by default"
    assert RunConfig.from_dict({"world": {"starts": "fixed"}}).descriptor_config() == {"name": "phash16"}
    varied = RunConfig.from_dict({"world": {"starts": "varied"}})
    assert varied.descriptor_config() == {"name": "change16"}
    varied.validate()
    assert varied.descriptor == "change16", "run.json stores the descriptor chosen"
    chosen = RunConfig.from_dict({"descriptor": "phash16", "world": {"starts": "varied"}})
    assert chosen.descriptor_config() == {"name": "phash16"}


def test_bad_start_settings_are_refused_with_one_line():
    with pytest.raises(ConfigError, match=r"unknown starts 'sometimes'; choose one of: fixed, varied"):
        RunConfig.from_dict({"world": {"starts": "sometimes"}})
    from babblegen.tasks import TASKS
    from babblegen.tasks.registry import register_task

    spec = get_task("noveb_tabletop")
    bare = TaskSpec(**{**{f: getattr(spec, f) for f in spec.__dataclass_fields__}, "name": "bare", "starts": None})
    register_task(bare)
    try:
        with pytest.raises(ConfigError, match="task 'bare' declares no start distribution"):
            RunConfig.from_dict({"task": "bare", "world": {"starts": "varied"}}).validate()
        RunConfig.from_dict({"task": "bare", "world": {"starts": "fixed"}}).validate()  # fixed starts need none
    finally:
        TASKS.pop("bare")
    with pytest.raises(ValueError, match="probability"):
        RunConfig.from_dict({"noveb": {"start_mutation_prob": 1.5}})


def test_resume_refuses_other_starts_and_runs_stored_before_resume_fixed():
    stored = RunConfig(workers=1)
    stored.validate()
    data = stored.to_dict()
    with pytest.raises(ConfigError, match="cannot change 'starts'"):
        resumed_config(data, {"starts": "fixed"})
    del data["world"]["starts"], data["world"]["objects"]  # stored before either setting existed
    data["descriptor"] = "phash16"
    resumed = resumed_config(data)
    assert (resumed.world.starts, resumed.world.objects) == ("fixed", "paper")


def test_objects_default_to_varied_with_varied_starts_and_runs_stored_before_resume_paper():
    tabletop, wall = get_task("noveb_tabletop"), get_task("wall_tabletop")
    auto = WorldSettings(objects="auto")
    assert auto.for_task(tabletop).objects == "varied"
    assert replace(auto, starts="fixed").for_task(tabletop).objects == "paper"
    assert auto.for_task(wall).objects == "paper", "the wall scene's own objects are its point"
    assert WorldSettings(objects="heldout").for_task(tabletop).objects == "heldout", "a chosen set stays"
    for config in (RunConfig(workers=1), RunConfig.from_dict({"world": {"fps": 10}})):
        config.validate()
        assert config.world.objects == "varied", "a run's default"
    fixed = RunConfig.from_dict({"world": {"starts": "fixed"}, "descriptor": "phash16"})
    fixed.validate()
    assert fixed.world.objects == "paper"
    stored = RunConfig(workers=1)
    stored.validate()
    data = stored.to_dict()
    assert data["world"]["objects"] == "varied", "the resolved object set is stored, not 'auto'"
    del data["world"]["objects"]  # a run stored with varied starts before objects were drawn
    assert resumed_config(data).world.objects == "paper"


def end_scene(start: Start, attempt: int) -> np.ndarray:
    """A stand-in world's end scene: every object of the start pushed 1 cm along x per attempt index's parity."""
    poses = layout_poses(get_task("noveb_tabletop"), start.layout)
    poses[:, 0] += 0.01 * (1 + attempt % 2)
    return poses


def test_a_start_made_by_a_parent_s_movement_is_the_scene_it_left():
    """With start_from_end, start mutations begin from the scene the parent's movement left (recorded by the run
    loop, `record_end`), whole poses and all; an unknown scene, or one with an object off the table top, gives a
    new layout instead."""
    task = get_task("noveb_tabletop")
    sampler = StartSampler(task, 4)
    config = {"children": 24, "start_mutation_prob": 1.0, "start_from_end": 1.0}
    ex = make_explorer("noveb", config, 4, LIMITS, START, starts=sampler)
    asked = []
    for _ in range(5):
        cands = ex.ask()
        asked += cands
        for c in cands:
            sampler.record_end(c.index, end_scene(c.start, c.index))
        ex.tell(cands, [code_of(c.genome, c.start) for c in cands])
    made = [c for c in asked if c.start.origin == "made"]
    assert made and all(c.start.made_from == c.parent and c.start.drawn_at == c.index for c in made)
    for c in made:
        np.testing.assert_array_equal(c.start.poses, sampler.ends[c.parent])
        np.testing.assert_array_equal(c.start.placement, c.start.poses)
    again = Start.from_dict(made[0].start.to_dict())
    assert again.key() == made[0].start.key() and again.made_from == made[0].start.made_from
    assert genome_key("k", made[0].genome, made[0].start) != genome_key("k", made[0].genome, sampler.draw(0))
    # a scene with an object fallen off the table, or none recorded: a whole new layout for the attempt
    fallen = sampler.ends[made[0].parent].copy()
    fallen[1, 2] = 0.05
    sampler.record_end(10_000, fallen)
    for source in (10_000, 20_000):
        start = sampler.made(source, 77)
        assert start.origin == "drawn" and np.array_equal(start.layout, sampler.draw(77).layout)
    # 0 breeds exactly as before
    plain = make_explorer("noveb", {"children": 24}, 4, LIMITS, START, starts=StartSampler(task, 4))
    zero = make_explorer(
        "noveb", {"children": 24, "start_from_end": 0.0}, 4, LIMITS, START, starts=StartSampler(task, 4)
    )
    assert [c.start.to_dict() for c in run_generations(plain, 4)] == [
        c.start.to_dict() for c in run_generations(zero, 4)
    ]
