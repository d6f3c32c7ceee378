"""Does lavapipe render the same pixels whatever SIMD code it runs? Many recorded frames of a dataset re-rendered
under several lavapipe settings, each in its own command, compared pixel by pixel.

    python benchmarks/check_render_dispatch.py DATASET [--frames 6000] [--out runs/render_dispatch]

Every setting renders the same scenes: the dataset's recorded joint states and object poses, frame after frame
(the first --frames of them), from the head camera with the run's own settings (colour, and depth and masks where
the run records them). A rare pixel one level apart is what a short run cannot show; thousands of frames can.
Settings: the machine's own; lavapipe as on a CPU without AVX (``GALLIUM_OVERRIDE_CPU_CAPS=sse4.1`` clears AVX,
AVX2, FMA and AVX-512, and lavapipe picks 128-bit vectors), the same told to use 256-bit vectors, and as on a CPU
without AVX-512 (``avx`` clears AVX-512 alone: AVX2 and FMA stay), at its own 256-bit vectors and told to use 128.
With ``--llvm-cpus NAME...`` also lavapipe's shader code generated for other CPU models (LLVM's names: icelake-server,
haswell, znver3...) on this CPU, through benchmarks/fake_llvm_cpu.c, a shim compiled with ``cc`` and preloaded that
answers LLVM's host-CPU question (each setting also reports the names LLVM was given, so a shim never consulted
shows); "llvm_own" loads the shim without changing the answer.

    python benchmarks/check_render_dispatch.py DATASET --settings machine --llvm-cpus icelake-server haswell
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

SETTINGS: dict[str, dict[str, str]] = {
    "machine": {},
    "no_avx": {"GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1"},
    "no_avx_at_256": {"GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1", "LP_NATIVE_VECTOR_WIDTH": "256"},
    "no_avx512": {"GALLIUM_OVERRIDE_CPU_CAPS": "avx"},
    "no_avx512_at_128": {"GALLIUM_OVERRIDE_CPU_CAPS": "avx", "LP_NATIVE_VECTOR_WIDTH": "128"},
}


def render(dataset: Path, frames: int, out: Path) -> None:
    """Child: render the dataset's first ``frames`` recorded frames; every kind to ``out/<kind>.npy``."""
    from babblegen.config import RunConfig
    from babblegen.dataset.lerobot import load_dataset
    from babblegen.dataset.sidecar import read_run_info
    from babblegen.tasks import get_task
    from babblegen.world.rollout import Frames
    from babblegen.world.world import World

    info = read_run_info(dataset)
    config = RunConfig.from_dict(info["config"])
    ds = load_dataset(dataset, info["repo_id"])
    columns = ["observation.state", "observation.environment_state"]
    table = ds.hf_dataset.select(range(min(frames, ds.num_frames))).select_columns(columns).with_format("numpy")[:]
    state = np.asarray(table[columns[0]], dtype=np.float64)
    poses = np.asarray(table[columns[1]], dtype=np.float64).reshape(len(state), -1, 7)
    recorded = Frames(state, state, state[:, :3], poses, np.zeros(poses.shape[:2]), None)
    world = World(get_task(config.task), config.world, seed=config.seed)
    got: dict[str, list[np.ndarray]] = {}
    try:
        for t in range(len(state)):
            world._pose_scene(recorded, t)
            for kind, image in world._render_views([], head=True)["head"].items():
                got.setdefault(kind, []).append(image)
    finally:
        world.close()
    out.mkdir(parents=True, exist_ok=True)
    for kind, images in got.items():
        np.save(out / f"{kind}.npy", np.stack(images))


def llvm_names_asked(log: Path) -> list[str]:
    """The distinct CPU names the shim answered, from its log (none if it was never asked)."""
    return sorted(set(log.read_text().split())) if log.exists() else []


def llvm_cpu_settings(names: list[str], out: Path) -> dict[str, dict[str, str]]:
    """Settings that preload benchmarks/fake_llvm_cpu.c (compiled into ``out``) naming each CPU model to LLVM."""
    shim = out / "fake_llvm_cpu.so"
    out.mkdir(parents=True, exist_ok=True)
    source = Path(__file__).with_name("fake_llvm_cpu.c")
    subprocess.run(["cc", "-shared", "-fPIC", "-O2", "-o", str(shim), str(source), "-ldl"], check=True)
    settings = {"llvm_own": {"LD_PRELOAD": str(shim)}}
    settings |= {f"llvm_{name}": {"LD_PRELOAD": str(shim), "BABBLEGEN_LLVM_CPU": name} for name in names}
    for name, env in settings.items():
        env["BABBLEGEN_LLVM_CPU_LOG"] = str(out / name / "llvm_cpu.txt")
    return settings


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dataset", type=Path)
    p.add_argument("--frames", type=int, default=6000)
    p.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    p.add_argument("--llvm-cpus", nargs="*", default=[], metavar="NAME", help="LLVM CPU names to generate code for")
    p.add_argument("--out", type=Path, default=Path("runs/render_dispatch"))
    p.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.child is not None:
        render(args.dataset, args.frames, args.child)
        return
    settings = dict(SETTINGS)
    if args.llvm_cpus:
        settings |= llvm_cpu_settings(args.llvm_cpus, args.out)
    names = ["machine", *[s for s in args.settings if s != "machine"]]
    names += [s for s in settings if s.startswith("llvm_")]
    for name in names:
        target = args.out / name
        if (target / "rgb.npy").exists():
            continue
        target.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, **settings[name]}
        cmd = [sys.executable, __file__, str(args.dataset), "--frames", str(args.frames), "--child", str(target)]
        subprocess.run(cmd, env=env, check=True)
    reference = {k.stem: np.load(k) for k in (args.out / "machine").glob("*.npy")}
    report = {}
    for name in names[1:]:
        report[name] = {}
        asked = llvm_names_asked(args.out / name / "llvm_cpu.txt") if name.startswith("llvm_") else None
        if asked is not None:
            report[name]["llvm_cpu"] = asked
            print(f"{name:>14}: LLVM was told {', '.join(asked) if asked else 'nothing (the shim was never asked)'}")
        for kind, ref in reference.items():
            other = np.load(args.out / name / f"{kind}.npy")
            apart = np.abs(other.astype(np.int32) - ref.astype(np.int32))
            per_frame = apart.reshape(len(ref), -1).max(axis=1)
            frames = np.flatnonzero(per_frame)
            report[name][kind] = {
                "frames": len(ref),
                "frames_differing": len(frames),
                "pixels_differing": int((apart.reshape(*apart.shape[:3], -1).max(axis=3) > 0).sum()),
                "largest_difference": int(apart.max()),
                "first_frames": frames[:5].tolist(),
            }
            r = report[name][kind]
            print(
                f"{name:>14} {kind:>12}: {r['frames_differing']} of {r['frames']} frames differ "
                f"({r['pixels_differing']} pixels, by up to {r['largest_difference']})"
            )
    (args.out / "report.json").write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
