"""babblegen's episode statistics against LeRobot's ``compute_episode_stats``: identical arrays."""

from __future__ import annotations

import numpy as np
import pytest
from lerobot.datasets.compute_stats import compute_episode_stats

from babblegen.exporters.lerobot_stats import image_stats, numeric_stats


def columns_of(length: int, seed: int) -> tuple[dict, dict]:
    """Columns like an episode's: float32 vectors (one constant, one with many ties), float64 timestamps, int64
    indexes."""
    rng = np.random.default_rng(seed)
    columns = {
        "state": rng.normal(size=(length, 7)).astype(np.float32),
        "poses": np.round(rng.normal(size=(length, 28)), 1).astype(np.float32),
        "contacts": (rng.random((length, 4)) > 0.7).astype(np.float32),
        "still": np.full((length, 3), 0.25, dtype=np.float32),
        "timestamp": np.arange(length) / 10,
        "frame_index": np.arange(length),
        "episode_index": np.full(length, 5),
    }
    features = {k: {"dtype": str(v.dtype), "shape": v.shape[1:] or (1,)} for k, v in columns.items()}
    return columns, features


@pytest.mark.parametrize(("length", "seed"), [(1, 0), (2, 1), (3, 2), (45, 3), (256, 4), (1000, 5)])
def test_numeric_statistics_are_lerobots_bit_for_bit(length, seed):
    columns, features = columns_of(length, seed)
    want, got = compute_episode_stats(columns, features), numeric_stats(columns, features)
    assert set(got) == set(want)
    for key, stats in want.items():
        assert set(got[key]) == set(stats), key
        for name, value in stats.items():
            assert got[key][name].dtype == value.dtype and got[key][name].shape == value.shape, (key, name)
            np.testing.assert_array_equal(got[key][name], value, err_msg=f"{key} {name}")


@pytest.mark.parametrize("length", [3, 45, 256])
def test_image_statistics_match_lerobots(length, tmp_path):
    from PIL import Image

    rng = np.random.default_rng(length)
    images = rng.integers(0, 256, (length, 32, 48, 3), dtype=np.uint8)
    images[:, :8] = 40  # a flat region: many equal values
    paths = []  # LeRobot's writer computes image statistics from the frames it saved as PNG files
    for i, image in enumerate(images):
        paths.append(str(tmp_path / f"frame-{i:04d}.png"))
        Image.fromarray(image).save(paths[-1])
    want = compute_episode_stats({"img": paths}, {"img": {"dtype": "image"}})["img"]
    got = image_stats(images)
    assert set(got) == set(want)
    for name, value in want.items():
        assert got[name].shape == value.shape, name
        if name in ("mean", "std"):  # LeRobot accumulates these in float32; the counts give them exactly
            np.testing.assert_allclose(got[name], value, rtol=1e-3, err_msg=name)
        else:
            np.testing.assert_array_equal(got[name], value, err_msg=name)
    from lerobot.datasets.compute_stats import sample_indices

    # against the frames LeRobot samples, in float64: right to the float32 the statistics are stored in
    sampled = images[sample_indices(length)].astype(np.float64) / 255
    np.testing.assert_allclose(got["mean"].ravel(), sampled.mean(axis=(0, 1, 2)), rtol=1e-6)
    np.testing.assert_allclose(got["std"].ravel(), sampled.std(axis=(0, 1, 2)), rtol=1e-6)
