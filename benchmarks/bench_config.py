"""babblegen's configuration (argparse + TOML + dataclasses) against draccus and tyro, on the real RunConfig.

babblegen today: ``babblegen/cli.py`` parses flags with argparse, ``babblegen/config.py`` merges them over a TOML
file and builds the ``RunConfig`` dataclass tree (with its ``noveb`` and ``world`` sections) in
``RunConfig.from_dict``, whose dataclasses check values in ``__post_init__``; ``RunConfig.validate`` checks
the rest. draccus (LeRobot's choice) and tyro build the same tree straight from the dataclasses, with dotted
flags (``--noveb.population``, ``--world.camera_width`` / ``--world.camera-width``); draccus also reads TOML
(``config_path``), tyro does not (a TOML file goes through ``RunConfig.from_dict`` and is passed as ``default``).

What is measured:

1. import time: wall time of ``python -c "import ..."`` in a fresh interpreter, less an empty one (best of 3),
   and what ``babblegen --help`` imports (``python -X importtime``);
2. the wall time of ``babblegen --help`` and ``babblegen generate --help`` today, and of ``--help`` for a
   draccus / tyro parser of RunConfig (fresh processes, best of 3);
3. time to turn a typical command line (and the same line with a TOML file) into a RunConfig, in process after
   the imports (best of 5); the three results are checked to be equal;
4. what each does with bad input (unknown key, wrong type, out-of-range value, in flags and in the TOML file),
   ``validate()`` included; a different verdict from today's is marked.

Run: ``.venv/bin/python benchmarks/bench_config.py`` (about half a minute).
"""

from __future__ import annotations

import contextlib
import io
import math
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from timing import per_call

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PY = sys.executable

# A typical run: flags from the top level and from both sections.
TODAY_ARGS = [
    "--seed", "3", "--generations", "50", "--population", "16", "--k", "4", "--sigma", "0.2",
    "--width", "160", "--height", "120", "--workers", "2", "--no-rerun",
]  # fmt: skip
DRACCUS_ARGS = [
    "--seed", "3", "--noveb.generations", "50", "--noveb.population", "16", "--noveb.k", "4",
    "--noveb.sigma", "0.2", "--world.camera_width", "160", "--world.camera_height", "120", "--workers", "2",
    "--rerun", "false",
]  # fmt: skip
TYRO_ARGS = [
    "--seed", "3", "--noveb.generations", "50", "--noveb.population", "16", "--noveb.k", "4",
    "--noveb.sigma", "0.2", "--world.camera-width", "160", "--world.camera-height", "120", "--workers", "2",
    "--no-rerun",
]  # fmt: skip
TYPICAL_TOML = """\
seed = 3
workers = 2
rerun = false

[noveb]
population = 16
generations = 50
k = 4
sigma = 0.2

[world]
camera_width = 160
camera_height = 120
"""

# (case, today's flags, draccus flags, tyro flags, TOML text): exactly one of flags / TOML is used.
BAD_INPUT: list[tuple[str, list[str], list[str], list[str], str | None]] = [
    ("flag: unknown", ["--popsize", "16"], ["--noveb.popsize", "16"], ["--noveb.popsize", "16"], None),
    (
        "flag: not an int",
        ["--population", "abc"],
        ["--noveb.population", "abc"],
        ["--noveb.population", "abc"],
        None,
    ),
    ("flag: int | None", ["--max-attempts", "many"], ["--max_attempts", "many"], ["--max-attempts", "many"], None),
    (
        "flag: out of range",
        ["--population", "1"],
        ["--noveb.population", "1"],
        ["--noveb.population", "1"],
        None,
    ),
    ("flag: negative seed", ["--seed", "-1"], ["--seed", "-1"], ["--seed", "-1"], None),
    ("flag: bad choice", ["--explorer", "evo"], ["--explorer", "evo"], ["--explorer", "evo"], None),
    ("toml: unknown [noveb] key", [], [], [], "[noveb]\npopsize = 16\n"),
    ("toml: unknown top-level key", [], [], [], "popsize = 16\n"),
    ("toml: section not a table", [], [], [], "noveb = 3\n"),
    ("toml: str for int", [], [], [], '[noveb]\npopulation = "many"\n'),
    ("toml: float for int", [], [], [], "[world]\nfps = 2.5\n"),
    ("toml: numeric str for int", [], [], [], 'seed = "3"\n'),
]


# --- timing -------------------------------------------------------------------------------------------------


def wall(cmd: list[str], repeats: int = 3) -> float:
    """Best wall time of a command in a fresh process (its output discarded)."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(cmd, capture_output=True, cwd=REPO, check=False)
        best = min(best, time.perf_counter() - t0)
    return best


def heaviest_imports(code: str, n: int = 6) -> list[tuple[str, float]]:
    """Top-level packages by cumulative import time (s) when running `code` (python -X importtime)."""
    r = subprocess.run([PY, "-X", "importtime", "-c", code], capture_output=True, text=True, cwd=REPO)
    best: dict[str, float] = {}
    for line in r.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m:
            pkg = m.group(4).split(".")[0]
            best[pkg] = max(best.get(pkg, 0.0), int(m.group(2)) / 1e6)
    return sorted(best.items(), key=lambda kv: -kv[1])[:n]


# --- the three ways of building a RunConfig ----------------------------------------------------------------------
def today(argv: list[str], toml: Path | None = None, parser: object | None = None):  # -> RunConfig
    """babblegen generate's path: argparse, then TOML < flags, then RunConfig.from_dict."""
    from babblegen import cli
    from babblegen.config import RunConfig, load_toml, merge
    from babblegen.generate_flags import overrides

    parser = parser or cli.build_parser()
    args = parser.parse_args(["generate", "--out", "/tmp/unused", *(["--config", str(toml)] if toml else []), *argv])
    data = load_toml(args.config) if args.config else {}
    return RunConfig.from_dict(merge(data, overrides(args)))


def with_draccus(argv: list[str], toml: Path | None = None):  # -> RunConfig
    import draccus

    from babblegen.config import RunConfig

    return draccus.parse(RunConfig, config_path=toml, args=argv)


def with_tyro(argv: list[str], toml: Path | None = None):  # -> RunConfig
    import tyro

    from babblegen.config import RunConfig, load_toml

    default = RunConfig.from_dict(load_toml(toml)) if toml else None
    return tyro.cli(RunConfig, args=argv, default=default)


def outcome(fn: Callable[[], object]) -> tuple[str, str]:
    """('accepted' | 'rejected' | 'crash', message): what a user would see, on one line."""
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            fn()
    except SystemExit as e:
        text = re.sub(r"[│╭╮╰╯]", "", err.getvalue() + out.getvalue())
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        errors = [ln for ln in lines if " error: " in ln]
        if errors:  # argparse
            return "rejected", errors[-1].split(" error: ", 1)[1]
        paragraphs: list[list[str]] = [[]]  # tyro: a box of paragraphs split by rules; title + first one
        for ln in lines:
            if set(ln) <= set("─- "):
                paragraphs.append([])
            else:
                paragraphs[-1].append(ln)
        body = [" ".join(p) for p in paragraphs if p][:2]
        if len(body) == 2 and body[1].startswith(body[0]):
            body = body[1:]
        return ("rejected" if e.code else "accepted"), ": ".join(body)
    except Exception as e:
        from babblegen.config import ConfigError

        msg = f"{type(e).__name__}: {e}"
        if e.__cause__ is not None and str(e.__cause__) not in msg:
            msg += f" (cause: {e.__cause__})"
        ok = isinstance(e, ConfigError) or type(e).__module__.startswith(("draccus", "tyro"))
        return ("rejected" if ok else "crash"), " ".join(msg.split())
    return "accepted", ""


def validated(make: Callable[[], object]) -> Callable[[], object]:
    def run() -> object:
        config = make()
        config.validate()
        return config

    return run


# --- report ---------------------------------------------------------------------------------------------------
def table(title: str, header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    lines = [title, fmt.format(*header), "-" * (sum(widths) + 2 * (len(widths) - 1))]
    lines += [fmt.format(*map(str, r)) for r in rows]
    return "\n".join(lines)


def fmt_s(seconds: float) -> str:
    return f"{seconds * 1e3:,.0f} ms" if seconds >= 0.1 else f"{seconds * 1e3:,.2f} ms"


def main() -> None:
    from importlib.metadata import version

    versions = {p: version(p) for p in ("draccus", "tyro")}
    print("installed: " + ", ".join(f"{k} {v}" for k, v in versions.items()))

    # 1. import time ------------------------------------------------------------------------------------------
    empty = wall([PY, "-c", "pass"])
    imports = [
        ("stdlib: argparse, tomllib, dataclasses", "import argparse, tomllib, dataclasses"),
        ("babblegen.config (dataclass tree)", "import babblegen.config"),
        ("babblegen.cli (argparse + config)", "import babblegen.cli"),
        ("babblegen.cli + build_parser()", "import babblegen.cli as c; c.build_parser()"),
        ("draccus", "import draccus"),
        ("tyro", "import tyro"),
        ("draccus + babblegen.config", "import draccus, babblegen.config"),
        ("tyro + babblegen.config", "import tyro, babblegen.config"),
    ]
    rows = [[label, fmt_s(wall([PY, "-c", code]) - empty)] for label, code in imports]
    print(table(f"1. import time, fresh process, less an empty interpreter ({fmt_s(empty)})", ["", "wall"], rows))
    heavy = heaviest_imports("import babblegen.cli as c; c.build_parser()")
    print("   what build_parser() (so --help) imports, cumulative: " + ", ".join(f"{k} {v:.2f} s" for k, v in heavy))
    print()

    # 2. --help -------------------------------------------------------------------------------------------------
    helps = [
        ("babblegen --help (today)", [str(BIN / "babblegen"), "--help"]),
        ("babblegen generate --help (today)", [str(BIN / "babblegen"), "generate", "--help"]),
        (
            "draccus parser of RunConfig --help",
            [PY, "-c", "import draccus; from babblegen.config import RunConfig; draccus.parse(RunConfig)", "--help"],
        ),
        (
            "tyro parser of RunConfig --help",
            [PY, "-c", "import tyro; from babblegen.config import RunConfig; tyro.cli(RunConfig)", "--help"],
        ),
    ]
    rows = [[label, fmt_s(wall(cmd))] for label, cmd in helps]
    print(table("2. --help, wall time of a fresh process", ["", "wall"], rows))
    print()

    # 3. parse time -----------------------------------------------------------------------------------------------
    import draccus  # noqa: F401  (imports outside the timings)
    import tyro  # noqa: F401

    from babblegen import cli

    with tempfile.TemporaryDirectory() as tmp:
        typical = Path(tmp) / "typical.toml"
        typical.write_text(TYPICAL_TOML)
        parser = cli.build_parser()
        results = {
            "today": today(TODAY_ARGS),
            "draccus": with_draccus(DRACCUS_ARGS),
            "tyro": with_tyro(TYRO_ARGS),
            "today+toml": today([], typical),
            "draccus+toml": with_draccus([], typical),
            "tyro+toml": with_tyro([], typical),
        }
        same = all(r == results["today"] for r in results.values())
        rows = [
            ["today: build_parser + parse + from_dict", fmt_s(per_call(lambda: today(TODAY_ARGS))), "-"],
            [
                "today: parse + from_dict (parser built once)",
                fmt_s(per_call(lambda: today(TODAY_ARGS, parser=parser))),
                fmt_s(per_call(lambda: today([], typical, parser=parser))),
            ],
            [
                f"draccus {versions['draccus']}: draccus.parse",
                fmt_s(per_call(lambda: with_draccus(DRACCUS_ARGS))),
                fmt_s(per_call(lambda: with_draccus([], typical))),
            ],
            [
                f"tyro {versions['tyro']}: tyro.cli",
                fmt_s(per_call(lambda: with_tyro(TYRO_ARGS))),
                fmt_s(per_call(lambda: with_tyro([], typical))),
            ],
        ]
        print(
            table(
                "3. command line -> RunConfig (with noveb and world sections), in process, best of 5",
                ["", "flags", "TOML file"],
                rows,
            )
        )
        print(f"   typical flags: {' '.join(TODAY_ARGS)}")
        print(f"   all six RunConfigs equal: {same}")
        print()

        # 4. bad input ------------------------------------------------------------------------------------------
        rows = []
        for i, (case, a_today, a_draccus, a_tyro, toml_text) in enumerate(BAD_INPUT):
            toml = None
            if toml_text is not None:
                toml = Path(tmp) / f"bad{i}.toml"
                toml.write_text(toml_text)
            verdicts = [
                outcome(validated(lambda a=a_today, t=toml: today(a, t, parser=parser))),
                outcome(validated(lambda a=a_draccus, t=toml: with_draccus(a, t))),
                outcome(validated(lambda a=a_tyro, t=toml: with_tyro(a, t))),
            ]
            cells = [f"{v}: {m[:95]}" if m else v for v, m in verdicts]
            cells[1:] = [
                ("" if v == verdicts[0][0] else "DIFFERS ") + c
                for (v, _), c in zip(verdicts[1:], cells[1:], strict=True)
            ]
            rows.append([case, *cells])
        print("4. bad input (validate() included; tyro reads TOML through babblegen's from_dict)")
        for case, *cells in rows:
            print(f"  {case}")
            for name, cell in zip(("today", "draccus", "tyro"), cells, strict=True):
                print(f"      {name:<8} {cell}")


if __name__ == "__main__":
    main()
