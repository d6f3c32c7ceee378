"""What every world model of the evaluation shares: it predicts where objects end from an episode's start and
commands (`predict`, through its own `rollout`), and applies a frame's predicted motion only where its "moves" logit
exceeds a gate, chosen on episodes held back from training (`choose_gate`)."""

from __future__ import annotations

import numpy as np

from babblegen.worldmodel.episodes import MOVED, EpisodeSet
from babblegen.worldmodel.poses import object_state


class GatedModel:
    """A model with a ``gate`` (a logit) and a ``rollout(first, actions, joints0, objects=...)``."""

    gate: float = 0.0

    def rollout(self, first, actions, joints0, objects=None) -> np.ndarray:  # pragma: no cover - each model's own
        raise NotImplementedError

    def predict(self, episodes: EpisodeSet) -> np.ndarray:
        """(E, K, 4) every object's x, y, z, yaw in each episode's last frame, predicted from its first frame's
        poses and joints and its commanded joints."""
        return self.rollout(
            [p[0] for p in episodes.poses], episodes.actions, [s[0] for s in episodes.states], objects=episodes.objects
        )

    def choose_gate(self, episodes: EpisodeSet, gates: tuple[float, ...]) -> float:
        """The gate among ``gates`` whose rollouts best tell which objects move (F1, the displacement over `MOVED`)
        on ``episodes``: each model's own trade between missed and false moves. Sets and returns it."""
        first = object_state(episodes.first)
        truth = np.linalg.norm(episodes.final[..., :3] - episodes.first[..., :3], axis=-1) > MOVED
        best, best_f1 = 0.0, -1.0
        for gate in gates:
            self.gate = gate
            moved = np.linalg.norm(self.predict(episodes)[..., :3] - first[..., :3], axis=-1) > MOVED
            f1 = 2 * (moved & truth).sum() / max(moved.sum() + truth.sum(), 1)
            if f1 > best_f1:
                best, best_f1 = gate, f1
        self.gate = best
        return best
