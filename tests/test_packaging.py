"""A wheel built from the checkout holds every package of the source tree at its installed name, and the tasks'
assets. pyproject.toml maps folders to packages (tasks/ installs as babblegen.tasks); a package the build leaves
out goes unnoticed in the editable install and fails only where babblegen is installed from a wheel."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def package_dirs() -> dict[str, str]:
    """pyproject.toml's package-dir: installed package name -> source folder."""
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]


@pytest.fixture(scope="module")
def wheel_files(tmp_path_factory: pytest.TempPathFactory) -> set[str]:
    """The paths inside a wheel built (without build isolation, as offline as the tests) from a copy of the
    sources: a build in the checkout reuses its build/lib, where packages an earlier build had stay."""
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for folder in set(package_dirs().values()):
        shutil.copytree(ROOT / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__"))
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out), str(src)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (wheel,) = out.glob("babblegen-*.whl")
    with zipfile.ZipFile(wheel) as z:
        return set(z.namelist())


def test_the_mapping_covers_the_source_folders():
    assert {"babblegen", "tasks", "exporters"} <= set(package_dirs().values())


def test_the_wheel_holds_every_package_at_its_installed_name(wheel_files):
    expected = []
    for package, folder in package_dirs().items():
        for init in sorted((ROOT / folder).rglob("__init__.py")):
            installed = "/".join([*package.split("."), *init.parent.relative_to(ROOT / folder).parts])
            expected += [f"{installed}/{module.name}" for module in sorted(init.parent.glob("*.py"))]
    assert "babblegen/parallel/__init__.py" in expected and "babblegen/tasks/__init__.py" in expected
    missing = [path for path in expected if path not in wheel_files]
    assert not missing, f"the wheel lacks {missing}"


def test_the_wheel_holds_the_task_assets(wheel_files):
    assets = sorted(p.name for p in (ROOT / "tasks" / "assets").iterdir() if p.is_file())
    assert assets
    missing = [name for name in assets if f"babblegen/tasks/assets/{name}" not in wheel_files]
    assert not missing, f"the wheel lacks the task assets {missing}"
