"""A World that watches its contacts, for the tests and tests/reference/make_reference.py."""

from __future__ import annotations

import numpy as np

from babblegen.world.world import World


class WatchedWorld(World):
    """A World that also records, every physics substep, the deepest contact any object has (PhysX's separation:
    negative is penetration) and which pairs of objects touch."""

    def _bind_scene(self) -> None:
        super()._bind_scene()
        self.deepest, self.pairs = 0.0, set()

    def _touching(self) -> np.ndarray:
        touched = super()._touching()
        object_of = self._contacts.object_of_body
        for contact in self.sim.scene.px.get_contacts():
            a, b = (object_of.get(body) for body in contact.bodies)
            if a is None and b is None:
                continue
            self.deepest = min([self.deepest, *(p.separation for p in contact.points)])
            if a is not None and b is not None:
                self.pairs.add((min(a, b), max(a, b)))
        return touched
