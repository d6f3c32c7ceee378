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
from babblegen.exporters.lerobot import load_dataset
from babblegen.exporters.report import FIGURES
from babblegen.exporters.sidecar import read_attempts, read_run_info


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
    assert set(summary["figures"]) == set(FIGURES)
    md = (out / "summary.md").read_text()
    assert "contacts per attempt" in md and "random babbling" in md and "contact ratio" in md


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
