"""How many times does each vendor-specific instruction of the simulator, the renderer and the encoders run in a
babblegen run? Approximate reciprocals (``rcpps``, ``rsqrtps``, their scalar, VEX and AVX-512 forms) return what the
CPU maker chose within the ISA's error bound: ``rsqrtps(10.0f)`` is ``0x3EA1E800`` on an AMD CPU and ``0x3EA1E000``
on an Intel one. A run that executes none computes the same on both.

    python benchmarks/count_vendor_instructions.py --attempts 1200 --starts fixed
    python benchmarks/count_vendor_instructions.py --attempts 150 --box-hulls off   # the counter at work: thousands
    python benchmarks/count_vendor_instructions.py --jit --llvm-cpus haswell znver3

The run: finds every such instruction in the libraries with ``objdump``, then runs ``babblegen generate
--workers 1 --no-rerun --no-progress`` (in one process) under gdb with a counting breakpoint on each (gdb_count_hits.py)
and prints a table (library, function, instruction, count) and the total. Exit status 1 when any ran, 2 when the run
itself failed. The libraries: ``simulator`` (every shared library of SAPIEN: PhysX is linked into libsapien.so),
``renderer`` (Mesa's lavapipe and the LLVM it generates shader code with), ``encoders`` (PyAV's FFmpeg, x264, x265,
SVT-AV1). With ``--depth`` the run records depth maps, so x265 encodes them too.

``--jit``: lavapipe's shader code is generated at run time, so no file holds it. A World renders every camera kind
(colour, depth, masks) and one rollout's frames, then its executable anonymous memory (the JIT-compiled shaders) is
read and disassembled, and the approximate reciprocals in it counted; ``--llvm-cpus`` repeats this with LLVM told
another host CPU model (benchmarks/fake_llvm_cpu.c, as in check_render_dispatch.py).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DRIVER = Path(__file__).with_name("gdb_count_hits.py")

# Approximate reciprocals and reciprocal square roots: SSE (rcpps, rsqrtps, rcpss, rsqrtss), their VEX forms (v...),
# AVX-512 (vrcp14*, vrsqrt14*; vrcp28*, vrsqrt28* of AVX512ER), AVX512-FP16 (vrcpph, vrsqrtph, ...) and 3DNow!.
APPROXIMATE = re.compile(
    r"^(v?rcp(ps|ss)|v?rsqrt(ps|ss)|vrcp(14|28)(ps|ss|pd|sd)|vrsqrt(14|28)(ps|ss|pd|sd)|vrcp(ph|sh)|vrsqrt(ph|sh)"
    r"|pfrcp\w*|pfrsqrt\w*)$"
)
FUNCTION = re.compile(r"^([0-9a-f]+) <(.*)>:$")
INSTRUCTION = re.compile(r"^\s*([0-9a-f]+):\s+(\S+)")


@dataclass(frozen=True)
class Site:
    library: str  # real path
    address: int  # virtual address in the library (objdump's)
    file_offset: int
    function: str
    instruction: str


def short_name(function: str) -> str:
    """A demangled function name without its parameter list and the ``@@Base`` suffix."""
    name = function.split("@@")[0]
    depth, cut = 0, len(name)
    for i, c in enumerate(name):
        if c in "<(":
            if c == "(" and depth == 0:
                cut = i
                break
            depth += c == "<"
        elif c == ">":
            depth -= 1
    return name[:cut].removeprefix("void ").strip()


def section_offsets(library: Path) -> list[tuple[int, int, int]]:
    """(virtual address, size, file offset) of each section."""
    out = subprocess.run(["objdump", "-h", str(library)], capture_output=True, text=True, check=True).stdout
    sections = []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 7 and parts[0].isdigit():
            sections.append((int(parts[3], 16), int(parts[2], 16), int(parts[5], 16)))
    return sections


def find_sites(library: Path) -> list[Site]:
    """Every approximate-reciprocal instruction in ``library``, with the function that holds it."""
    out = subprocess.run(
        ["objdump", "-d", "-C", "--no-show-raw-insn", str(library)], capture_output=True, text=True, check=True
    ).stdout
    sections = section_offsets(library)
    sites, function = [], "?"
    real = os.path.realpath(library)
    for line in out.splitlines():
        head = FUNCTION.match(line)
        if head:
            function = short_name(head.group(2))
            continue
        insn = INSTRUCTION.match(line)
        if insn and APPROXIMATE.match(insn.group(2)):
            address = int(insn.group(1), 16)
            vma, _, offset = next(s for s in sections if s[0] <= address < s[0] + s[1])
            sites.append(Site(real, address, address - vma + offset, function, insn.group(2)))
    return sites


def library_groups() -> dict[str, list[Path]]:
    """The shared libraries of the simulator, the renderer and the encoders in this environment."""
    site = Path(sysconfig.get_paths()["purelib"])
    simulator = sorted(p for d in ("sapien", "sapien.libs") for p in (site / d).rglob("*.so*") if p.is_file())
    simulator += sorted(p for p in (Path.home() / ".sapien").rglob("*physx*.so*") if p.is_file())
    encoders = sorted(
        p
        for p in (site / "av.libs").glob("*.so*")
        if re.match(r"lib(avcodec|avutil|swscale|x264|x265|SvtAv1Enc)", p.name)
    )
    renderer = []
    for icd in sorted(Path("/usr/share/vulkan/icd.d").glob("lvp_icd*.json")):
        lvp = Path(json.loads(icd.read_text())["ICD"]["library_path"])
        if not lvp.is_absolute():
            lvp = Path("/usr/lib/x86_64-linux-gnu") / lvp
        if lvp.is_file() and lvp not in renderer:
            renderer.append(lvp)
            ldd = subprocess.run(["ldd", str(lvp)], capture_output=True, text=True).stdout
            renderer += [Path(m) for m in re.findall(r"=> (\S*libLLVM\S*)", ldd) if Path(m) not in renderer]
    return {"simulator": simulator, "renderer": renderer, "encoders": encoders}


def count_run(sites: list[Site], generate: list[str], workdir: Path) -> tuple[list[int], int, float]:
    """Run ``babblegen generate <generate>`` under gdb, counting each site's executions; (counts, exit status of
    the run, seconds)."""
    spec, out = workdir / "spec.json", workdir / "counts.json"
    spec.write_text(json.dumps({"sites": [s.__dict__ for s in sites], "out": str(out)}))
    babblegen = Path(sys.executable).with_name("babblegen")
    argv = ["gdb", "-batch", "-nx", "-x", str(DRIVER), "--args", sys.executable, str(babblegen), "generate"]
    env = {**os.environ, "BABBLEGEN_COUNT_SPEC": str(spec)}
    t = time.perf_counter()
    done = subprocess.run(argv + generate, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if not out.exists():
        sys.exit(f"gdb wrote no counts (exit {done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    result = json.loads(out.read_text())
    if result["exit_status"] != 0:
        print(done.stdout[-3000:], done.stderr[-3000:], sep="\n", file=sys.stderr)
    placed = sum(a is not None for a in result["addresses"])
    print(f"{placed} of {len(sites)} sites were loaded and counted")
    for line in done.stdout.splitlines():
        if line.startswith("finished:"):
            print(f"babblegen {line}")
    return result["counts"], result["exit_status"], seconds


def print_table(sites: list[Site], counts: list[int]) -> int:
    """The table, by library and function; returns the total."""
    rows: Counter[tuple[str, str, str]] = Counter()
    static: Counter[tuple[str, str, str]] = Counter()
    for s, n in zip(sites, counts, strict=True):
        key = (Path(s.library).name, s.function, s.instruction)
        rows[key] += n
        static[key] += 1
    width = max((len(f) for _, f, _ in rows), default=8)
    print(f"{'library':<28} {'function':<{width}} {'instruction':<12} {'sites':>5} {'executed':>12}")
    for key in sorted(rows, key=lambda k: (-rows[k], k)):
        lib, function, insn = key
        print(f"{lib[:28]:<28} {function:<{width}} {insn:<12} {static[key]:>5} {rows[key]:>12,}")
    total = sum(counts)
    print(f"total: {total:,} executions of {len(sites)} approximate-reciprocal instructions")
    return total


# --- lavapipe's JIT-compiled shader code --------------------------------------------------------------------------
def jit_child(out: Path) -> None:
    """Child: render every camera kind and one rollout, then disassemble this process's anonymous executable
    memory (lavapipe's shaders) and write the counts of its instructions to ``out``."""
    from dataclasses import asdict

    import numpy as np

    from babblegen.camera_views import CAMERA_PRESETS
    from babblegen.tasks import get_task
    from babblegen.world.rollout import Command
    from babblegen.world.settings import WorldSettings
    from babblegen.world.world import World

    kinds = {"depth": True, "segmentation": True}
    views = [{**asdict(v), **kinds} for v in CAMERA_PRESETS.values()]
    world = World(get_task("noveb_tabletop"), WorldSettings(cameras=views), seed=0)
    world.warm_up()
    world.rollout(Command("ee_waypoints", np.array([[0.45, 0.55, 0.2]])))
    code = bytearray()
    with open("/proc/self/maps") as maps:
        regions = [line.split() for line in maps]
    with open("/proc/self/mem", "rb") as mem:
        for r in regions:
            if len(r) == 5 and "x" in r[1]:  # no file behind it: generated code
                start, end = (int(x, 16) for x in r[0].split("-"))
                mem.seek(start)
                code += mem.read(end - start)
    world.close()
    blob = out.with_suffix(".bin")
    blob.write_bytes(bytes(code))
    asm = subprocess.run(
        ["objdump", "-D", "-b", "binary", "-m", "i386:x86-64", "--no-show-raw-insn", str(blob)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    mnemonics = Counter(m.group(2) for line in asm.splitlines() if (m := INSTRUCTION.match(line)))
    out.write_text(json.dumps({"bytes": len(code), "mnemonics": mnemonics}))


def jit_check(llvm_cpus: list[str], workdir: Path) -> int:
    """Scan lavapipe's generated code for the host CPU model and each of ``llvm_cpus``; returns the approximate
    reciprocals found in all."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from check_render_dispatch import llvm_cpu_settings, llvm_names_asked

    settings = {"own": {}}
    if llvm_cpus:
        settings |= {k.removeprefix("llvm_"): v for k, v in llvm_cpu_settings(llvm_cpus, workdir).items() if k != "own"}
    print(f"{'LLVM CPU':<18} {'code kB':>8} {'instructions':>12} {'FMA':>7} {'approximate':>11}  LLVM was told")
    found = 0
    for name, env in settings.items():
        out, log = workdir / f"jit-{name}.json", workdir / f"jit-{name}.log"
        env = {**os.environ, **env, "BABBLEGEN_LLVM_CPU_LOG": str(log)}
        subprocess.run([sys.executable, __file__, "--jit-child", str(out)], env=env, check=True)
        got = json.loads(out.read_text())
        m = got["mnemonics"]
        approx = {k: v for k, v in m.items() if APPROXIMATE.match(k)}
        fma = sum(v for k, v in m.items() if re.match(r"vf(n?madd|n?msub)", k))
        told = ",".join(llvm_names_asked(log)) or "(own answer)"
        size, total = got["bytes"] / 1024, sum(m.values())
        print(f"{name:<18} {size:>8.0f} {total:>12,} {fma:>7,} {sum(approx.values()):>11}  {told}")
        for k, v in sorted(approx.items()):
            print(f"    {k}: {v}")
        found += sum(approx.values())
    return found


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--attempts", type=int, default=150)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--starts", choices=["fixed", "varied"], default="fixed")
    p.add_argument(
        "--objects", choices=["paper", "varied", "heldout"], default="paper", help="the run's object set [paper]"
    )
    p.add_argument("--pcm", choices=["on", "off"], default="on", help="PhysX's persistent contact manifolds [on]")
    p.add_argument(
        "--box-hulls", choices=["on", "off"], default="on", help="the scene's boxes collide as convex hulls [on]"
    )
    p.add_argument("--depth", action="store_true", help="record depth maps too (x265 encodes them)")
    p.add_argument("--video-codec", default=None, help="h264 (the default) or libsvtav1")
    p.add_argument(
        "--libraries", nargs="+", default=["simulator", "renderer", "encoders"], help="which library groups [all]"
    )
    p.add_argument("--list", action="store_true", help="list the instructions in the libraries; run nothing")
    p.add_argument("--jit", action="store_true", help="scan lavapipe's generated shader code instead of a run")
    p.add_argument("--llvm-cpus", nargs="*", default=[], help="with --jit: also for these LLVM CPU models")
    p.add_argument("--jit-child", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.jit_child:
        jit_child(args.jit_child)
        return
    workdir = Path(tempfile.mkdtemp(prefix="count-vendor-"))
    try:
        if args.jit:
            sys.exit(1 if jit_check(args.llvm_cpus, workdir) else 0)
        groups = library_groups()
        sites: list[Site] = []
        for group in args.libraries:
            for library in groups[group]:
                found = find_sites(library)
                print(f"{group:<10} {library.name:<40} {len(found):>4} approximate-reciprocal instructions")
                sites += found
        if args.list:
            print_table(sites, [0] * len(sites))
            return
        generate = ["--out", str(workdir / "run"), "--max-attempts", str(args.attempts), "--seed", str(args.seed)]
        generate += ["--starts", args.starts, "--workers", "1", "--no-rerun", "--no-progress"]
        generate += ["--objects", args.objects]
        if args.depth:
            generate.append("--depth")
        if args.video_codec:
            generate += ["--video-codec", args.video_codec]
        config = workdir / "world.toml"
        on = {"on": "true", "off": "false"}
        config.write_text(f"[world]\npcm = {on[args.pcm]}\nbox_hulls = {on[args.box_hulls]}\n")
        generate += ["--config", str(config)]
        print(f"babblegen generate {' '.join(generate)}")
        counts, status, seconds = count_run(sites, generate, workdir)
        summary = (workdir / "run" / "babblegen" / "attempts.jsonl").read_text().count("\n") if status == 0 else 0
        print(f"run: exit status {status}, {summary} attempts, {seconds:.0f} s under gdb")
        total = print_table(sites, counts)
        sys.exit(2 if status != 0 else 1 if total else 0)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
