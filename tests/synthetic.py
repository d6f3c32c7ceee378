"""Episode sets made by hand, for the world model's tests: one source, one explorer, an attempt per episode."""

from __future__ import annotations

import numpy as np

from babblegen.worldmodel.episodes import EpisodeSet, Scene


def episode_set(
    scene: Scene,
    poses: list[np.ndarray],
    actions: list[np.ndarray],
    states: list[np.ndarray],
    layouts: list[str],
    genome: list,
    objects: np.ndarray | None = None,
) -> EpisodeSet:
    """An EpisodeSet of ``scene`` whose episode i has ``poses[i]`` (frames x objects x 7), ``actions[i]`` and
    ``states[i]`` (frames x 7), start layout ``layouts[i]`` and the waypoint genome ``genome``."""
    n = len(poses)
    extra = {} if objects is None else {"objects": objects}
    return EpisodeSet(
        scene=scene,
        source=np.array(["d"] * n),
        attempt=np.arange(n),
        explorer=np.array(["x"] * n),
        identity=np.array([str(i) for i in range(n)]),
        layout=np.array(layouts),
        commands=[{"kind": "ee_waypoints", "genome": genome, "layout": None}] * n,
        actions=actions,
        states=states,
        poses=poses,
        **extra,
    )
