#!/usr/bin/env bash
# Install babblegen from a wheel built from this checkout into a fresh virtual environment (not editable; the
# dependencies are .venv's, nothing is downloaded) and run it away from the checkout: every package of the source
# tree imports from the wheel, `babblegen generate` runs with 2 worker processes, and LeRobot loads what it wrote.
# The editable install in .venv finds any package of the source tree, listed for the build or not; this finds one
# a wheel lacks. Needs the .venv of scripts/setup.sh; takes a few minutes; leaves nothing behind.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
PY=$ROOT/.venv/bin/python
export HF_HUB_OFFLINE=1 PIP_DISABLE_PIP_VERSION_CHECK=1
say() { printf '\033[1m[check_wheel]\033[0m %s\n' "$*"; }

TMP=$(mktemp -d -t babblegen-wheel.XXXXXX)
trap 'rm -rf "$TMP"' EXIT
mkdir "$TMP/src" "$TMP/dist" "$TMP/run"

# --- the wheel, built from a copy of the sources: a build in the checkout reuses its build/lib, where the packages
# an earlier build had stay (and would hide one this build leaves out) ---------------------------------------------
"$PY" - "$TMP/src" <<'EOF'
import shutil
import sys
import tomllib
from pathlib import Path

dest = Path(sys.argv[1])
for name in ("pyproject.toml", "README.md"):
    shutil.copy2(name, dest / name)
for folder in set(tomllib.loads(Path("pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].values()):
    shutil.copytree(folder, dest / folder, ignore=shutil.ignore_patterns("__pycache__"))
EOF
say "building the wheel"
"$PY" -m pip wheel -q --no-deps --no-build-isolation -w "$TMP/dist" "$TMP/src"
WHEEL=$(echo "$TMP"/dist/babblegen-*.whl)

# --- a fresh environment with the wheel, and .venv's packages as a plain sys.path entry: .venv's .pth files do not
# run, so the editable install's finder (which would import whatever the wheel lacks from the checkout) stays out --
say "installing $(basename "$WHEEL") into a fresh virtual environment"
"$PY" -m venv "$TMP/venv"
VPY=$TMP/venv/bin/python
"$VPY" -m pip install -q --no-deps --no-index "$WHEEL"
"$PY" -c 'import sysconfig; print(sysconfig.get_path("purelib"))' \
  > "$("$VPY" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/babblegen-check-deps.pth"

cd "$TMP/run"  # not the checkout, which would be importable from the working directory
say "importing every package of the source tree from the wheel"
"$VPY" - "$ROOT" <<'EOF'
import importlib
import importlib.util
import sys
import tomllib
from importlib.resources import files
from pathlib import Path

root, venv = Path(sys.argv[1]), Path(sys.prefix)
assert not any("__editable__" in repr(finder) for finder in sys.meta_path), sys.meta_path
problems = []
for package, folder in tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].items():
    for init in sorted((root / folder).rglob("__init__.py")):
        name = ".".join([package, *init.parent.relative_to(root / folder).parts])
        try:
            spec = importlib.util.find_spec(name)
        except ImportError as e:
            problems.append(f"{name} does not import ({e})")
            continue
        if spec is None or spec.origin is None:
            problems.append(f"{name} is not in the wheel")
        elif not Path(spec.origin).is_relative_to(venv):
            problems.append(f"{name} imports from {spec.origin}, not from the wheel")
for asset in sorted((root / "tasks" / "assets").iterdir()):
    if not (files("babblegen.tasks") / "assets" / asset.name).is_file():
        problems.append(f"babblegen/tasks/assets/{asset.name} is not in the wheel")
if problems:
    sys.exit("check_wheel: " + "; ".join(problems))
for name in ("babblegen", "babblegen.parallel"):
    print(f"{name}: {importlib.import_module(name).__file__}")
EOF
if "$TMP/venv/bin/babblegen" --help | grep -q "unavailable:"; then
  "$TMP/venv/bin/babblegen" --help | grep -A1 "unavailable:" >&2
  exit 1
fi

say "babblegen generate with 2 worker processes"
"$TMP/venv/bin/babblegen" generate --out "$TMP/run/dataset" --workers 2 --max-attempts 6 --no-rerun --no-progress
"$VPY" - "$TMP/run/dataset" <<'EOF'
import sys

from lerobot.datasets.lerobot_dataset import LeRobotDataset

ds = LeRobotDataset("babblegen/dataset", root=sys.argv[1])
assert ds.meta.total_episodes >= 1, f"no episode in {sys.argv[1]}"
frame = ds[0]
print(f"LeRobot loads {ds.meta.total_episodes} episodes, {ds.meta.total_frames} frames; frame 0 has {len(frame)} keys")
EOF
say "the wheel works"
