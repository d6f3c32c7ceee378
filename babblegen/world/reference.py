"""The world as it stepped before its per-substep shortcuts, kept as the reference they are checked against
(``tests/test_world.py``) and measured against (``benchmarks/bench_world.py --substeps``)."""

from __future__ import annotations

import numpy as np

from babblegen.world.world import World


class ManiSkillDrivenWorld(World):
    """The world as it stepped before its per-substep shortcuts: every control step through ManiSkill's
    controller (``set_action``, then ``before_simulation_step`` before each physics step) and contacts found by
    the bodies' entity names. The reference the shortcuts must match bit for bit."""

    def _bind_scene(self) -> None:
        super()._bind_scene()
        self._drive_joints = None  # ManiSkill's controller for every control step
        self._arm_entity_names = {link.entity.name for link in self._arm.links} - {self.robot.base_link}
        self._object_index = {e.name: i for i, e in enumerate(self._object_entities)}

    def _touching(self) -> np.ndarray:
        touched = np.zeros(len(self._object_entities), dtype=bool)
        for contact in self.sim.scene.px.get_contacts():
            a, b = contact.bodies[0].entity.name, contact.bodies[1].entity.name
            if a in self._arm_entity_names and b in self._object_index:
                obj = self._object_index[b]
            elif b in self._arm_entity_names and a in self._object_index:
                obj = self._object_index[a]
            else:
                continue
            if any(np.any(p.impulse != 0) or p.separation < 1e-3 for p in contact.points):
                touched[obj] = True
        return touched
