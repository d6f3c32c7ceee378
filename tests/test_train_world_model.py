"""examples/train_world_model.py's parts on synthetic data: no simulator, no dataset on disk but a sidecar."""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wm():
    sys.path.insert(0, str(ROOT / "examples"))  # as running the script puts its folder first: its own modules
    spec = importlib.util.spec_from_file_location("train_world_model", ROOT / "examples" / "train_world_model.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    torch.set_num_threads(1)  # as the script runs (and much faster on a busy machine)
    return module


@pytest.fixture(scope="module")
def wmd(wm):
    """examples/world_model_data.py, the module the script reads datasets with."""
    return sys.modules["world_model_data"]


def synthetic(wm, n: int, seed: int, n_objects: int = 3):
    """Episodes whose first input says how far object 0 moves along x; the others never move."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 8))
    disp = np.zeros((n, n_objects, 2))
    disp[:, 0, 0] = np.where(x[:, 0] > 0, 0.1 * x[:, 0], 0.0)
    moved = np.linalg.norm(disp, axis=2) > 0.01
    genomes = np.array([f"g{seed}:{i}" for i in range(n)])
    return wm.Episodes(x, disp, moved, genomes, [f"o{i}" for i in range(n_objects)])


def test_named_dirs(wm):
    assert wm.named_dirs("noveb=a/b,c") == ("noveb", [Path("a/b"), Path("c")])
    for bad in ("noveb", "=a", "noveb="):
        with pytest.raises(argparse.ArgumentTypeError):
            wm.named_dirs(bad)


def test_yaw_of_a_rotation_about_z(wmd):
    for angle in (-3.0, -0.5, 0.0, 1.2, 3.1):
        q = np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])
        assert wmd.yaw(q) == pytest.approx(angle)
    flipped = np.array([0.0, 1.0, 0.0, 0.0])  # upside down about x: no yaw
    assert wmd.yaw(flipped) == pytest.approx(0.0)


def test_occupancy_is_one_area_averaged_channel_per_id(wmd):
    mask = np.zeros((8, 8), dtype=np.uint16)
    mask[:4, :4] = 5  # top-left cell of a 2 x 2 grid, fully
    mask[4:, 4:6] = 7  # half of the bottom-right cell
    maps = wmd.occupancy(mask, [5, 7, 9], 2)
    assert maps.shape == (3, 2, 2)
    np.testing.assert_allclose(maps[0], [[1, 0], [0, 0]])
    np.testing.assert_allclose(maps[1], [[0, 0], [0, 0.5]])
    assert not maps[2].any()  # an object out of view has an empty map


def test_mask_ids_by_name(wmd):
    features = {wmd.MASKS: {"info": {"ids": {"0": "background", "4": "can", "5": "ball"}}}}
    assert wmd.mask_ids(features, ["ball", "can"], Path("d")) == [5, 4]
    with pytest.raises(SystemExit, match="cube"):
        wmd.mask_ids(features, ["cube"], Path("d"))
    with pytest.raises(SystemExit, match="no-segmentation"):
        wmd.mask_ids({}, ["can"], Path("d"))


def test_scores(wm):
    truth = wm.Episodes(
        np.zeros((2, 1)),
        np.array([[[0.03, 0.04], [0.0, 0.0]], [[0.0, 0.0], [0.1, 0.0]]]),
        np.array([[True, False], [False, True]]),
        np.array(["a", "b"]),
        ["p", "q"],
    )
    nothing = wm.scores(np.zeros_like(truth.disp), np.zeros_like(truth.moved), truth)
    assert nothing["f1"] == 0.0
    assert nothing["median_cm"] == pytest.approx(7.5)  # median of 5 cm and 10 cm
    perfect = wm.scores(truth.disp, truth.moved, truth)
    assert perfect == {"f1": 1.0, "median_cm": 0.0}
    half = wm.scores(truth.disp, np.array([[True, True], [False, False]]), truth)
    assert half["f1"] == pytest.approx(0.5)  # tp 1, fp 1, fn 1
    still = wm.Episodes(truth.x, np.zeros_like(truth.disp), np.zeros_like(truth.moved), truth.genomes, truth.objects)
    assert np.isnan(list(wm.scores(still.disp, still.moved, still).values())).all()


def test_experiment_is_seeded_and_learns(wm):
    sources = {"a": [synthetic(wm, 60, 1), synthetic(wm, 60, 2)], "b": [synthetic(wm, 40, 3)]}
    tests = {"held_out": synthetic(wm, 50, 9)}
    out = wm.experiment(sources, tests, n=40, epochs=60, seed=0, hidden=32)
    assert list(out["held_out"]) == [wm.BASELINE, "a", "b"]
    for scores in out["held_out"].values():
        assert len(scores["f1"]) == len(scores["median_cm"]) == 2  # one value per repeat
    assert out["held_out"][wm.BASELINE]["f1"] == [0.0, 0.0]
    assert min(out["held_out"]["a"]["f1"]) > 0.5  # the signal is in the input
    assert out == wm.experiment(sources, tests, n=40, epochs=60, seed=0, hidden=32)
    table = wm.markdown(out["held_out"])
    assert len(table) == 5 and all(line.startswith("| ") for line in table)  # header, rule, baseline, a, b


def test_union_and_take(wm):
    a, b = synthetic(wm, 5, 1), synthetic(wm, 3, 2)
    both = wm.Episodes.union([a, b])
    assert len(both.x) == 8 and both.genomes[5] == "g2:0"
    assert both.take(np.array([0, 7])).genomes.tolist() == ["g1:0", "g2:2"]
    with pytest.raises(SystemExit, match="different objects"):
        wm.Episodes.union([a, synthetic(wm, 3, 2, n_objects=2)])


def test_genome_keys_from_the_sidecar(wmd, tmp_path: Path):
    rows = [
        {"attempt": 0, "episode_index": 1, "kind": "noveb", "genome": [[0.1, 0.2]]},
        {"attempt": 1, "episode_index": None, "kind": "noveb", "genome": [[9.0]]},  # infeasible: no episode
        {"attempt": 2, "episode_index": 0, "kind": "noveb", "genome": [[0.1, 0.2]]},
    ]
    (tmp_path / "babblegen").mkdir()
    (tmp_path / "babblegen" / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    keys = wmd.genome_keys(tmp_path, np.array([0, 1]))
    assert keys[0] == keys[1] == "noveb:[[0.1, 0.2]]"


def test_the_convolutional_model_learns_where_the_path_crosses_an_object(wm):
    """Synthetic scenes: one object in a random cell of an 8 x 8 map and a tool path through another random cell;
    the object moves when they coincide. The answer is in the image alone, wherever the object stands."""

    def scenes(n: int, seed: int):
        rng = np.random.default_rng(seed)
        grid, steps = 8, 2
        images = np.zeros((n, 3, grid, grid))  # object map, path, low path
        obj, path = rng.integers(0, 4, (n, 2)), rng.integers(0, 4, (n, 2))
        path[: n // 2] = obj[: n // 2]  # half the paths cross the object
        for i in range(n):
            images[i, 0, obj[i, 0], obj[i, 1]] = 1.0
            images[i, 1:, path[i, 0], path[i, 1]] = 1.0
        hit = (obj == path).all(axis=1)
        disp = np.zeros((n, 1, 2))
        disp[hit, 0, 0] = 0.1
        x = np.concatenate([rng.normal(size=(n, 7 * steps)), images.reshape(n, -1)], axis=1)
        return wm.Episodes(x, disp, hit[:, None], np.array([f"{seed}:{i}" for i in range(n)]), ["o"])

    net = {"kind": "conv", "n_trajectory": 14, "channels": 3, "grid": 8}
    out = wm.experiment({"a": [scenes(300, 1)]}, {"t": scenes(200, 2)}, n=300, epochs=40, seed=0, hidden=32, net=net)
    assert out["t"]["a"]["f1"][0] > 0.8


def test_the_object_maps_model_learns_one_rule_for_every_object(wm):
    """Two objects, each in a random cell of an 8 x 8 map, and an arm path through some cells, low (at the objects'
    height) or high: an object moves when the low path crosses its cell. One network shared by both objects learns
    it from both; the test scenes are new."""

    def scenes(n: int, seed: int):
        rng = np.random.default_rng(seed)
        grid, steps = 8, 2
        maps = np.zeros((n, 4, grid, grid))  # object 0, object 1, path, low path
        moved = np.zeros((n, 2), dtype=bool)
        for i in range(n):
            cells = rng.permutation(grid * grid)[:2]
            for k, c in enumerate(cells):
                maps[i, k].flat[c] = 1.0
            crossed = cells[rng.integers(0, 2)] if rng.random() < 0.6 else rng.integers(0, grid * grid)
            low = rng.random() < 0.5
            maps[i, 2].flat[crossed] = 1.0
            maps[i, 3].flat[crossed] = float(low)
            moved[i] = low & (cells == crossed)
        disp = np.zeros((n, 2, 2))
        disp[moved, 0] = 0.1
        x = np.concatenate([rng.normal(size=(n, 7 * steps)), maps.reshape(n, -1)], axis=1)
        return wm.Episodes(x, disp, moved, np.array([f"{seed}:{i}" for i in range(n)]), ["o0", "o1"])

    net = {"kind": "object_maps", "n_trajectory": 14, "grid": 8}
    out = wm.experiment({"a": [scenes(400, 1)]}, {"t": scenes(200, 2)}, n=400, epochs=40, seed=0, hidden=32, net=net)
    assert out["t"]["a"]["f1"][0] > 0.8


def test_the_object_poses_model_sees_the_arm_relative_to_each_object(wm, wmd):
    """Objects anywhere on a 1 m square; an object moves when the arm's path passes within 5 cm of it below 5 cm
    height. The rule holds wherever the objects stand, so the shared network learns it for new layouts."""
    steps, n_objects = 2, 2

    def scenes(n: int, seed: int):
        rng = np.random.default_rng(seed)
        start = np.zeros((n, n_objects, 4))
        start[..., :2] = rng.uniform(-0.5, 0.5, (n, n_objects, 2))
        start[..., 2] = 1.0  # yaw 0: cos, sin
        arm = np.zeros((n, steps, wmd.ARM_LINKS, 3))
        arm[..., :2] = rng.uniform(-0.5, 0.5, (n, 1, 1, 2))
        target = rng.integers(0, n_objects, n)
        near = rng.random(n) < 0.6
        arm[near, :, -1, :2] = start[near, target[near], None, :2] + rng.normal(0, 0.02, (near.sum(), steps, 2))
        arm[..., 2] = rng.choice([0.02, 0.3], (n, 1, 1))
        gap = np.linalg.norm(arm[:, None, :, :, :2] - start[:, :, None, None, :2], axis=-1)  # (n, k, steps, links)
        moved = ((gap < 0.05) & (arm[:, None, ..., 2] < 0.05)).any(axis=(2, 3))
        disp = np.zeros((n, n_objects, 2))
        disp[moved, 0] = 0.1
        x = np.concatenate([rng.normal(size=(n, 7 * steps)), start.reshape(n, -1), arm.reshape(n, -1)], axis=1)
        return wm.Episodes(x, disp, moved, np.array([f"{seed}:{i}" for i in range(n)]), ["o0", "o1"])

    net = {"kind": "object_poses", "n_trajectory": 14, "steps": steps}
    out = wm.experiment({"a": [scenes(600, 1)]}, {"t": scenes(300, 2)}, n=600, epochs=60, seed=0, hidden=64, net=net)
    assert out["t"]["a"]["f1"][0] > 0.8
