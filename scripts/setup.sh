#!/usr/bin/env bash
# Set up babblegen on a fresh Debian 12 / Ubuntu machine: system packages for CPU rendering and video
# decoding, a .venv with Python 3.12, and the package installed editable with its dev extras.
# Idempotent: a second run with nothing missing takes a few seconds.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

# --- system packages -------------------------------------------------------------------------------
. /etc/os-release
apt_updated=0
apt_update() { if [ "$apt_updated" -eq 0 ]; then say "apt-get update"; $SUDO apt-get update -qq; apt_updated=1; fi; }
have_pkg() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"; }
mesa_major() { dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | sed -E 's/^([0-9]+:)?([0-9]+).*/\2/'; }

# SAPIEN renders through Vulkan only. Without a GPU that is Mesa's lavapipe, which must be Mesa >= 23
# (Debian 12's own 22.3 fails with "failed to find a rendering device"); bookworm-backports has 25.x.
need=()
for p in libvulkan1 ffmpeg; do have_pkg "$p" || need+=("$p"); done
if [ ${#need[@]} -gt 0 ]; then
  apt_update
  say "installing ${need[*]} (Vulkan loader, FFmpeg libraries for video decoding)"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
if ! have_pkg mesa-vulkan-drivers || [ "$(mesa_major)" -lt 23 ]; then
  if [ "${ID:-}" = "debian" ] && [ "${VERSION_CODENAME:-}" = "bookworm" ]; then
    src=/etc/apt/sources.list.d/bookworm-backports.sources
    if [ ! -f "$src" ]; then
      say "adding the bookworm-backports apt source (for Mesa lavapipe >= 23)"
      printf 'Types: deb\nURIs: http://deb.debian.org/debian\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
        | $SUDO tee "$src" >/dev/null
      apt_updated=0
    fi
    apt_update
    say "installing mesa-vulkan-drivers from bookworm-backports"
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports mesa-vulkan-drivers >/dev/null
  else
    apt_update
    say "installing mesa-vulkan-drivers"
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers >/dev/null
  fi
fi
say "Mesa Vulkan drivers $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers)"

# --- Python 3.12 -----------------------------------------------------------------------------------
find_python() {
  for c in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.12*/bin/python3.12 python3.12 /usr/bin/python3.12; do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import venv, ensurepip' 2>/dev/null; then
      command -v "$c"; return 0
    fi
  done
  return 1
}
PY=$(find_python || true)
if [ -z "$PY" ]; then
  apt_update
  say "installing python3.12 and python3.12-venv"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3.12 python3.12-venv >/dev/null
  PY=$(find_python)
fi

# --- virtual environment ---------------------------------------------------------------------------
if [ ! -x .venv/bin/python ]; then
  say "creating .venv with $PY"
  "$PY" -m venv .venv
fi
stamp_want=$(cat pyproject.toml scripts/setup.sh scripts/constraints.txt | sha256sum | cut -d' ' -f1)
if [ "$(cat .venv/.setup-stamp 2>/dev/null)" != "$stamp_want" ]; then
  say "installing babblegen (editable, with dev extras) into .venv; the first time takes a few minutes"
  .venv/bin/python -m pip install -q --upgrade pip
  # no wheel cache: the downloads (PyTorch's are several GB) would stay in ~/.cache beside their installed copy;
  # every package at the version in scripts/constraints.txt, so that two machines set up months apart run the same code
  .venv/bin/python -m pip install -q --no-cache-dir -c scripts/constraints.txt -e ".[dev]"
  echo "$stamp_want" > .venv/.setup-stamp
else
  say ".venv is up to date"
fi
say "done: $(.venv/bin/python --version), babblegen $(.venv/bin/python -c 'import importlib.metadata as m; print(m.version("babblegen"))')"
