"""scripts/setup.sh installs every Python package at the version scripts/constraints.txt pins: a run's values depend on
some of them (the pHash's DCT and resize, PhysX, the encoders), so two machines set up apart run the same code."""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import pytest
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
CONSTRAINTS = ROOT / "scripts" / "constraints.txt"


def pins() -> dict[str, str]:
    lines = [line.strip() for line in CONSTRAINTS.read_text().splitlines()]
    return dict(line.split("==", 1) for line in lines if line and not line.startswith("#"))


def test_constraints_pin_every_package_the_run_depends_on() -> None:
    pinned = {name.lower().replace("_", "-") for name in pins()}
    for package in ("sapien", "mani-skill", "numpy", "scipy", "pillow", "imagehash", "av", "torch", "lerobot", "ompl"):
        assert package in pinned, package
    assert all(version and "," not in version for version in pins().values())


@pytest.mark.skipif(
    not (Path(sys.prefix) / ".setup-stamp").exists(), reason="this environment was not made by scripts/setup.sh"
)
def test_setup_installed_the_pinned_versions() -> None:
    wrong = {}
    for name, version in pins().items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            wrong[name] = (version, None)
            continue
        if Version(installed).public != Version(version).public:
            wrong[name] = (version, installed)
    assert not wrong, f"installed versions differ from scripts/constraints.txt: {wrong}"
