"""Keep and use a learned simulator: load one that `babblegen evaluate --save-models` wrote (or train one), roll it
out from a dataset's scene and any movement, plan with it, and run the plan in the real simulator.

```python
from babblegen.worldmodel import api

model = api.load_model("models/noveb_4000attempts_equal-attempts_repeat1.pt")
scene = api.scene_of("dataset/", episode=12)                 # where the episode started, its objects and arm
ends, spread = api.predict(model, scene, scene.actions)      # (K, 4) x, y, z, yaw of every object, and (K,) spread
plan = api.plan(model, scene, goal_object=1, goal_xy=(0.85, -0.05))
ends_for_real = api.execute(scene, plan.genome)              # the chosen movement, simulated
```
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from babblegen.worldmodel.episodes import EpisodeSet, read_dataset
from babblegen.worldmodel.planning_cem import CemSettings, cem_plan
from babblegen.worldmodel.simulator import GraphSettings, LearnedSimulator


@dataclass
class Scene:
    """One start of a dataset: its objects' poses (K, 7), their object vectors (K, P), the arm's joints (7,), and
    the recorded episode's own commanded joints (T, 7) and what the world needs to run a movement from there."""

    dataset: str
    poses: np.ndarray
    objects: np.ndarray
    joints: np.ndarray
    actions: np.ndarray
    command: dict


@dataclass
class Plan:
    genome: np.ndarray | None  # (n, 3) waypoints in the normalised workspace box; None: no movement brings it nearer
    actions: np.ndarray | None  # (T, 7) its commanded joints, as the model scored them
    predicted_miss: float  # metres between where the model says the goal object ends and the goal


def load_model(path: str | Path) -> LearnedSimulator:
    """A learned simulator written by `LearnedSimulator.save` (`babblegen evaluate --save-models DIR`)."""
    return LearnedSimulator.load(Path(path))


def train(datasets: list[str | Path], settings: GraphSettings | None = None) -> LearnedSimulator:
    """A learned simulator trained on every executed episode of ``datasets`` (one scene: slots, table, arm)."""
    episodes = EpisodeSet.union([read_dataset(Path(d)).episodes for d in datasets])
    return LearnedSimulator.fit(episodes, settings)


def scene_of(dataset: str | Path, episode: int) -> Scene:
    """The start of a dataset's executed episode ``episode`` (in attempt order)."""
    e = read_dataset(Path(dataset)).episodes
    return Scene(str(e.source[episode]), e.poses[episode][0], e.objects[episode], e.states[episode][0],
                 e.actions[episode], e.commands[episode])  # fmt: skip


def predict(model: LearnedSimulator, scene: Scene, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where every object ends (K, 4: x, y, z, yaw) when the arm is commanded ``actions`` (T, 7) from ``scene``,
    and how far the ensemble's members disagree on each (K,), cm."""
    ends, spread = model.rollout([scene.poses], [actions], [scene.joints], objects=[scene.objects], spread=True)
    return ends[0], spread[0]


def plan(
    model: LearnedSimulator,
    scene: Scene,
    goal_object: int,
    goal_xy: tuple[float, float],
    cem: CemSettings | None = None,
    seed: int = 0,
) -> Plan:
    """The movement the model predicts brings object ``goal_object`` nearest ``goal_xy`` from ``scene``: the
    cross-entropy method over waypoint genomes, scored by the model alone (`planning_cem.cem_plan`)."""
    from babblegen.worldmodel.planning_sim import commander

    result = cem_plan(
        model, commander(scene.dataset), scene.poses[None], scene.joints[None], np.array([goal_object]),
        np.asarray(goal_xy, dtype=np.float64)[None], cem or CemSettings(), seed, scene.objects[None],
    )  # fmt: skip
    return Plan(result.genomes[0], result.actions[0], float(result.predicted_miss[0]))


def execute(scene: Scene, genome: np.ndarray, attempt: int = 0) -> np.ndarray | None:
    """(K, 4) where every object ends when ``genome`` runs from ``scene`` in the real simulator (None: infeasible),
    seeded as attempt ``attempt`` of the dataset's run."""
    from babblegen.worldmodel.planning import PLAN_ATTEMPTS
    from babblegen.worldmodel.planning_sim import simulate

    c = scene.command
    ok, _, final = simulate((scene.dataset, PLAN_ATTEMPTS + attempt, "ee_waypoints", np.asarray(genome).tolist(),
                             c["layout"], c.get("objects")))  # fmt: skip
    return final if ok else None
