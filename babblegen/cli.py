"""`babblegen` command line: generate a dataset, and verify, report on, view or evaluate one.

This module builds the parser (the `generate` command's flags are `babblegen.generate_flags`'s; every other command
is a module that adds itself, `SUBCOMMANDS`), runs the command asked for, and turns a configuration error, a stop
while a run starts or a full disk into one line and an exit status. A command imports what it runs (the run
loop and its sinks, the report, the viewer, the simulator) when it runs: any of them would add a quarter to
``babblegen --help``."""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from babblegen.config import ConfigError, RunConfig, load_toml, merge
from babblegen.dataset.paths import is_babblegen_dataset
from babblegen.generate_flags import camera_overrides, generate_parser, overrides
from babblegen.interrupts import Interrupted, Interrupts, installed

# The subcommands other modules register, and their names: a command whose module does not import is still on the
# command line, and running it says what is missing.
SUBCOMMANDS: dict[str, tuple[str, ...]] = {
    "babblegen.report_cli": ("view", "report"),
    "babblegen.verify": ("verify",),
    "babblegen.worldmodel.cli": ("evaluate",),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="babblegen",
        description=(
            "Novelty-driven Evolutionary Babbling (NovEB): a simulated PR2-like arm explores a tabletop by "
            "searching for movements whose outcome image is novel, and every executed movement becomes a "
            "LeRobot episode."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Run `babblegen COMMAND --help` for each command's options.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    generate_parser(sub).set_defaults(func=cmd_generate)

    for module, commands in SUBCOMMANDS.items():
        _register(sub, module, commands)
    return parser


def _register(sub, module: str, commands: tuple[str, ...]) -> None:
    """Let ``module`` add its subcommands; when it does not import, add each as one that only says so."""
    try:
        register = importlib.import_module(module).register
    except ImportError as e:
        reason = f"cannot import {module} ({e})"
        for name in commands:
            p = sub.add_parser(name, help=f"unavailable: {reason}", add_help=False)
            p.set_defaults(func=_unavailable(name, reason), unavailable=True)
        return
    register(sub)


def _unavailable(name: str, reason: str):
    def run(args: argparse.Namespace) -> int:
        print(f"babblegen: error: {name}: {reason}", file=sys.stderr)
        return 2

    return run


def _one_line_warnings() -> None:
    """Warnings as one line each, like the errors (``babblegen: warning: ...``), not Python's two with the source
    line that raised them."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"babblegen: warning: {message}", file=file or sys.stderr)

    warnings.showwarning = show


def cmd_generate(args: argparse.Namespace) -> int:
    from babblegen.run import Run

    _one_line_warnings()

    if args.resume:
        if args.config is not None:
            raise ConfigError("--resume uses the stored configuration of the run; drop --config")
        if args.cameras is not None or args.depth is not None or args.segmentation is not None:
            raise ConfigError(
                "--resume cannot change the cameras of an existing run; drop --cameras/--depth/--segmentation"
            )
        flat = {k: v for k, v in overrides(args).items() if not isinstance(v, dict)}
        flat.update({k: v for k, v in overrides(args)["noveb"].items()})
        flat.update({k: v for k, v in overrides(args)["world"].items()})
        run = Run.resume(args.out, flat)
    else:
        data = load_toml(args.config) if args.config else {}
        data = merge(data, overrides(args))
        camera_overrides(args, data)
        run = Run.start(args.out, RunConfig.from_dict(data))
    summary = run.execute(progress=not args.no_progress)
    if not summary.written:  # stopped before its dataset held an episode: nothing of this sitting is left
        print(_interrupted_at_start(args.out), file=sys.stderr)
        return 130
    for line in summary.lines():
        print(line)
    if summary.interrupted:
        print(f"resume with: babblegen generate --out {summary.out} --resume")
        return 130
    if summary.signal is not None:
        print(f"{summary.signal} arrived as the run finished: the dataset is complete")
        return 130
    print(
        "load it with: from lerobot.datasets.lerobot_dataset import LeRobotDataset; "
        f"LeRobotDataset('{run.repo_id}', root='{summary.out}')"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown and not getattr(args, "unavailable", False):  # an unavailable command takes any arguments
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return args.func(args)
    except ConfigError as e:
        print(f"babblegen: error: {e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Interrupted):  # without babblegen's handlers in place (a run handles its own stops)
        if args.command == "generate":
            print(_interrupted_at_start(getattr(args, "out", None)), file=sys.stderr)
        else:
            print(_interrupted(args), file=sys.stderr)
        return 130
    except Exception as e:
        full = _disk_full(e)
        if full is None:
            raise
        where = getattr(args, "out", None) or "the output directory"
        print(
            f"babblegen: error: no space left on the device holding {where}; everything up to the last commit "
            f"point is safe: free some space, then run the same command with --resume",
            file=sys.stderr,
        )
        return 1


def _interrupted(args: argparse.Namespace) -> str:
    """What a command other than ``generate`` says when a stop ends it: what it left (an evaluation keeps what it
    measured after each model)."""
    said = f"babblegen: {args.command} interrupted"
    kept = Path(getattr(args, "out", None) or "") / "evaluation.md"
    if args.command == "evaluate" and kept.is_file():
        return f"{said}; the models measured so far are in {kept}"
    return said


def _interrupted_at_start(out: str | None) -> str:
    said = "babblegen: interrupted before the first episode was written"
    if out is None or not Path(out).is_dir() or not any(Path(out).iterdir()):
        return f"{said}; nothing was written"
    if is_babblegen_dataset(Path(out)):
        return f"{said}; resume with: babblegen generate --out {out} --resume"
    return f"{said}; {out} holds an incomplete start: delete it, then run the same command again"


def _disk_full(error: BaseException | None) -> BaseException | None:
    """The out-of-space error behind ``error`` (itself, or what it was raised from), if there is one."""
    import errno

    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
            return error
        if "No space left on device" in str(error):  # libraries that wrap the OSError in their own type
            return error
        error = error.__cause__ or error.__context__
    return None


def entry_point() -> None:
    """Console script: run, then leave without the interpreter's teardown, where OMPL's Python binding
    prints spurious reference-leak warnings (everything babblegen opened is closed by then).

    `generate` takes SIGINT and SIGTERM over until the process ends (`babblegen.console` does it before this module's
    imports), so a signal during the summary or the exit is recorded too: it makes the exit status 130."""
    import logging
    import os

    stop = installed()
    if stop is None and sys.argv[1:2] == ["generate"]:
        stop = Interrupts(raising=False).install()
    code = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    if code == 0 and stop is not None and stop.pending is not None:  # the last moment a signal can change it
        print(f"{stop.pending} arrived as babblegen ended: the dataset is complete", file=sys.stderr, flush=True)
        code = 130
    os._exit(code)


if __name__ == "__main__":
    entry_point()
