"""Shared fixtures: small real datasets made once per test session with the real CLI.

`small_noveb_dataset` (NovEB, with Rerun recordings) and `small_random_dataset` (random babbling) each hold 24
attempts at 64x64 pixels, committed after every generation. Treat them as read-only: copy what a test changes.
"""

from __future__ import annotations

from pathlib import Path

import pytest

SMALL_RUN = ["--max-attempts", "24", "--checkpoint-every", "1", "--width", "64", "--height", "64", "--no-progress"]


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
