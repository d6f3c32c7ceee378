"""`babblegen view` (Rerun) and `babblegen report` (the paper's figures and a summary), registered on the
main command line by `babblegen.cli`. The viewer and the report are imported when their command runs: either would
add a quarter to ``babblegen --help``."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from babblegen.config import ConfigError
from babblegen.dataset.lerobot import read_dataset_info
from babblegen.dataset.paths import ATTEMPTS, LEROBOT_INFO, RUN_INFO, sidecar_dir


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {value}")
    return value


def register(sub) -> None:
    """Add the `view` and `report` subcommands to the main parser's subparsers."""
    v = sub.add_parser(
        "view",
        help="show a dataset in the Rerun viewer (or save a .rrd)",
        description=(
            "Log a babblegen dataset to Rerun, from the LeRobot dataset and its sidecar table alone (so it also "
            "works on a copied dataset): the 3D scene with the arm, objects, tool path and contacts, the head "
            "camera, per-frame and per-attempt plots, and the final tool and object positions seen from above. "
            "Opens the viewer, or writes FILE.rrd with --save (also when there is no display)."
        ),
    )
    v.add_argument("dataset", type=Path, metavar="DIR", help="a dataset written by `babblegen generate`")
    v.add_argument("--episode", type=_positive_int, default=None, help="show only this episode")
    v.add_argument(
        "--max-episodes",
        type=_positive_int,
        default=50,
        help="without --episode, show the first N episodes (0: all; default: 50); the overview covers every attempt",
    )
    v.add_argument(
        "--save", type=Path, default=None, metavar="FILE.rrd", help="write a recording instead of opening the viewer"
    )
    v.set_defaults(func=cmd_view)

    r = sub.add_parser(
        "report",
        help="the NovEB paper's figures 2-5 and a summary table",
        description=(
            "Write the paper's figures as PNG (2: final tool positions from above; 3: final object positions; "
            "4: accumulated contacts vs attempted movements; 5: accumulated contacts per object) and summary.md / "
            "summary.json, all from the sidecar table. With --compare, both runs side by side (e.g. NovEB against "
            "random babbling)."
        ),
    )
    r.add_argument("dataset", type=Path, metavar="DIR", help="a dataset written by `babblegen generate`")
    r.add_argument("--compare", type=Path, default=None, metavar="OTHER_DIR", help="a run to compare with")
    r.add_argument("--out", type=Path, default=None, metavar="REPORT_DIR", help="output folder (default: DIR/report)")
    r.set_defaults(func=cmd_report)


def check_dataset(path: Path) -> Path:
    """Raise ConfigError unless `path` holds a babblegen dataset."""
    if not path.exists():
        raise ConfigError(f"{path} does not exist")
    if not (sidecar_dir(path) / RUN_INFO).is_file() or not (sidecar_dir(path) / ATTEMPTS).is_file():
        raise ConfigError(
            f"{path} is not a babblegen dataset (no {sidecar_dir(path) / RUN_INFO} and {ATTEMPTS}); "
            "make one with `babblegen generate --out DIR`"
        )
    return path


def _has_display() -> bool:
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def cmd_view(args: argparse.Namespace) -> int:
    from babblegen.exporters.rerun import ViewerError, default_view_file, view_dataset

    root = check_dataset(args.dataset)
    if args.save is not None and args.save.suffix != ".rrd":
        raise ConfigError(f"--save needs a .rrd file name, got {args.save}")
    save = args.save
    if save is None and not _has_display():
        save = default_view_file(root)
        print("no display found: writing a recording instead of opening the viewer")
    total = _total_episodes(root)
    if args.episode is not None:
        if args.episode >= total:
            raise ConfigError(f"episode {args.episode} is not in {root} (it has episodes 0 to {total - 1})")
        episodes: list[int] | None = [args.episode]
    else:
        n = total if args.max_episodes == 0 else min(args.max_episodes, total)
        episodes = list(range(n))
        if n < total:
            print(f"showing episodes 0 to {n - 1} of {total} (use --episode N or --max-episodes 0 for all)")
    try:
        written = view_dataset(root, episodes, save=save)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    except ViewerError as e:
        print(f"babblegen: error: {e}", file=sys.stderr)
        return 1
    if written is not None:
        print(f"recording written to {written}; open it with: rerun {written}")
    return 0


def _total_episodes(root: Path) -> int:
    if not (root / LEROBOT_INFO).is_file():
        raise ConfigError(f"{root} has no LeRobot dataset (no {root / LEROBOT_INFO})")
    return int(read_dataset_info(root).get("total_episodes", 0))


def cmd_report(args: argparse.Namespace) -> int:
    from babblegen.exporters.report import write_report

    root = check_dataset(args.dataset)
    other = check_dataset(args.compare) if args.compare is not None else None
    out = args.out if args.out is not None else root / "report"
    result = write_report(root, other, out)
    s = result["run"]
    print(
        f"{s['attempts']} attempts, {s['executed']} executed, {s['contacts']} with contact, archive {s['archive']}"
        + (
            f"; contact ratio against {other}: {result['comparison']['contact_ratio']:.2f}"
            if other is not None and result["comparison"]["contact_ratio"] is not None
            else ""
        )
    )
    figures = ", ".join(Path(p).name for p in result["figures"].values())
    print(f"report written to {out}: summary.md, summary.json, {figures}")
    return 0
