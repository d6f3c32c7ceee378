"""Reading the simulator's contacts every physics substep: which objects the arm touches, and the impulse of each
recorded pair (`babblegen.contact_events`: two objects, an object and the table or the floor)."""

from __future__ import annotations

import math

import numpy as np

from babblegen.contact_events import contact_pairs


def _impulse(contact) -> tuple[float, float, float]:
    """The sum of a contact's points' impulses (N s, world frame), as PhysX reports them on its first body."""
    x = y = z = 0.0
    for p in contact.points:
        i, j, h = p.impulse.tolist()
        x, y, z = x + i, y + j, z + h
    return x, y, z


class ContactReader:
    """The contacts of one built scene of ``sim`` (a ManiSkill env; built again with the scene, `World._bind_scene`).
    ``arm_bodies``: the arm's moving links; ``object_bodies``: each object's rigid body, in the task's order;
    ``statics``: the table's and the floor's."""

    def __init__(self, sim, arm_bodies: set, object_bodies: list, statics: list):
        self._sim = sim
        # contact bodies as the simulator hands them back (one Python object per body): the arm's moving links,
        # and each object's index
        self.arm_bodies = arm_bodies
        self.object_of_body = {body: i for i, body in enumerate(object_bodies)}
        # the recorded pairs (`babblegen.contact_events`): the ordered bodies of a contact -> (pair, +1 in the
        # pair's order or -1 reversed, its objects' bodies, whether a body has several shapes); each pair's impulse
        # since the previous frame; and what `touching` last read from each contact of sleeping objects
        parties = [*object_bodies, *statics]
        self.pair_of: dict[tuple, tuple[int, float, tuple, bool]] = {}
        for k, (a, b) in enumerate(contact_pairs(len(object_bodies))):
            moving = tuple(parties[i] for i in (a, b) if i < len(object_bodies))
            # a body of several shapes (a dumbbell, an ell) touches another in one contact per pair of shapes
            several = any(len(parties[i].collision_shapes) > 1 for i in (a, b))
            self.pair_of[parties[a], parties[b]] = (k, 1.0, moving, several)
            self.pair_of[parties[b], parties[a]] = (k, -1.0, moving, several)
        self.impulse_since = [0.0] * (len(self.pair_of) // 2)
        self.asleep: dict[tuple, float | tuple[float, float, float]] = {}  # by bodies (magnitude) or shapes
        self._n_objects = len(object_bodies)

    def take_impulses(self) -> np.ndarray:
        """Each pair's impulse since the last call (N s, float32); counting starts afresh."""
        impulses = np.asarray(self.impulse_since, dtype=np.float32)
        self.impulse_since = [0.0] * len(self.impulse_since)
        return impulses

    def touching(self) -> np.ndarray:
        """Which objects the arm touches now: a contact between a moving arm link and the object with a point
        that pushes (non-zero impulse) or nearly touches (separation under 1 mm).

        In the same scan, each recorded pair's impulse in this substep (`babblegen.contact_events`: two objects, an
        object and the table or the floor) is added to ``impulse_since``: the magnitude of the sum of its contact
        points' impulses (N s; PhysX reports the normal impulse), oriented from the pair's first party. Reading
        the points is most of the scan's cost; a contact whose objects sleep (PhysX's: at rest for 0.4 s) keeps the
        impulses of its last solve, so once read asleep they are reused until an object wakes."""
        touched = np.zeros(self._n_objects, dtype=bool)
        arm, object_of, pair_of, asleep = self.arm_bodies, self.object_of_body, self.pair_of, self.asleep
        since, net = self.impulse_since, {}
        for contact in self._sim.scene.px.get_contacts():
            a, b = bodies = tuple(contact.bodies)
            pair = pair_of.get(bodies)
            if pair is not None:
                k, sign, moving, several = pair
                sleeping = moving[0].is_sleeping and (len(moving) == 1 or moving[1].is_sleeping)
                if several:  # one of the pair's contacts: their impulses are summed before the magnitude
                    key = tuple(contact.shapes) if sleeping or asleep else None
                    got = asleep.get(key) if sleeping else None
                    if got is None:
                        x, y, z = _impulse(contact)
                        got = (sign * x, sign * y, sign * z)
                    v = net.setdefault(k, [0.0, 0.0, 0.0])
                    v[0], v[1], v[2] = v[0] + got[0], v[1] + got[1], v[2] + got[2]
                else:  # the pair's one contact
                    key = bodies
                    got = asleep.get(key) if sleeping else None
                    if got is None:
                        got = math.hypot(*_impulse(contact))
                    since[k] += got
                if sleeping:
                    asleep[key] = got
                elif key and asleep:
                    asleep.pop(key, None)  # awake: read afresh when it sleeps again
                continue
            obj = object_of.get(b) if a in arm else object_of.get(a) if b in arm else None
            if obj is None or touched[obj]:
                continue
            if any(p.impulse.any() or p.separation < 1e-3 for p in contact.points):
                touched[obj] = True
        for k, v in net.items():
            since[k] += math.hypot(*v)
        return touched
