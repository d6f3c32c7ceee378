"""`babblegen evaluate` end to end on small real datasets: the tables and numbers it writes, planning's executed
candidates, and one clear line with exit status 2 for each kind of bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from babblegen.cli import main

FAST = ["--steps", "30", "--members", "2", "--workers", "1"]


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
            assert set(scores) >= {"all", "macro", "shapes"}
            # each shape's objects alone: together they are every object, moved or not
            assert sum(sc["moved"] for sc in scores["shapes"].values()) == scores["all"]["moved"]
    held = result["tests"]["held"]
    assert sum(held["strata"].values()) == held["episodes"]
    table = (evaluation / "evaluation.md").read_text()
    assert "| noveb |" in table and "| random |" in table and "nothing moves" in table
    shapes = result["blocks"][0]["sources"]["noveb"][0]["scores"]["held"]["shapes"]
    assert "By shape on held" in table
    # where each model ends the moved objects, in units of their true moves: one pair per moved object, their median
    # along the move the score's, and the figure of them
    for block in result["blocks"]:
        for runs in block["sources"].values():
            ends, held = np.asarray(runs[0]["ends"]["held"]), runs[0]["scores"]["held"]["all"]
            assert ends.shape == (held["moved"], 2)
            assert np.median(ends[:, 0]) == pytest.approx(held["along"], abs=1e-3)
    assert "How far along its true move each model ends the moved objects" in table
    assert (evaluation / "ends.png").read_bytes().startswith(b"\x89PNG")
    assert all(f"{shape} ({sc['moved']} moved): F1 / error" in table for shape, sc in shapes.items())


def test_a_stop_keeps_what_was_measured_and_says_where(
    small_noveb_dataset, small_random_dataset, small_heldout_dataset, tmp_path, capsys, monkeypatch
):
    """Ctrl-C after the first model: exit status 130, and the line says where the models measured so far are (not
    what an interrupted generate says)."""
    from babblegen.worldmodel import report

    real = report.write

    def write_then_stop(result: dict, out: Path) -> list[Path]:
        real(result, out)
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "write", write_then_stop)
    args = ["evaluate", "--train", f"noveb={small_noveb_dataset}", "--train", f"random={small_random_dataset}"]
    args += ["--test", f"held={small_heldout_dataset}", "--plan-goals", "0", "--out", str(tmp_path), *FAST]
    assert main(args) == 130
    printed = capsys.readouterr()
    assert f"babblegen: evaluate interrupted; the models measured so far are in {tmp_path / 'evaluation.md'}" in (
        printed.err
    )
    assert "[1/4] noveb" in printed.out and "episode" not in printed.err.split("interrupted")[1]
    assert "**In progress**: 1 of 4 models trained so far." in (tmp_path / "evaluation.md").read_text()


def test_an_attempt_budget_cuts_each_dataset_to_its_first_attempts(small_noveb_dataset):
    from babblegen.dataset.sidecar import read_attempts
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
    assert not (task.strata["arm"] & task.strata["object"]).any()  # pushed by the arm, or by another object alone


def test_goals_pushed_by_another_object_come_from_contact_events(small_heldout_dataset, tmp_path):
    """An object the arm never touched that met another object (the sidecar's contact events) is a goal of the
    "pushed by another object" stratum, drawn first up to its share; the other goals are each episode's most-moved
    object, no episode twice."""
    from babblegen.worldmodel.episodes import object_distance_moved, read_dataset
    from babblegen.worldmodel.planning import PlanningSettings, choose_goals, contact_flags

    root = tmp_path / "ds"
    shutil.copytree(small_heldout_dataset, root)
    test = read_dataset(root).episodes
    names = test.scene.objects
    e = len(test) - 1
    path = root / "babblegen" / "attempts.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    for row in rows:
        if row["attempt"] == int(test.attempt[e]):
            row["touched"] = {n: False for n in names}
            row["object_contacts"] = {f"{names[1]}|{names[2]}": {"first_frame": 5, "impulse": 0.01}}
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    test = read_dataset(root).episodes
    touched, met = contact_flags(test)
    assert not touched[e].any() and met[e].tolist() == [n in names[1:3] for n in names]

    settings = PlanningSettings(goals=4, min_move_cm=0.0, object_share=0.25)
    goals = choose_goals(test, settings)
    moved = object_distance_moved(test)
    assert (e, 1 + int(np.argmax(moved[e, 1:3]))) in goals  # the one such object, within the share (1 of 4)
    assert len({g for g, _ in goals}) == len(goals) == min(4, len(test))
    assert all(k == int(np.argmax(moved[g])) for g, k in goals if g != e)
    alone = choose_goals(test, PlanningSettings(goals=4, min_move_cm=0.0, object_share=0.0))
    assert all(k == int(np.argmax(moved[g])) for g, k in alone)  # no share: the most-moved objects alone


def test_planning_records_the_planner_goals_and_intervals(small_noveb_dataset, small_heldout_dataset, tmp_path):
    """The cem planner end to end on two goals (a tiny search): evaluation.json's planning block records the
    planner and the goals, every source's result its success and 95 % interval, beside the baselines."""
    from babblegen.worldmodel.episodes import read_dataset
    from babblegen.worldmodel.experiment import Source, run_experiment
    from babblegen.worldmodel.planning import PlanningSettings, build_task
    from babblegen.worldmodel.planning_oracle import measured_ceiling
    from babblegen.worldmodel.report import write
    from babblegen.worldmodel.simulator import GraphSettings

    test = {"held": read_dataset(small_heldout_dataset).episodes}
    settings = PlanningSettings(goals=2, candidates=2, min_move_cm=0.0, cem_samples=6, cem_iterations=2, cem_elites=2)
    task = build_task(test["held"], settings, workers=1, cache=None, echo=lambda _: None)
    sources = [Source("noveb", [read_dataset(small_noveb_dataset)])]
    # the ceiling: the same search with the true simulator as its model, on one of the goals, kept and read again
    key, cache = settings.key(test["held"]), tmp_path / "ceiling.json"
    ceiling = measured_ceiling(task, settings, 1, 1, cache, key, echo=lambda _: None)
    assert measured_ceiling(task, settings, 1, 1, cache, key, echo=lambda _: None) == ceiling
    assert len(ceiling["goals"]) == 1 and ceiling["runs"] > 0 and 0.0 <= ceiling["rate"] <= 1.0
    result = run_experiment(
        sources, test, [None], ["attempts"], GraphSettings(steps=30, members=2), task, settings, 1,
        echo=lambda _: None, ceiling=ceiling,
    )  # fmt: skip
    result["settings"] = {"planning": {"success_cm": 3.0}}
    write(result, tmp_path)
    saved = json.loads((tmp_path / "evaluation.json").read_text())
    assert saved["planning"]["planner"] == "cem" and saved["planning"]["goals"] == 2
    run = saved["blocks"][0]["sources"]["noveb"][0]["planning"]
    lo, hi = run["ci95"]
    assert 0.0 <= lo <= run["model"] <= hi <= 1.0
    assert len(run["goal_success"]) == 2 and run["rollouts"] > 0
    assert run["executed"]["differs"] == 0.0  # what was scored is what ran
    # each goal's miss, executed, decides its success; the model's own prediction of it sits beside
    miss, predicted = np.array(run["goal_miss_cm"]), np.array(run["goal_predicted_miss_cm"])
    assert len(miss) == len(predicted) == 2
    assert np.array_equal(np.nan_to_num(miss, nan=np.inf) <= 3.0, np.array(run["goal_success"]) == 1.0)
    chosen = np.isfinite(predicted)  # a prediction wherever the model chose a genome, nowhere else
    assert chosen.sum() == round((1 - run["no_plan"]) * 2) and (predicted[chosen] >= 0).all()
    assert not (np.isfinite(miss) & ~chosen).any()
    table = (tmp_path / "evaluation.md").read_text()
    assert "median miss, predicted / executed (cm)" in table
    pooled = saved["blocks"][0]["planning"]["noveb"]
    assert pooled["model"] == run["model"] and pooled["ci95"] == run["ci95"]
    assert saved["planning"]["ceiling"]["goals"] == ceiling["goals"]
    on = pooled["on_ceiling_goals"]
    assert on["ceiling"] == ceiling["rate"] and on["model"] == run["goal_success"][ceiling["goals"][0]]
    assert "the true simulator as the model (ceiling, 1 goals)" in (tmp_path / "evaluation.md").read_text()
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


@pytest.fixture(scope="module")
def varied_objects_dataset(tmp_path_factory) -> Path:
    """Uniform random waypoints from varied starts, every start with its own drawn objects (seed 11: apart from the
    other datasets): a few attempts."""
    from conftest import SMALL_RUN

    out = tmp_path_factory.mktemp("varied_objects") / "ds"
    args = ["generate", "--out", str(out), *SMALL_RUN, "--max-attempts", "8", "--explorer", "random_waypoints"]
    assert main([*args, "--objects", "varied", "--seed", "11", "--no-rerun"]) == 0
    return out


@pytest.mark.sim
def test_varied_objects_are_read_per_episode_and_planned_with(varied_objects_dataset):
    """Each episode's objects come from its sidecar row; planning executes the goal episode's genome from its start
    with its objects and ends exactly where the recorded episode ended, every object."""
    from babblegen.dataset.sidecar import read_attempts
    from babblegen.shapes import ObjectSpec
    from babblegen.worldmodel.episodes import object_vector, read_dataset
    from babblegen.worldmodel.planning import PlanningSettings, build_task

    test = read_dataset(varied_objects_dataset).episodes
    rows = {r["attempt"]: r for r in read_attempts(varied_objects_dataset)}
    assert len(test) >= 2
    for e, attempt in enumerate(test.attempt):
        expected = [object_vector(ObjectSpec.from_factors(o)) for o in rows[int(attempt)]["objects"]]
        np.testing.assert_array_equal(test.objects[e], np.stack(expected))
    assert len({test.objects[e].tobytes() for e in range(len(test))}) == len({*test.layout})  # per start
    settings = PlanningSettings(goals=2, candidates=2, min_move_cm=0.0)
    task = build_task(test, settings, workers=1, cache=None, echo=lambda _: None)
    assert task is not None and task.feasible[:, 0].all()
    np.testing.assert_array_equal(task.final_xy[:, 0], task.goal_xy)
    goals = [int(np.flatnonzero((test.final[:, k, :2] == xy).all(axis=1))[0]) for k, xy in zip(task.goal_object,
             task.goal_xy, strict=True)]  # fmt: skip
    np.testing.assert_array_equal(task.objects, test.objects[goals])
    # every object ends exactly where it was recorded, height and yaw too; the slots' stand-ins would not
    from babblegen.worldmodel.planning_sim import simulate
    from babblegen.worldmodel.poses import object_state

    c = test.commands[0]
    job = [str(test.source[0]), int(test.attempt[0]), c["kind"], c["genome"], c["layout"], c["objects"]]
    np.testing.assert_array_equal(simulate(tuple(job))[2], object_state(test.final[0]))
    stand_ins = simulate(tuple(job[:5] + [None]))[2]
    assert np.abs(stand_ins[:, 2] - object_state(test.final[0])[:, 2]).max() > 0.002


@pytest.mark.sim
def test_evaluate_trains_on_varied_objects_and_tests_on_the_paper_s(varied_objects_dataset, small_heldout_dataset,
                                                                    tmp_path):  # fmt: skip
    """A model trained on drawn objects is scored on a test set of the paper's objects (slots and table agree)."""
    args = ["evaluate", "--train", f"varied={varied_objects_dataset}", "--test", f"paper={small_heldout_dataset}"]
    assert main([*args, "--plan-goals", "0", "--equal", "attempts", "--out", str(tmp_path), *FAST]) == 0
    result = json.loads((tmp_path / "evaluation.json").read_text())
    (run,) = result["blocks"][0]["sources"]["varied"]
    scores = run["scores"]["paper"]["all"]
    assert scores["episodes"] == result["tests"]["paper"]["episodes"] > 0
    assert 0.0 <= scores["false_moves"] <= 1.0
    assert result["settings"]["model"]["kind"] == "graph"
