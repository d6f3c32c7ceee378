"""Shared fixtures: small real datasets made once per test session with the real CLI; the test tiers.

`small_noveb_dataset` (NovEB, with Rerun recordings) and `small_random_dataset` (random babbling), both of seed 0
from the default varied starts, and `small_heldout_dataset` (uniform random waypoints from varied starts, seed 7)
each hold 24 attempts at 64x64 pixels, committed after every generation. Treat them as read-only: copy what a
test changes.

Two tiers: tests that run the simulator are marked `sim` (here for those that use a simulated fixture,
explicitly for the others); `pytest -m "not sim"` is the fast tier, `pytest` runs both.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

# LeRobot loads a dataset through Hugging Face `datasets`, which caches an Arrow copy of its tables: the tests'
# copies go to a folder of their own, removed at the end, not to the user's cache (this process, the worker
# processes and the CLI subprocesses alike)
_HF_DATASETS_CACHE = tempfile.mkdtemp(prefix="babblegen-tests-hf-datasets-")
os.environ["HF_DATASETS_CACHE"] = _HF_DATASETS_CACHE


def pytest_sessionfinish(session, exitstatus) -> None:
    shutil.rmtree(_HF_DATASETS_CACHE, ignore_errors=True)


# fixtures that build a World or make a dataset with the simulator
SIM_FIXTURES = {
    "small_noveb_dataset", "small_random_dataset", "small_heldout_dataset", "small_run", "small_paper_run", "world",
    "push", "one_worker",
}  # fmt: skip

# 6 children per generation (the default is 128): 24 attempts then span several generations and commit points
SMALL_RUN = ["--workers", "1", "--max-attempts", "24", "--checkpoint-every", "1", "--children", "6"]
SMALL_RUN += ["--width", "64", "--height", "64", "--no-progress"]


def _generate(out: Path, *extra: str) -> Path:
    from babblegen.cli import main

    assert main(["generate", "--out", str(out), *SMALL_RUN, *extra]) == 0
    return out


@pytest.fixture(scope="session")
def small_noveb_dataset(tmp_path_factory) -> Path:
    return _generate(tmp_path_factory.mktemp("noveb") / "ds", "--explorer", "noveb", "--rerun")


@pytest.fixture(scope="session")
def small_random_dataset(tmp_path_factory) -> Path:
    return _generate(tmp_path_factory.mktemp("random") / "ds", "--explorer", "random")


@pytest.fixture(scope="session")
def small_heldout_dataset(tmp_path_factory) -> Path:
    """Uniform random waypoints from varied starts of the paper's objects, seeded apart from the two above (a world
    model's test set; upright objects, as the goals' tests assume)."""
    out = tmp_path_factory.mktemp("heldout") / "ds"
    return _generate(out, "--explorer", "random_waypoints", "--starts", "varied", "--objects", "paper", "--seed", "7")


# modules whose every test runs the simulator: the fast tier does not even import them (SAPIEN, OMPL)
SIM_MODULES = {
    "test_contacts.py", "test_kinematics.py", "test_parallel.py", "test_reference.py", "test_scenes.py", "test_world.py"
}  # fmt: skip


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    if collection_path.name in SIM_MODULES and config.getoption("markexpr", "").replace(" ", "") == "notsim":
        return True
    return None


def pytest_collection_modifyitems(config, items) -> None:
    for item in items:
        if item.path.name in SIM_MODULES or SIM_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.sim)
