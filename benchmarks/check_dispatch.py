"""Does a run's data depend on which SIMD or BLAS code the CPU runs? The same short run under several dispatch
settings, each in its own command (the variables are changed for that command alone), compared attempt by attempt.

    python benchmarks/check_dispatch.py --attempts 150 --seed 1 [--starts varied] [--out runs/dispatch]

Settings: the machine's own environment; OpenBLAS choosing its kernels for this CPU (``OPENBLAS_CORETYPE`` and
``OPENBLAS_L2_SIZE`` unset together); numpy without its AVX-512 code; lavapipe at 256-bit vectors, as on a CPU without
AVX-512 (Mesa's "avx" override clears AVX-512 alone), and as on a CPU without AVX ("sse4.1": no AVX, AVX2 or FMA)
at its own 128-bit vectors and told to use 256; torch's kernels at AVX2 and without SIMD (``ATEN_CPU_CAPABILITY``).
A short run rarely shows lavapipe's rare pixel one level apart: benchmarks/check_render_dispatch.py re-renders
thousands of recorded frames.
For each, the first attempt whose sidecar row differs from the machine's own run and the fields that differ
(genome, final poses, descriptor...), and whether the episodes' LeRobot frames and videos are byte-identical.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

NUMPY_NO_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
SETTINGS: dict[str, dict[str, str | None]] = {
    "machine": {},
    "openblas_own_kernels": {"OPENBLAS_CORETYPE": None, "OPENBLAS_L2_SIZE": None},
    "numpy_no_avx512": {"NPY_DISABLE_CPU_FEATURES": NUMPY_NO_AVX512},
    # lavapipe as on a CPU without AVX (128-bit vectors), and without AVX-512; the vector width alone at 128 on an
    # AVX-512 CPU crashes Mesa 25.0's JIT-compiled shaders (heap corruption), so the CPU features it sees are
    # lowered with it, as on such a machine
    "lavapipe_no_avx": {"GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1", "LP_NATIVE_VECTOR_WIDTH": "128"},
    "lavapipe_256": {"LP_NATIVE_VECTOR_WIDTH": "256"},
    "lavapipe_no_avx512": {"GALLIUM_OVERRIDE_CPU_CAPS": "avx"},
    # a CPU without AVX whose lavapipe is told to use 256-bit vectors anyway
    "lavapipe_no_avx_at_256": {"GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1", "LP_NATIVE_VECTOR_WIDTH": "256"},
    # torch's own kernels (the controller's action arithmetic) as on a CPU without AVX-512, and without any SIMD
    "torch_avx2": {"ATEN_CPU_CAPABILITY": "avx2"},
    "torch_default": {"ATEN_CPU_CAPABILITY": "default"},
}
IGNORED = {"timings", "worker_failures"}


def run(out: Path, env_change: dict[str, str | None], args: argparse.Namespace) -> None:
    env = dict(os.environ)
    for key, value in env_change.items():
        if value is None:
            env.pop(key, None)
        else:
            env[key] = value
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--seed", str(args.seed)]
    cmd += ["--max-attempts", str(args.attempts), "--workers", "1", "--no-rerun", "--no-progress"]
    cmd += ["--starts", args.starts]
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        (out / "FAILED").write_text(f"exit {done.returncode}\n{done.stderr[-4000:]}")


def rows(root: Path) -> list[dict]:
    lines = (root / "babblegen" / "attempts.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if k not in IGNORED} for line in lines]


def digests(root: Path) -> dict[str, str]:
    files = [*root.glob("data/**/*.parquet"), *root.glob("videos/**/*.mp4")]
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--attempts", type=int, default=150)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--starts", default="fixed", choices=["fixed", "varied"])
    p.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    p.add_argument("--out", type=Path, default=Path("runs/dispatch"))
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    names = ["machine", *[s for s in args.settings if s != "machine"]]
    for name in names:
        target = args.out / f"{name}-{args.starts}-{args.seed}"
        if not target.exists():
            run(target, SETTINGS[name], args)
    reference = args.out / f"machine-{args.starts}-{args.seed}"
    ref_rows, ref_files = rows(reference), digests(reference)
    for name in names[1:]:
        other = args.out / f"{name}-{args.starts}-{args.seed}"
        if (other / "FAILED").exists():
            print(f"{name}: the run failed ({(other / 'FAILED').read_text().splitlines()[0]}), {len(rows(other))} rows")
            continue
        got = rows(other)
        first = next((i for i, (a, b) in enumerate(zip(ref_rows, got, strict=False)) if a != b), None)
        same_files = digests(other) == ref_files
        if first is None and len(got) == len(ref_rows):
            print(f"{name}: all {len(got)} sidecar rows equal; data and videos {'equal' if same_files else 'DIFFER'}")
            continue
        if first is None:
            print(f"{name}: {len(got)} rows against {len(ref_rows)}")
            continue
        fields = sorted(k for k in ref_rows[first] if ref_rows[first].get(k) != got[first].get(k))
        print(f"{name}: first difference at attempt {ref_rows[first]['attempt']}, in {', '.join(fields)}")


if __name__ == "__main__":
    main()
