"""Contact events between objects, the table and the floor (`babblegen.contact_events`): the pairs' names and order,
the dataset feature, the sidecar row's ``object_contacts`` and the report's count of episodes in which one object
touched another. Without the simulator (tests/test_contacts.py records them in a real push)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from babblegen.contact_events import contact_events, contact_pairs, had_object_contact, pair_names
from babblegen.dataset.schema import OBJECT_CONTACTS, features
from babblegen.exporters.lerobot_encoding import frame_columns
from babblegen.exporters.report_measures import object_contacts
from babblegen.exporters.sidecar import attempt_row
from babblegen.tasks import get_task
from babblegen.world.rollout import Command, Frames, Rollout

SLOTS = ["object_0", "object_1", "object_2"]


def test_pairs_in_slot_order_objects_then_table_then_floor():
    assert contact_pairs(3) == [(0, 1), (0, 2), (1, 2), (0, 3), (1, 3), (2, 3), (0, 4), (1, 4), (2, 4)]
    assert pair_names(SLOTS) == [
        "object_0|object_1",
        "object_0|object_2",
        "object_1|object_2",
        "object_0|table",
        "object_1|table",
        "object_2|table",
        "object_0|floor",
        "object_1|floor",
        "object_2|floor",
    ]
    assert pair_names(["a"]) == ["a|table", "a|floor"]
    assert len(pair_names([f"object_{i}" for i in range(6)])) == 15 + 12


@pytest.mark.parametrize("objects", [SLOTS, ["gray_box", "can", "blue_box", "ball"]], ids=["slots", "paper"])
def test_every_object_set_has_the_feature(objects):
    feats = features([f"joint_{i}" for i in range(7)], objects, 32, 32)
    n = len(objects)
    ft = feats[OBJECT_CONTACTS]
    assert ft["dtype"] == "float32" and ft["shape"] == (n * (n - 1) // 2 + 2 * n,)
    assert ft["names"] == pair_names(objects)
    assert feats["observation.contacts"]["names"] == objects  # the arm's contacts as before


def impulses_of_a_push() -> np.ndarray:
    """(8 frames, 9 pairs) of three objects: all three resting on the table from the start, object_0 pushed into
    object_2 in frames 3 and 4, object_2 falling to the floor in frame 6."""
    x = np.zeros((8, 9), dtype=np.float32)
    x[1:, 3:6] = 0.196  # N s: 0.2 kg on the table for 0.1 s
    x[3, 1], x[4, 1] = 0.02, 0.005
    x[6:, 8] = 0.196
    return x


def test_events_are_the_contacts_that_began_during_the_episode():
    events = contact_events(impulses_of_a_push(), SLOTS)
    assert list(events) == ["object_0|object_2", "object_2|floor"]
    assert events["object_0|object_2"] == {"first_frame": 3, "impulse": 0.025}
    assert events["object_2|floor"]["first_frame"] == 6
    assert events["object_2|floor"]["impulse"] == pytest.approx(2 * 0.196)
    with pytest.raises(ValueError, match="9"):
        contact_events(np.zeros((8, 4)), SLOTS)


def test_frame_columns_carry_the_impulses():
    t, x = 8, impulses_of_a_push()
    frames = Frames(np.zeros((t, 7)), np.zeros((t, 7)), np.zeros((t, 3)), np.zeros((t, 3, 7)), np.zeros((t, 3)), None)
    frames.object_contacts = x
    columns = frame_columns(frames, 10, features([f"j{i}" for i in range(7)], SLOTS, 8, 8))
    assert columns[OBJECT_CONTACTS].dtype == np.float32
    np.testing.assert_array_equal(columns[OBJECT_CONTACTS], x)


def sidecar_row(impulses: np.ndarray | None) -> dict:
    """The sidecar row of an executed movement of the paper's scene whose frames recorded ``impulses``."""
    task = get_task("noveb_tabletop")
    t = len(impulses) if impulses is not None else 8
    frames = Frames(np.zeros((t, 7)), np.zeros((t, 7)), np.zeros((t, 3)), np.zeros((t, 4, 7)), np.zeros((t, 4)), None)
    frames.object_contacts = impulses
    poses = np.tile([0.7, 0.0, 0.75, 1.0, 0.0, 0.0, 0.0], (4, 1))
    rollout = Rollout(
        Command("ee_waypoints", np.zeros((1, 3))),
        True,
        ee_targets=np.array([[0.7, 0.0, 0.9]]),
        frames=frames,
        touched=np.zeros(4, dtype=bool),
        displacement=np.zeros(4),
        start_poses=poses,
        final_poses=poses,
    )
    cand = SimpleNamespace(index=5, generation=1, kind="ee_waypoints", genome=np.zeros(3), parent=None, start=None)
    evaluation = SimpleNamespace(novelty=0.0, archived=False)
    return attempt_row(cand, rollout, None, evaluation, 0, "noveb", task)


def test_the_sidecar_row_holds_the_events_and_the_report_counts_object_contacts():
    names = pair_names(["gray_box", "can", "blue_box", "ball"])
    pushed = np.zeros((10, 14), dtype=np.float32)
    pushed[1:, 6:10] = 0.1  # every object on the table
    pushed[4, names.index("can|blue_box")] = 0.03
    fell = np.zeros_like(pushed)
    fell[1:, 6:10] = 0.1
    fell[7, names.index("ball|floor")] = 0.5
    rows = [sidecar_row(pushed), sidecar_row(fell), sidecar_row(np.zeros_like(pushed))]
    assert rows[0]["object_contacts"] == {"can|blue_box": {"first_frame": 4, "impulse": pytest.approx(0.03)}}
    assert rows[1]["object_contacts"] == {"ball|floor": {"first_frame": 7, "impulse": 0.5}}
    assert rows[2]["object_contacts"] == {}
    assert [had_object_contact(r) for r in rows] == [True, False, False]

    old = sidecar_row(None)  # a movement recorded before contact events: no field, no answer
    assert "object_contacts" not in old and had_object_contact(old) is None
    assert object_contacts(rows + [old, {"feasible": False}]) == {
        "object_contact_episodes": 1,
        "contact_events_per_pair": {"ball|floor": 1, "can|blue_box": 1},
    }
    assert object_contacts([old]) == {"object_contact_episodes": None, "contact_events_per_pair": None}
