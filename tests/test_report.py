"""`babblegen report`: its numbers match an independent count from the sidecar table and the LeRobot dataset,
its figures are real images, and it refuses paths that are not babblegen datasets."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from babblegen.cli import main
from babblegen.dataset.lerobot import load_dataset
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.exporters.report import FIGURES, START_FIGURE


@pytest.fixture(scope="module")
def report(small_noveb_dataset, small_random_dataset, tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("report")
    assert main(["report", str(small_noveb_dataset), "--compare", str(small_random_dataset), "--out", str(out)]) == 0
    return out, json.loads((out / "summary.json").read_text())


def recount(root: Path) -> dict:
    """The report's numbers, counted again from attempts.jsonl in the most direct way."""
    rows = [json.loads(line) for line in (root / "babblegen" / "attempts.jsonl").read_text().splitlines()]
    names = read_run_info(root)["object_names"]
    done = [r for r in rows if r["feasible"]]
    contacts = sum(1 for r in done if True in r["touched"].values())
    cells, std = {}, {}
    for n in names:
        xy = np.array([r["final_poses"][n][:2] for r in done]).reshape(-1, 2)
        cells[n] = len(np.unique(np.floor(xy / 0.02).astype(int), axis=0))
        std[n] = (float(np.std(xy[:, 0])), float(np.std(xy[:, 1]))) if len(xy) else (None, None)
    reasons: dict[str, int] = {}
    for r in rows:
        if not r["feasible"]:
            reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
    return {
        "attempts": len(rows),
        "executed": len(done),
        "feasible_fraction": len(done) / len(rows),
        "contacts": contacts,
        "contacts_per_object": {n: sum(r["touched"][n] for r in done) for n in names},
        "contacts_per_attempt": contacts / len(rows),
        "archive": sum(r["archived"] for r in rows),
        "cells": cells,
        "std": std,
        "infeasible_reasons": reasons,
    }


def check_against(summary: dict, expected: dict) -> None:
    for key in ("attempts", "executed", "contacts", "contacts_per_object", "archive", "infeasible_reasons"):
        assert summary[key] == expected[key], key
    assert summary["feasible_fraction"] == pytest.approx(expected["feasible_fraction"])
    assert summary["contacts_per_attempt"] == pytest.approx(expected["contacts_per_attempt"])
    for name, cells in expected["cells"].items():
        spread = summary["final_object_spread"][name]
        assert spread["cells"] == cells, name
        assert (spread["std_x"], spread["std_y"]) == pytest.approx(expected["std"][name]), name
    assert summary["wall_time_s"] > 0


def test_numbers_match_an_independent_count(report, small_noveb_dataset, small_random_dataset):
    _, summary = report
    this, other = recount(small_noveb_dataset), recount(small_random_dataset)
    check_against(summary["run"], this)
    check_against(summary["compare"], other)
    ratio = summary["comparison"]["contact_ratio"]
    assert ratio == (this["contacts"] / other["contacts"] if other["contacts"] else None)
    assert summary["run"]["explorer"] == "noveb" and summary["compare"]["explorer"] == "random"


@pytest.mark.parametrize("which", ["small_noveb_dataset", "small_random_dataset"])
def test_counts_agree_with_the_lerobot_dataset(report, which, request):
    root = request.getfixturevalue(which)
    summary = report[1]["run" if which == "small_noveb_dataset" else "compare"]
    rows = read_attempts(root)
    names = read_run_info(root)["object_names"]
    ds = load_dataset(root, read_run_info(root)["repo_id"])
    assert ds.meta.total_episodes == summary["executed"]
    table = ds.hf_dataset.with_format("arrow")[:]
    episode = np.asarray(table.column("episode_index").to_pylist())
    contacts = np.asarray(table.column("observation.contacts").to_pylist()).reshape(len(episode), len(names))
    touched = np.stack([contacts[episode == e].any(axis=0) for e in range(ds.meta.total_episodes)]).reshape(
        -1, len(names)
    )
    assert int(touched.any(axis=1).sum()) == summary["contacts"]
    assert dict(zip(names, touched.sum(axis=0).tolist(), strict=True)) == summary["contacts_per_object"]
    by_episode = {r["episode_index"]: r for r in rows if r["feasible"]}
    for e in range(ds.meta.total_episodes):
        assert [by_episode[e]["touched"][n] for n in names] == touched[e].tolist()


def test_figures_are_real_images(report):
    from matplotlib.image import imread

    out, summary = report
    for name in FIGURES.values():
        path = out / name
        assert path.stat().st_size > 10_000, name
        img = imread(path)
        assert img.ndim == 3 and img.shape[0] > 300 and img.shape[1] > 300, name
        rgb = (img[..., :3] * 255).astype(np.uint32)
        colours = np.unique(rgb[..., 0] << 16 | rgb[..., 1] << 8 | rgb[..., 2])
        assert len(colours) > 20, f"{name} is nearly a flat colour"
    assert set(summary["figures"]) == {*FIGURES, START_FIGURE[0]}  # these runs record their start poses
    assert (out / START_FIGURE[1]).stat().st_size > 10_000
    md = (out / "summary.md").read_text()
    assert "contacts per attempt" in md and "random babbling" in md and "contact ratio" in md
    assert START_FIGURE[1] in md and "| starts (" in md and summary["run"]["starts"] == "varied"  # the default


def test_report_needs_only_the_sidecar_and_defaults_to_dir_report(small_noveb_dataset, tmp_path):
    copy = tmp_path / "sidecar-only"
    shutil.copytree(small_noveb_dataset / "babblegen", copy / "babblegen", ignore=shutil.ignore_patterns("rerun"))
    assert main(["report", str(copy)]) == 0
    summary = json.loads((copy / "report" / "summary.json").read_text())
    assert "compare" not in summary and summary["run"]["attempts"] == len(read_attempts(small_noveb_dataset))
    assert all((copy / "report" / name).is_file() for name in FIGURES.values())
    assert not math.isnan(summary["run"]["wall_time_s"])


@pytest.mark.parametrize("args", [["{tmp}"], ["{tmp}/missing"], ["{ds}", "--compare", "{tmp}"]])
def test_bad_paths_exit_2(args, small_noveb_dataset, tmp_path, capsys):
    argv = [a.format(tmp=tmp_path, ds=small_noveb_dataset) for a in args]
    assert main(["report", *argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("babblegen: error: ") and ("not a babblegen dataset" in err or "does not exist" in err)
    assert not (tmp_path / "out").exists()


def test_diversity_counts_distinct_interactions_by_hand():
    from babblegen.exporters.report import diversity

    names = ["gray_box", "can"]
    still = {"gray_box": [0.5, -0.2, 0.72], "can": [0.6, 0.0, 0.75]}

    def row(genome, touched=(), moved=None, novelty=0.0, feasible=True):
        final = dict(still)
        displacement = {"gray_box": 0.0, "can": 0.0}
        for name, (xy, d) in (moved or {}).items():
            final[name] = [*xy, 0.72]
            displacement[name] = d
        r = {"kind": "ee_waypoints", "genome": genome, "feasible": feasible, "novelty": novelty}
        if feasible:
            r |= {"touched": {n: n in touched for n in names}, "displacement": displacement, "final_poses": final}
        return r

    rows = [
        row([[0.1, 0.2, 0.3]], ["can"], {"can": ([0.61, 0.01], 0.05)}, novelty=0.5),
        row([[0.1, 0.2, 0.3]], ["can"], {"can": ([0.63, 0.01], 0.05)}),  # the same genome again
        row([[0.9, 0.9, 0.9]], feasible=False),
        row([[0.5, 0.5, 0.5]]),  # touched nothing
        row(
            [[0.2, 0.2, 0.2]],
            ["gray_box", "can"],
            {"gray_box": ([0.5, -0.2], 0.005), "can": ([0.611, 0.019], 0.03)},
            0.2,
        ),
    ]
    d = diversity(rows, names)
    assert d["distinct_genomes_executed"] == 3
    assert d["duplicate_episodes"] == 1
    assert d["touching_genomes"] == 2
    assert d["touching_genomes_per_object"] == {"gray_box": 1, "can": 2}
    # the can ended in 2 cm cells (30, 0), (31, 0) and (30, 0) again; the gray box moved 5 mm: not moved
    assert d["moved_cells"] == 2 and d["moved_cells_per_object"] == {"gray_box": 0, "can": 2}
    assert d["novelty_positive_share"] == 2 / 4
    # 1 cm layouts: the can at cells (61, 1), (63, 1), (60, 0) and (61, 1) again, the gray box never moved
    assert d["distinct_outcomes"] == 3


def test_moved_objects_end_on_the_table_the_floor_or_out_of_the_scene_by_hand():
    """Objects a row moved over 1 cm are counted where their centres end, against a table top at 0.7 m: on it
    (0.72 m; down to 5 cm under the top), on the floor (0.03 m) or fallen past its edge (-3 m); an unmoved object
    and an infeasible row count nowhere."""
    from babblegen.exporters.report import markdown, moved_object_ends

    names = ["box", "ball"]

    def row(box, ball, feasible=True):
        """Each object's (final pose, displacement)."""
        return {
            "feasible": feasible,
            "final_poses": {"box": box[0], "ball": ball[0]},
            "displacement": {"box": box[1], "ball": ball[1]},
        }

    rows = [
        row(([0.61, 0.01, 0.72], 0.05), ([0.90, 0.10, 0.73], 0.005)),  # the box on the table, the ball unmoved
        row(([0.63, 0.01, 0.66], 0.05), ([1.80, 0.30, 0.03], 1.10)),  # on the table's edge, 4 cm low; the floor
        row(([0.61, 0.01, 0.72], 0.05), ([5.10, 0.40, -3.0], 4.50)),  # the box's cell again; past the floor
        row(([2.00, 2.00, -9.0], 2.50), ([0.90, 0.10, -9.0], 9.00), feasible=False),
    ]
    ends = moved_object_ends(rows, names, table_top=0.7)
    assert ends == {
        "moved_on_table": 3,
        "moved_on_floor": 1,
        "moved_out_of_scene": 1,
        "moved_cells_on_table": 2,  # the box at 2 cm cells (30, 0), (31, 0) and (30, 0) again
        "episodes_losing_an_object": 1,
    }
    summary = {"contacts_per_object": {}, "final_object_spread": {}, "final_tool_spread": {"cells": 0}, **ends}
    summary |= {"explorer": "noveb", "attempts": 4, "executed": 3, "feasible_fraction": 0.75, "contacts": 0}
    summary |= {"contacts_per_attempt": 0.0, "archive": 0, "wall_time_s": 0.0, "worker_time_s": 0.0}
    md = markdown([summary | {"infeasible_reasons": {}}], ["run"], None, figures={})
    assert (
        "| moved objects ending on the table / on the floor / past the floor's edge (out of the scene) | 3 / 1 / 1 |"
        in md
    )
    assert "| episodes losing an object out of the scene | 1 |" in md


# --- without a simulator: a sidecar table written by hand --------------------------------------------------------
def fake_run(root: Path, starts: str | None, start_poses: bool) -> Path:
    """A dataset's sidecar alone: run.json (``world.starts`` left out when None) and three executed rows, with
    ``start`` and ``start_poses`` only when ``start_poses`` (older datasets have neither)."""
    from babblegen.tasks import get_task

    task = get_task("noveb_tabletop").to_dict()
    world = {} if starts is None else {"starts": starts}
    info = {"config": {"explorer": "noveb", "world": world}, "task": task}
    (root / "babblegen").mkdir(parents=True)
    (root / "babblegen" / "run.json").write_text(json.dumps(info))
    rng = np.random.default_rng(0)
    rows = []
    for i in range(3):
        poses = {
            o["name"]: [*(np.array(o["xy"]) + rng.normal(0, 0.03, 2)), 0.75, 1.0, 0.0, 0.0, 0.0]
            for o in task["objects"]
        }
        row = {"attempt": i, "generation": 0, "explorer": "noveb", "kind": "ee_waypoints", "genome": [[0.1 * i] * 3]}
        row |= {"feasible": True, "episode_index": i, "novelty": 0.1, "archived": True, "final_ee_pos": [0.6, 0.0, 0.8]}
        row |= {"touched": dict.fromkeys(poses, False), "displacement": dict.fromkeys(poses, 0.0), "final_poses": poses}
        if start_poses:
            row |= {"start": {"source": "drawn", "drawn_at": i, "layout": [[*p[:2], 0.0] for p in poses.values()]}}
            row |= {"start_poses": poses}
        rows.append(row)
    (root / "babblegen" / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root


@pytest.mark.parametrize(("starts", "start_poses"), [("varied", True), (None, False)])
def test_start_figure_only_for_rows_with_start_poses(tmp_path, starts, start_poses):
    from babblegen.exporters.report import write_report

    root = fake_run(tmp_path / "ds", starts, start_poses)
    result = write_report(root)
    out = root / "report"
    assert (out / START_FIGURE[1]).is_file() == start_poses
    assert not start_poses or (out / START_FIGURE[1]).stat().st_size > 10_000
    assert (START_FIGURE[0] in result["figures"]) == start_poses
    assert all((out / name).is_file() for name in FIGURES.values())
    md = (out / "summary.md").read_text()
    assert (START_FIGURE[1] in md) == start_poses
    assert result["run"]["starts"] == (starts or "fixed")
    assert f"| starts (fixed: the task's scene; varied: drawn layouts) | {starts or 'fixed'} |" in md


@pytest.mark.parametrize(
    ("world_settings", "explorer", "says"),
    [
        ({}, "noveb", "fixed: every episode starts from the task's scene"),
        ({"starts": "fixed"}, "random", "fixed: every episode starts from the task's scene"),
        ({"starts": "varied"}, "noveb", "start mutation (probability 0.25) draws a new one"),
        ({"starts": "varied"}, "random", "every attempt draws its own"),
    ],
)
def test_dataset_card_says_how_starts_were_drawn(world_settings, explorer, says):
    from babblegen.exporters.dataset_card import card_text
    from babblegen.tasks import get_task

    cfg = {"explorer": explorer, "task": "noveb_tabletop", "seed": 1, "noveb": {"start_mutation_prob": 0.25}}
    cfg["world"] = {"camera_width": 64, "camera_height": 64, **world_settings}
    run_info = {"config": cfg, "task": get_task("noveb_tabletop").to_dict(), "versions": {}}
    counters = {"executed": 2, "attempts": 3, "contacts": 1, "generations": 1}
    card = card_text({"fps": 10, "robot_type": "pr2_like_arm", "features": {}}, run_info, counters)
    line = next(line for line in card.splitlines() if line.startswith("- **Starts:** "))
    assert says in line
    if world_settings.get("starts") == "varied":
        assert "settled by physics" in line and "per-object regions" in line and "`start_poses`" in line


def test_report_of_a_run_that_draws_six_objects(tmp_path, monkeypatch):
    """Objects drawn per start, six slots: every slot gets its rows and a colour of its own (the stand-ins are all
    gray), no stand-in is drawn resting on the table, and the summary counts touched objects by shape."""
    from babblegen.objects import slot_task
    from babblegen.tasks import get_task

    task = slot_task(get_task("noveb_tabletop"), "varied", 6).to_dict()
    names = [o["name"] for o in task["objects"]]
    world = {"starts": "varied", "objects": "varied", "num_objects": 6}
    root = tmp_path / "ds"
    (root / "babblegen").mkdir(parents=True)
    (root / "babblegen" / "run.json").write_text(
        json.dumps({"config": {"explorer": "noveb", "world": world}, "task": task})
    )
    shapes = [["box", "sphere", "capsule", "box", "hull", "dumbbell"], ["sphere", "sphere", "box", "tee", "ell", "box"]]
    touched = [{"object_0", "object_3"}, {"object_1", "object_2"}]  # boxes: 2 of 2, then 1 of 2; spheres 0 + 1 of 3
    rows = []
    for i in range(2):
        poses = {n: [0.7 + 0.05 * j, -0.2 + 0.08 * j, 0.75, 1.0, 0.0, 0.0, 0.0] for j, n in enumerate(names)}
        objects = [
            {"name": n, "shape": s, "size": [0.03], "color": [0.5, 0.5, 0.5, 1.0]}
            for n, s in zip(names, shapes[i], strict=True)
        ]
        row = {"attempt": i, "generation": 0, "explorer": "noveb", "kind": "ee_waypoints", "genome": [[0.1 * i] * 3]}
        row |= {"feasible": True, "episode_index": i, "novelty": 0.1, "archived": True, "final_ee_pos": [0.6, 0.0, 0.8]}
        row |= {"touched": {n: n in touched[i] for n in names}, "displacement": dict.fromkeys(names, 0.0)}
        row |= {"final_poses": poses, "objects": objects}
        rows.append(row)
    (root / "babblegen" / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert main(["report", str(root)]) == 0
    summary = json.loads((root / "report" / "summary.json").read_text())["run"]
    assert (summary["objects"], summary["num_objects"]) == ("varied", 6)
    assert summary["contacts_per_object"] == {
        n: int(n in {"object_0", "object_1", "object_2", "object_3"}) for n in names
    }
    assert summary["contacts_per_shape"] == {
        "box": {"objects": 4, "touched": 3},
        "capsule": {"objects": 1, "touched": 0},
        "dumbbell": {"objects": 1, "touched": 0},
        "ell": {"objects": 1, "touched": 0},
        "hull": {"objects": 1, "touched": 0},
        "sphere": {"objects": 3, "touched": 1},
        "tee": {"objects": 1, "touched": 0},
    }
    md = (root / "report" / "summary.md").read_text()
    assert "| objects (paper: the task's; varied, heldout: drawn per start into slots) | varied, 6 |" in md
    assert "| box objects touched / started with (in executed movements) | 3 / 4 |" in md
    assert all(f"| contacts with {n} |" in md for n in names)
    from babblegen.exporters.report_measures import Run

    colors = Run(root).colors
    assert len(set(colors.values())) == 6 and (0.5, 0.5, 0.5) not in colors.values()
    # the figure of final positions: six coloured point sets and no stand-in outline
    from babblegen.exporters import report_figures

    drawn = []
    background = report_figures._top_view_background

    def spy(ax, run):
        background(ax, run)
        drawn.append(len(ax.patches))

    monkeypatch.setattr(report_figures, "_top_view_background", spy)
    report_figures.figure_final_objects([Run(root)], tmp_path / "fig3.png")
    assert drawn == [2], "the table and the robot only"
