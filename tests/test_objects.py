"""Object sets: draws as a function of seed and attempt, held-out objects apart from every varied draw, factors that
replay exactly, the geometry each shape reports, and bad settings refused (no simulator)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from babblegen.config import ConfigError, RunConfig
from babblegen.objects import (
    HELDOUT_SHAPES,
    VARIED_SHAPES,
    ObjectRanges,
    ObjectSampler,
    slot_task,
)
from babblegen.shapes import ObjectSpec
from babblegen.starts import Start, StartSampler
from babblegen.tasks import get_task

TASK = get_task("noveb_tabletop")


def _draws(object_set: str, n: int = 400, seed: int = 5) -> list[ObjectSpec]:
    sampler = ObjectSampler(object_set, 4, seed)
    return [o for a in range(n) for o in sampler.draw(a)]


def test_a_draw_is_a_function_of_seed_and_attempt():
    one, other = ObjectSampler("varied", 5, 7), ObjectSampler("varied", 5, 7)
    assert [o.factors() for o in one.draw(12)] == [o.factors() for o in other.draw(12)]
    assert one.draw(12) != one.draw(13)
    assert ObjectSampler("varied", 5, 8).draw(12) != one.draw(12)
    assert [o.name for o in one.draw(0)] == ["object_0", "object_1", "object_2", "object_3", "object_4"]


def test_varied_draws_span_what_the_issue_asks():
    objects = _draws("varied")
    shapes = {o.shape for o in objects}
    assert shapes == set(VARIED_SHAPES)  # six kinds, a compound (dumbbell) and a convex hull among them
    masses = np.array([o.mass for o in objects])
    friction = np.array([o.static_friction for o in objects])
    dynamic = np.array([o.dynamic_friction for o in objects])
    assert masses.max() / masses.min() >= 4
    assert friction.max() / friction.min() >= 2
    assert np.all(dynamic <= friction) and np.all(dynamic >= 0.6 * friction - 1e-6)
    assert len({tuple(o.color) for o in objects}) == len(objects)
    for o in objects:  # pushable and whole in view: no part wider than the table's start region allows
        assert 0.01 < o.half_height <= 0.08 and o.footprint_radius < 0.15


def test_heldout_objects_are_apart_from_every_varied_draw():
    ranges = ObjectRanges()
    varied, heldout = _draws("varied", 500), _draws("heldout", 500)
    assert set(VARIED_SHAPES).isdisjoint(HELDOUT_SHAPES)
    assert {o.shape for o in heldout} == set(HELDOUT_SHAPES)
    assert not {o.shape for o in varied} & {o.shape for o in heldout}
    for name, value in (("density", lambda o: o.density), ("static_friction", lambda o: o.static_friction)):
        low, middle, high = ranges.bands(name)
        v = np.array([value(o) for o in varied])
        h = np.array([value(o) for o in heldout])
        tol = 1e-3 * middle[1]  # stored values are rounded to 6 decimals
        assert np.all((v <= middle[0] + tol) | (v >= middle[1] - tol)), name
        assert np.all((h >= middle[0] - tol) & (h <= middle[1] + tol)), name
    # by construction: the bands are the range cut in three (density on a log scale)
    low, middle, high = ranges.bands("density")
    assert low[0] == pytest.approx(100.0) and high[1] == pytest.approx(1000.0)
    assert middle == pytest.approx((100 * 10 ** (1 / 3), 100 * 10 ** (2 / 3)))


def test_factors_round_trip_through_json_exactly():
    for o in _draws("varied", 30) + _draws("heldout", 30):
        back = ObjectSpec.from_factors(json.loads(json.dumps(o.factors())))
        assert back == o
        assert back.volume == o.volume and back.footprint_radius == o.footprint_radius


def test_geometry_by_hand():
    cube = ObjectSpec("c", "box", (0.05, 0.05, 0.05), (1, 0, 0, 1), 0.2, (0, 0))
    assert cube.volume == pytest.approx(1e-3) and cube.density == pytest.approx(200)
    assert cube.footprint_radius == pytest.approx(0.05 * np.sqrt(2)) and cube.half_height == 0.05
    capsule = ObjectSpec("p", "capsule", (0.02, 0.03), (1, 0, 0, 1), 0.1, (0, 0))
    assert capsule.volume == pytest.approx(np.pi * 0.02**2 * 0.06 + 4 / 3 * np.pi * 0.02**3)
    assert capsule.footprint_radius == pytest.approx(0.05) and capsule.half_height == 0.02
    ell = ObjectSpec("l", "ell", (0.06, 0.04, 0.01, 0.02), (1, 0, 0, 1), 0.1, (0, 0))
    parts = ell.parts()
    assert len(parts) == 2 and ell.volume == pytest.approx(8 * 0.06 * 0.01 * 0.02 + 8 * 0.01 * 0.04 * 0.02)
    corners = np.array([[p.offset[0] + sx * p.size[0], p.offset[1] + sy * p.size[1]]
                        for p in parts for sx in (-1, 1) for sy in (-1, 1)])  # fmt: skip
    # the bars span x in [-0.06, 0.06] and y in [-0.01, 0.09]; the origin is their bounding box's centre
    assert np.allclose(corners.min(axis=0), [-0.06, -0.05]) and np.allclose(corners.max(axis=0), [0.06, 0.05])
    hull = next(o for o in _draws("varied", 60) if o.shape == "hull")
    v = np.asarray(hull.vertices)
    assert np.allclose((v.max(axis=0) + v.min(axis=0)) / 2, 0, atol=1e-6)
    assert hull.half_height == pytest.approx(v[:, 2].max(), abs=1e-6)


def test_starts_carry_their_objects_and_keep_them_when_one_is_moved():
    task = slot_task(TASK, "varied", 6)
    sampler = StartSampler(task, 3, ObjectSampler("varied", 6, 3))
    start = sampler.draw(10)
    assert len(start.objects) == 6 and start.layout.shape == (6, 3)
    moved = sampler.move_one(start, 11)
    assert moved.objects == start.objects and not np.array_equal(moved.layout, start.layout)
    back = Start.from_dict(json.loads(json.dumps(start.to_dict())))
    assert back.objects == start.objects and back.key() == start.key()
    other = Start(start.layout, 10, objects=sampler.draw(12).objects)
    assert other.key() != start.key()  # the same layout with other objects is another start
    # footprints keep the task's gap
    radius = np.array([o.footprint_radius for o in start.objects])
    xy = start.layout[:, :2]
    for i in range(6):
        for j in range(i):
            assert np.hypot(*(xy[i] - xy[j])) >= radius[i] + radius[j] + task.starts.gap - 1e-9


def test_paper_objects_leave_the_task_and_its_starts_as_they_were():
    assert slot_task(TASK, "paper", 4) is TASK
    plain, with_none = StartSampler(TASK, 4), StartSampler(TASK, 4, None)
    assert np.array_equal(plain.draw(3).layout, with_none.draw(3).layout) and plain.draw(3).objects is None


@pytest.mark.parametrize(
    ("world", "message"),
    [
        ({"objects": "paper", "num_objects": 5}, "paper's four objects"),
        ({"objects": "varied", "num_objects": 0}, "1 to 8"),
        ({"objects": "varied", "num_objects": 9}, "1 to 8"),
        ({"objects": "varied", "starts": "fixed"}, "needs --starts varied"),
        ({"objects": "varied", "object_ranges": {"size": [0.0, 0.04]}}, "must be > 0"),
        ({"objects": "varied", "object_ranges": {"density": [-5.0, 100.0]}}, "must be > 0"),
        ({"objects": "varied", "object_ranges": {"static_friction": [-0.1, 0.5]}}, "must be >= 0"),
        ({"objects": "varied", "object_ranges": {"density": [500.0, 100.0]}}, "low above its high"),
        ({"objects": "marbles"}, "unknown object set"),
        ({"objects": "varied", "num_objects": 8, "object_ranges": {"size": [0.07, 0.08]}}, "no place for"),
    ],
)
def test_bad_object_settings_are_refused(world, message):
    with pytest.raises(ConfigError, match=message):
        RunConfig.from_dict({"world": world}).validate()
