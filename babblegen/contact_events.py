"""Contact events between the scene's objects, the table and the floor, as the world records them.

Every physics substep, the world sums each pair's contact impulses (`World._touching`); each recorded frame holds, per
pair, the magnitudes of those sums since the previous frame (N s; ``Frames.object_contacts``, the dataset's
``observation.object_contacts``). The pairs, in slot order (`contact_pairs`): every two objects, then each object with
the table, then each object with the floor, named ``object_0|object_1``, ``object_0|table``, ``object_0|floor``.

An episode's events (`contact_events`, the sidecar's ``object_contacts``): the pairs whose contact began during the
episode, each with the first frame that holds an impulse and its whole impulse. A pair already touching in the first
frame after the start (frame 1: every object on the table, two objects a start left leaning on each other) is not an
event; an object falling to the floor, or one object pushed into another, is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

TABLE, FLOOR = "table", "floor"
SEPARATOR = "|"


def contact_pairs(n_objects: int) -> list[tuple[int, int]]:
    """The recorded pairs as indices into the contact parties: objects ``0 .. n_objects - 1``, then the table
    (``n_objects``) and the floor (``n_objects + 1``). Every two objects (i < j, in slot order), then each object with
    the table, then each object with the floor."""
    table, floor = n_objects, n_objects + 1
    pairs = [(i, j) for i in range(n_objects) for j in range(i + 1, n_objects)]
    return pairs + [(i, table) for i in range(n_objects)] + [(i, floor) for i in range(n_objects)]


def pair_names(object_names: list[str]) -> list[str]:
    """The names of `contact_pairs`, ``a|b`` (``object_0|object_1``, ``object_0|table``, ``object_0|floor``)."""
    parties = [*object_names, TABLE, FLOOR]
    return [f"{parties[a]}{SEPARATOR}{parties[b]}" for a, b in contact_pairs(len(object_names))]


def is_object_pair(name: str) -> bool:
    """Whether a pair name is of two objects (neither the table nor the floor)."""
    return not ({TABLE, FLOOR} & set(name.split(SEPARATOR)))


def contact_events(impulses: np.ndarray, object_names: list[str]) -> dict[str, dict[str, Any]]:
    """The pairs whose contact began during the episode, from its per-frame impulses ``(T, n_pairs)`` (frame 0 holds
    none: nothing happened before it): ``{pair: {"first_frame": f, "impulse": N s summed over the episode}}``, in
    pair order. A pair with an impulse in frame 1 touched from the start and is left out."""
    impulses = np.asarray(impulses, dtype=np.float64)
    names = pair_names(object_names)
    if impulses.ndim != 2 or impulses.shape[1] != len(names):
        raise ValueError(
            f"impulses must be (frames, {len(names)}) for {len(object_names)} objects, got {impulses.shape}"
        )
    events = {}
    for k, name in enumerate(names):
        touching = np.flatnonzero(impulses[:, k] > 0)
        if len(touching) == 0 or touching[0] <= 1:
            continue
        events[name] = {"first_frame": int(touching[0]), "impulse": round(float(impulses[:, k].sum()), 6)}
    return events


def had_object_contact(row: dict[str, Any]) -> bool | None:
    """Whether a sidecar row's episode had a contact event between two objects (one object pushed into another, an
    object falling onto another); None for a row that does not record contact events (not executed, or written
    before they were recorded)."""
    events = row.get("object_contacts")
    if events is None:
        return None
    return any(is_object_pair(name) for name in events)
