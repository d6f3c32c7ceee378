"""The committed reference (tests/reference/canonical.json, made by tests/reference/make_reference.py): canonical
rollouts re-simulated here record exactly the values recorded where it was made. What is promised: the same on any
x86-64 CPU with AVX2 and FMA (docs/reproducibility.md). And the machine fingerprint (babblegen.fingerprint).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from reference.make_reference import observed, simulate
from watch import WatchedWorld

from babblegen.descriptors import make_descriptor
from babblegen.evaluation import warm_up
from babblegen.fingerprint import SALT_ENV, fingerprint, rollout_digests
from babblegen.tasks import get_task
from babblegen.world.settings import WorldSettings

pytestmark = pytest.mark.filterwarnings("ignore:__array_wrap__ must accept context:DeprecationWarning")

REFERENCE = json.loads((Path(__file__).parent / "reference" / "canonical.json").read_text())
REGENERATE = "if recorded values are meant to change, regenerate it: python tests/reference/make_reference.py"


@pytest.fixture(scope="module")
def world():
    w = WatchedWorld(get_task(REFERENCE["task"]), WorldSettings(**REFERENCE["world"]))
    warm_up(w, None)
    yield w
    w.close()


@pytest.fixture(scope="module")
def drawn_world():
    """A World whose starts bring their own objects (the reference's ``objects_world`` settings)."""
    w = WatchedWorld(get_task(REFERENCE["task"]), WorldSettings(**REFERENCE["objects_world"]))
    warm_up(w, None)
    yield w
    w.close()


def run(w: WatchedWorld, spec: dict):
    return simulate(w, spec["waypoints"], spec["start"], spec["seed"], spec["attempt"], spec.get("objects"))


PAPER = [r for r in REFERENCE["rollouts"] if "objects" not in r]
DRAWN = [r for r in REFERENCE["rollouts"] if "objects" in r]


def test_the_reference_is_made_with_the_default_settings():
    assert WorldSettings(**REFERENCE["world"]) == WorldSettings(), f"the default world settings changed; {REGENERATE}"


def test_the_reference_covers_every_kind_of_contact():
    touches = [r["touches"] for r in PAPER]
    names = get_task(REFERENCE["task"]).object_names
    every_pair = {f"{a}-{b}" for i, a in enumerate(names) for b in names[i + 1 :]}
    assert {p for t in touches for p in t["pairs"]} == every_pair
    assert {o for t in touches for o in t["arm"]} >= set(names) - {"ball"}  # the ball stands out of reach
    assert any(t["can_toppled"] for t in touches)
    assert {r["start"] is None for r in PAPER} == {True, False}, "fixed and varied starts"


def differences(w: WatchedWorld, rollouts: list[dict]) -> list[str]:
    """Each rollout that records other values than the reference's, with the fields that differ."""
    differ = []
    for spec in rollouts:
        rollout = run(w, spec)
        got = rollout_digests(rollout, make_descriptor(spec["descriptor_name"]))
        fields = [f for f in spec["digests"] if got.get(f) != spec["digests"][f]]
        if observed(w, rollout) != spec["touches"]:
            fields.append("touches")
        if fields:
            differ.append(f"{spec['name']}: {', '.join(fields)}")
    return differ


def test_canonical_rollouts_record_the_reference_values_to_the_bit(world):
    differ = differences(world, PAPER)
    assert not differ, f"differ from tests/reference/canonical.json: {'; '.join(differ)}; {REGENERATE}"


def test_rollouts_with_drawn_objects_record_the_reference_values_to_the_bit(drawn_world):
    """Drawn objects, replayed from the stored spec: the objects of several shapes touched, pushed into each other."""
    from babblegen.objects import ObjectSampler
    from babblegen.shapes import ObjectSpec

    assert DRAWN, "the reference holds rollouts with drawn objects"
    for spec in DRAWN:  # the stored spec is what the run drew
        drawn = ObjectSampler("varied", len(spec["objects"]), spec["seed"]).draw(spec["attempt"])
        assert tuple(ObjectSpec.from_factors(o) for o in spec["objects"]) == drawn
    assert len({o["shape"] for r in DRAWN for o in r["objects"]}) >= 4
    assert any(t["touches"]["pairs"] for t in DRAWN) and all(t["touches"]["arm"] for t in DRAWN)
    differ = differences(drawn_world, DRAWN)
    assert not differ, f"differ from tests/reference/canonical.json: {'; '.join(differ)}; {REGENERATE}"


def test_a_difference_is_named_by_rollout_and_field(world):
    spec = json.loads(json.dumps(REFERENCE["rollouts"][1]))
    spec["digests"]["object_poses"] = "0" * 64
    assert differences(world, [spec]) == [f"{spec['name']}: object_poses"]


def test_the_fingerprint_is_the_same_every_time_and_changes_no_rollout_after_it(world, monkeypatch):
    spec = REFERENCE["rollouts"][0]
    before = rollout_digests(run(world, spec))
    t = time.perf_counter()
    first = fingerprint(world)
    seconds = time.perf_counter() - t
    assert fingerprint(world) == first and len(first) == 16
    assert rollout_digests(run(world, spec)) == before
    assert seconds < 5, seconds  # about 0.4 s on a quiet 2-core machine
    monkeypatch.setenv(SALT_ENV, "another kind of machine")
    assert fingerprint(world) != first
