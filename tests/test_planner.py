"""The planners where the answer is known independently: the bootstrap interval against hand-worked cases; CEM
given the true physics of a toy world (an oracle "model") reaches nearly every goal, given the simulator itself
(`planning_oracle`) ends where it predicts and reaches goals, and given a model that predicts nothing moves reaches
none; the cheap trajectories the search scores are exactly `ArmPlanner`'s IK and the movement `World.rollout`
executes (in the simulator, cheaply)."""

from __future__ import annotations

import numpy as np
import pytest

from babblegen.worldmodel.planning import bootstrap_ci, reached
from babblegen.worldmodel.planning_cem import CemSettings, cem_plan

# --- the bootstrap interval ----------------------------------------------------------------------------------


def test_bootstrap_interval_of_a_hand_worked_case():
    """Four goals, three reached: a resample's mean is k / 4 with k ~ Binomial(4, 3/4), so P(mean = 0) = 1/256,
    P(mean <= 1/4) = 13/256 = 0.051 and P(mean = 1) = 81/256: the 2.5 % quantile is 1/4, the 97.5 % one 1."""
    assert bootstrap_ci(np.array([0.0, 1.0, 1.0, 1.0])) == [0.25, 1.0]
    assert bootstrap_ci(np.ones(7)) == [1.0, 1.0]
    assert bootstrap_ci(np.zeros(7)) == [0.0, 0.0]


def test_bootstrap_interval_of_many_goals_is_the_normal_one():
    """30 of 100 reached: the interval is about 0.30 -/+ 1.96 sqrt(0.3 0.7 / 100) = [0.21, 0.39]."""
    lo, hi = bootstrap_ci(np.r_[np.ones(30), np.zeros(70)])
    half = 1.96 * np.sqrt(0.3 * 0.7 / 100)
    assert abs(lo - (0.3 - half)) < 0.015 and abs(hi - (0.3 + half)) < 0.015


def test_reached_counts_an_infeasible_movement_as_a_failure():
    goal = np.array([[0.8, 0.1], [0.8, 0.1], [0.8, 0.1]])
    final = np.array([[0.82, 0.1], [0.84, 0.1], [np.nan, np.nan]])
    assert reached(final, goal, 3.0).tolist() == [True, False, False]


# --- CEM in a toy world whose physics is known -----------------------------------------------------------------


class ToyCommander:
    """Genomes are their own "trajectories", every one feasible and direct."""

    def joint_paths(self, genomes):
        return [np.asarray(g, dtype=np.float64) for g in genomes]

    def actions(self, path):
        return path

    def direct(self, paths):
        return [True] * len(paths)


def toy_physics(first: np.ndarray, genome: np.ndarray) -> np.ndarray:
    """A push ends object 0 under the genome's last waypoint when that waypoint is low (z < 0.5); else nothing
    moves. Normalised x, y in [0, 1] map to 0.5 m x 0.8 m of table."""
    out = first.copy()
    last = genome[-1]
    if last[2] < 0.5:
        out[0, :2] = [0.5 + 0.5 * last[0], -0.4 + 0.8 * last[1]]
    return out


class OracleModel:
    """The toy world's true physics as the model."""

    def rollout(self, first, actions, joints0):
        return np.stack([toy_physics(f, a) for f, a in zip(first, actions, strict=True)])


class NothingMoves:
    def rollout(self, first, actions, joints0):
        return np.stack(first)


def toy_goals(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    first = np.zeros((n, 2, 4))
    first[:, :, :2] = [0.75, 0.0]
    goal_xy = np.stack([0.5 + 0.5 * rng.random(n), -0.4 + 0.8 * rng.random(n)], axis=1)
    return first, goal_xy


@pytest.mark.parametrize("model, expected", [(OracleModel(), (0.85, 1.0)), (NothingMoves(), (0.0, 0.0))])
def test_cem_with_the_true_physics_reaches_nearly_every_goal_and_with_nothing_moves_none(model, expected):
    first, goal_xy = toy_goals(20)
    keep = np.linalg.norm(goal_xy - first[:, 0, :2], axis=1) > 0.05  # goals 5 cm or more away, as the real ones
    first, goal_xy = first[keep], goal_xy[keep]
    result = cem_plan(model, ToyCommander(), first, np.zeros((len(first), 7)), np.zeros(len(first), int), goal_xy,
                      CemSettings(), seed=0)  # fmt: skip
    final = np.array(
        [toy_physics(f, g)[0, :2] if g is not None else f[0, :2] for f, g in zip(first, result.genomes, strict=True)]
    )
    success = reached(final, goal_xy, 3.0).mean()
    assert expected[0] <= success <= expected[1]
    if isinstance(model, NothingMoves):
        assert all(g is None for g in result.genomes)  # no plan: nothing is executed
    else:
        assert result.rollouts == len(first) * CemSettings().samples * CemSettings().iterations


def test_cem_samples_genomes_as_the_explorers_make_them():
    """Every sampled genome holds 1 to 4 waypoints inside the normalised box."""
    seen = []

    class Recording(ToyCommander):
        def joint_paths(self, genomes):
            seen.extend(genomes)
            return super().joint_paths(genomes)

    first, goal_xy = toy_goals(3)
    cem_plan(OracleModel(), Recording(), first, np.zeros((3, 7)), np.zeros(3, int), goal_xy, CemSettings(), seed=1)
    assert len(seen) == 3 * CemSettings().samples * CemSettings().iterations
    assert {len(g) for g in seen} <= {1, 2, 3, 4} and len({len(g) for g in seen}) > 1
    assert all(((g >= 0) & (g <= 1)).all() for g in seen)


# --- in the simulator ----------------------------------------------------------------------------------------


@pytest.mark.sim
def test_the_scored_trajectory_is_the_executed_one(small_heldout_dataset):
    """What the search scores for a genome (IK joined by straight segments, timed as the world times them) is, frame
    for frame, the ``action`` the world records when it executes that genome, wherever the segments are free; a
    genome the search does not score (IK fails or a segment collides) is one the planner rejects or detours."""
    from babblegen.evaluation import seeded_rollout
    from babblegen.tasks import get_task
    from babblegen.world.rollout import Command
    from babblegen.world.world import World
    from babblegen.worldmodel.planning_cem import Commander
    from babblegen.worldmodel.planning_sim import dataset_config

    config = dataset_config(str(small_heldout_dataset))
    commander = Commander(config)
    rng = np.random.default_rng(5)
    genomes = [rng.random((int(rng.integers(1, 5)), 3)) for _ in range(40)]
    scored = commander.trajectories(genomes)
    paths = commander.joint_paths(genomes)
    world = World(get_task(config.task), config.world, seed=config.seed)
    try:
        compared = 0
        for genome, action, path in zip(genomes, scored, paths, strict=True):
            plan = world.plan_command(Command("ee_waypoints", genome))
            if path is None:  # IK found no configuration: neither does the planner
                assert plan.path is None
                continue
            if action is None:  # too long, or a straight segment collides: then the planner detours or fails
                assert commander.actions(path) is None or plan.path is None or plan.planner != "direct"
                continue
            assert plan.path is not None and plan.planner == "direct"
            np.testing.assert_array_equal(plan.path, path)  # the same IK, the same straight path
            if compared < 2:  # two executions: the recorded commands are the scored ones
                rollout = seeded_rollout(world, Command("ee_waypoints", genome), config.seed, 10**9 + compared)
                executed = np.asarray(rollout.frames.action, dtype=np.float32).astype(np.float64)
                assert len(executed) >= len(action)
                np.testing.assert_array_equal(executed[: len(action)], action)
                compared += 1
        assert compared == 2
    finally:
        world.close()


@pytest.mark.sim
def test_with_the_true_simulator_as_its_model_the_search_ends_where_it_predicts(small_heldout_dataset):
    """The cem planner given the simulator itself as the model (`SimulatorModel`): the choice, executed as the
    planner executes it, ends to the bit where the search predicted, and nearer its goal than the goal object
    started on every goal it plans for; the search reaches goals (a model that predicts nothing moves reaches none,
    above). How many of 3 cm goals a perfect model's search reaches at the default budget is measured by
    benchmarks/planning_ceiling.py (half of 20: docs/world_model.md)."""
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.planning import PlanningSettings, build_task
    from babblegen.worldmodel.planning_oracle import simulator_search

    test = read_dataset(small_heldout_dataset).episodes
    task = build_task(test, PlanningSettings(goals=4, candidates=1, min_move_cm=2.0), 1, None, echo=lambda _: None)
    goals = list(range(len(task.goal_object)))
    assert len(goals) >= 3
    out = simulator_search(task, goals, CemSettings(samples=24, iterations=3), seed=0)
    planned = ~np.isnan(out["predicted_miss"])
    assert planned.sum() >= len(goals) // 2
    np.testing.assert_array_equal(out["executed_miss"], out["predicted_miss"])  # the model is the simulator
    start_miss = np.linalg.norm(task.first[goals, task.goal_object[goals], :2] - task.goal_xy[goals], axis=-1)
    assert (out["executed_miss"][planned] < start_miss[planned]).all()
    assert (out["executed_miss"][planned] <= 0.03).sum() >= 1  # one random genome: 1 goal in 500 (docs)
