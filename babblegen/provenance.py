"""What made a dataset, recorded in its run.json beside the configuration: the package versions and the machine
(CPU model and instruction-set extensions, Mesa). Neither is an input of the run: the same seed and configuration
are meant to give the same files anywhere; these say what ran it when two datasets are compared."""

from __future__ import annotations

import importlib.metadata
import platform
import subprocess
from pathlib import Path

from babblegen.interrupts import spawning

PACKAGES = (
    "babblegen",
    "sapien",
    "mani-skill",
    "ompl",
    "torch",
    "lerobot",
    "imagehash",
    "rerun-sdk",
    "numpy",
    "scipy",
    "pillow",  # pHash resizes the behaviour image with it (imagehash)
    "av",  # the video encoders
)
# the CPU's instruction-set extensions that decide which code numpy, lavapipe and the encoders run
CPU_FLAGS = ("sse4_2", "avx", "avx2", "fma", "bmi2", "avx512f", "avx512vl", "avx512_fp16", "amx_tile")


def versions() -> dict[str, str]:
    """Python's and each package's version in PACKAGES ("not installed" where one is missing)."""
    out = {"python": platform.python_version()}
    for p in PACKAGES:
        try:
            out[p] = importlib.metadata.version(p)
        except importlib.metadata.PackageNotFoundError:
            out[p] = "not installed"
    return out


def machine() -> dict[str, object]:
    """Where the run started: the CPU (model and the extensions in CPU_FLAGS) and the Mesa that renders, so that two
    datasets of one seed can be compared knowing what ran them. Not an input of the run."""
    info: dict[str, object] = {"machine": platform.machine()}
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    fields: dict[str, str] = {}
    for line in lines:
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
        if not line.strip():
            break  # the first processor is enough
    if fields:
        model = fields.get("model name", "?")
        info["cpu"] = f"{model} (family {fields.get('cpu family', '?')}, model {fields.get('model', '?')})"
        flags = set(fields.get("flags", "").split())
        info["cpu_flags"] = [f for f in CPU_FLAGS if f in flags]
    try:
        with spawning():  # a signal to the whole process group (Ctrl-C as a run opens) does not cut it short
            query = subprocess.Popen(
                ["dpkg-query", "-W", "-f=${Version}", "mesa-vulkan-drivers"],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
        try:
            version = query.communicate(timeout=10)[0]
        finally:
            query.kill()  # (when it took too long)
        info["mesa"] = version.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        info["mesa"] = "unknown"
    return info


def differences_from_here(info: dict) -> list[str]:
    """How the machine and packages that made a dataset (run.json) differ from this one's: where to look first."""
    lines = []
    made_here = {"machine": machine(), "versions": versions()}
    for name, here in made_here.items():
        recorded = info.get(name)
        if not recorded:
            lines.append(f"{name}: not recorded in this dataset's run.json (made before it was)")
            continue
        for key in sorted(set(recorded) | set(here)):
            if recorded.get(key) != here.get(key):
                lines.append(f"{name}.{key}: {recorded.get(key)} recorded, {here.get(key)} here")
    return lines
