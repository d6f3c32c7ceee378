"""`babblegen evaluate` end to end on small real datasets: the tables and numbers it writes, planning's executed
candidates, and one clear line with exit status 2 for each kind of bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from babblegen.cli import main

FAST = ["--steps", "30", "--workers", "1"]


@pytest.fixture(scope="module")
def evaluation(small_noveb_dataset, small_random_dataset, small_heldout_dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("evaluation")
    args = ["evaluate", "--train", f"noveb={small_noveb_dataset}", "--train", f"random={small_random_dataset}"]
    args += ["--test", f"held={small_heldout_dataset}", "--plan-goals", "0", "--out", str(out), *FAST]
    assert main(args) == 0
    return out


def test_every_source_is_scored_at_equal_attempts_and_episodes(evaluation, small_noveb_dataset, small_random_dataset):
    from babblegen.worldmodel.episodes import read_dataset

    result = json.loads((evaluation / "evaluation.json").read_text())
    assert [b["equal"] for b in result["blocks"]] == ["attempts", "episodes"]
    counts = {"noveb": len(read_dataset(small_noveb_dataset).episodes)}
    counts["random"] = len(read_dataset(small_random_dataset).episodes)
    equal_attempts, equal_episodes = result["blocks"]
    assert {n: r[0]["episodes"] for n, r in equal_attempts["sources"].items()} == counts
    assert {r[0]["episodes"] for r in equal_episodes["sources"].values()} == {min(counts.values())}
    for block in result["blocks"]:
        for runs in block["sources"].values():
            scores = runs[0]["scores"]["held"]
            assert 0.0 <= scores["macro"]["false_moves"] <= 1.0
            assert set(scores) >= {"all", "macro"}
    held = result["tests"]["held"]
    assert sum(held["strata"].values()) == held["episodes"]
    table = (evaluation / "evaluation.md").read_text()
    assert "| noveb |" in table and "| random |" in table and "nothing moves" in table


def test_an_attempt_budget_cuts_each_dataset_to_its_first_attempts(small_noveb_dataset):
    from babblegen.exporters.sidecar import read_attempts
    from babblegen.worldmodel.episodes import read_dataset

    data = read_dataset(small_noveb_dataset)
    rows = read_attempts(small_noveb_dataset)
    executed = [r["attempt"] for r in rows if r.get("episode_index") is not None and r["attempt"] < 10]
    assert data.budget(attempts=10).attempt.tolist() == executed
    assert len(data.budget(attempts=10, episodes=2)) == min(2, len(executed))


def test_the_goal_genome_reproduces_the_goal(small_heldout_dataset):
    """The baselines run in the simulator; the goal episode's own genome, seeded as its attempt was, ends exactly
    where the recorded episode ended: the replay baseline is 1.0, with the interval [1, 1]."""
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.planning import PlanningSettings, baseline_scores, build_task

    test = read_dataset(small_heldout_dataset).episodes
    settings = PlanningSettings(goals=2, candidates=3, min_move_cm=0.0)
    task = build_task(test, settings, workers=1, cache=None, echo=lambda _: None)
    assert task is not None and task.feasible[:, 0].all()
    np.testing.assert_array_equal(task.final_xy[:, 0], task.goal_xy)
    assert task.feasible.shape[1] == 1 + 3  # the goal's own movement and 3 random genomes, no mutations for cem
    baselines = baseline_scores(task, settings.success_cm)
    assert baselines["replay"]["rate"] == 1.0 and baselines["replay"]["ci95"] == [1.0, 1.0]
    assert (task.strata["arm"] ^ task.strata["object"]).all()  # every goal pushed by the arm or by another object


def test_planning_records_the_planner_goals_and_intervals(small_noveb_dataset, small_heldout_dataset, tmp_path):
    """The cem planner end to end on two goals (a tiny search): evaluation.json's planning block records the
    planner and the goals, every source's result its success and 95 % interval, beside the baselines."""
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.experiment import Source, run_experiment
    from babblegen.worldmodel.model import TrainSettings
    from babblegen.worldmodel.planning import PlanningSettings, build_task
    from babblegen.worldmodel.report import write

    test = {"held": read_dataset(small_heldout_dataset).episodes}
    settings = PlanningSettings(goals=2, candidates=2, min_move_cm=0.0, cem_samples=6, cem_iterations=2, cem_elites=2)
    task = build_task(test["held"], settings, workers=1, cache=None, echo=lambda _: None)
    sources = [Source("noveb", [read_dataset(small_noveb_dataset)])]
    result = run_experiment(
        sources, test, [None], ["attempts"], TrainSettings(steps=30), task, settings, 1, echo=lambda _: None
    )
    result["settings"] = {"planning": {"success_cm": 3.0}}
    write(result, tmp_path)
    saved = json.loads((tmp_path / "evaluation.json").read_text())
    assert saved["planning"]["planner"] == "cem" and saved["planning"]["goals"] == 2
    run = saved["blocks"][0]["sources"]["noveb"][0]["planning"]
    lo, hi = run["ci95"]
    assert 0.0 <= lo <= run["model"] <= hi <= 1.0
    assert len(run["goal_success"]) == 2 and run["rollouts"] > 0
    assert run["executed"]["differs"] == 0.0  # what was scored is what ran
    pooled = saved["blocks"][0]["planning"]["noveb"]
    assert pooled["model"] == run["model"] and pooled["ci95"] == run["ci95"]
    assert saved["planning"]["baselines"]["replay"]["rate"] == 1.0
    assert "one random genome" in (tmp_path / "evaluation.md").read_text()


def one_line_error(capsys, args: list[str]) -> str:
    assert main(["evaluate", *args, *FAST, "--plan-goals", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("babblegen: error:")
    return err


def test_missing_or_empty_datasets(small_heldout_dataset, tmp_path, capsys):
    held = f"held={small_heldout_dataset}"
    assert "no such dataset" in one_line_error(capsys, ["--train", f"a={tmp_path / 'nope'}", "--test", held])
    (tmp_path / "empty").mkdir()
    assert "not a babblegen dataset" in one_line_error(capsys, ["--train", f"a={tmp_path / 'empty'}", "--test", held])


def test_a_test_set_that_overlaps_training(small_noveb_dataset, small_random_dataset, capsys):
    """Random babbling of the same seed draws the same starts: not seeded apart."""
    err = one_line_error(capsys, ["--train", f"a={small_noveb_dataset}", "--test", f"b={small_random_dataset}"])
    assert "seeded apart" in err


def test_a_dataset_without_the_columns_it_needs(small_noveb_dataset, small_heldout_dataset, tmp_path, capsys):
    copy = tmp_path / "ds"
    shutil.copytree(small_noveb_dataset, copy)
    info = json.loads((copy / "meta" / "info.json").read_text())
    del info["features"]["observation.environment_state"]
    (copy / "meta" / "info.json").write_text(json.dumps(info))
    err = one_line_error(capsys, ["--train", f"a={copy}", "--test", f"held={small_heldout_dataset}"])
    assert "observation.environment_state" in err


def test_a_budget_beyond_a_dataset(small_noveb_dataset, small_heldout_dataset, capsys):
    args = ["--train", f"a={small_noveb_dataset}", "--test", f"held={small_heldout_dataset}", "--attempts", "500"]
    assert "--resume --max-attempts 500" in one_line_error(capsys, args)
