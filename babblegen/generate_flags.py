"""The `babblegen generate` command's flags, and how they map onto the run configuration (defaults < TOML < flags):
`generate_parser` declares them, `overrides` and `camera_overrides` turn the parsed flags into the configuration's
values. Importable without the simulator, like the configuration itself."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from babblegen.camera_views import CAMERA_PRESETS
from babblegen.config import RERUN_FRAMES, VIDEO_CODECS, ConfigError, RunConfig, default_workers
from babblegen.descriptors import DESCRIPTORS
from babblegen.explorers import EXPLORERS
from babblegen.explorers.noveb import NovEBConfig
from babblegen.objects import OBJECT_SETS
from babblegen.tasks import DEFAULT_TASK, TASKS
from babblegen.world.settings import START_MODES, WorldSettings, cameras_from_names, default_cameras

_N, _W = NovEBConfig(), WorldSettings()


def _positive(name: str):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got {text!r}") from None
        if v < 0:
            raise argparse.ArgumentTypeError(f"{name} must not be negative, got {v}")
        return v

    return parse


def _prob(text: str) -> float:
    v = float(text)
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"a probability must be in [0, 1], got {v}")
    return v


def generate_parser(sub) -> argparse.ArgumentParser:
    """Add the `generate` subcommand, with every flag, to the main parser's subparsers; returns it."""
    g = sub.add_parser(
        "generate",
        help="run an explorer and write a LeRobot dataset",
        description=(
            "Run NovEB (or the random-babbling control) and write every executed trajectory as a LeRobot v3.0 "
            "episode, with a sidecar table of all attempts under DIR/babblegen/. Values come from the defaults, "
            "then --config, then the flags. Safe to interrupt (Ctrl-C / SIGTERM): the dataset is finalized and "
            "--resume continues from the last commit point, even after a kill."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    g.add_argument("--out", required=True, type=Path, help="dataset directory (must be new or empty)")
    g.add_argument("--resume", action="store_true", help="continue the interrupted run in --out")
    g.add_argument("--config", type=Path, default=None, help="TOML file with run settings (flags override it)")
    g.add_argument("--explorer", choices=sorted(EXPLORERS), default=None, help="explorer [default: noveb]")
    g.add_argument("--task", choices=sorted(TASKS), default=None, help=f"scene [default: {DEFAULT_TASK}]")
    g.add_argument("--seed", type=_positive("--seed"), default=None, help="run seed [default: 0]")
    g.add_argument("--generations", type=_positive("--generations"), default=None, help=f"[default: {_N.generations}]")
    g.add_argument(
        "--max-attempts",
        type=_positive("--max-attempts"),
        default=None,
        help="stop after this many attempted movements (clones, children that repeat a tried genome, reuse its "
        f"outcome and do not count); 0: when the generations end [default: {RunConfig.max_attempts}]",
    )
    g.add_argument(
        "--descriptor",
        choices=["auto", *sorted(DESCRIPTORS)],
        default=None,
        help="behaviour descriptor of the outcome image; auto: phash16 (the after image) with fixed starts, change16 "
        "(what changed between the before and after images) with varied ones [default: auto; phash is the paper's]",
    )
    g.add_argument(
        "--population",
        type=int,
        default=None,
        help=f"parents kept per generation (the first generation's size) [default: {_N.population}]",
    )
    g.add_argument(
        "--children",
        type=_positive("--children"),
        default=None,
        help=f"children bred per generation from the population's survivors [default: {_N.children}]",
    )
    g.add_argument(
        "--lag",
        type=_positive("--lag"),
        default=None,
        help="generations bred before the one before is told: lag + 1 generations' movements can run at once, "
        f"for any number of workers (0: the paper's generations) [default: {_N.lag}]",
    )
    g.add_argument("--k", type=int, default=None, help=f"nearest neighbours for novelty [default: {_N.k}]")
    g.add_argument("--mutation-prob", type=_prob, default=None, help=f"[default: {_N.mutation_prob}]")
    g.add_argument("--sigma", type=float, default=None, help=f"Gaussian mutation sigma [default: {_N.sigma}]")
    g.add_argument(
        "--extend-prob",
        type=_prob,
        default=None,
        help=f"add-waypoint probability [default: {_N.extend_prob}]",
    )
    g.add_argument(
        "--remove-prob",
        type=_prob,
        default=None,
        help=f"remove-waypoint probability (0: the paper, genomes only grow) [default: {_N.remove_prob}]",
    )
    g.add_argument(
        "--remove-above",
        type=_positive("--remove-above"),
        default=None,
        help=f"only a genome of more waypoints than this may lose one [default: {_N.remove_above}]",
    )
    g.add_argument(
        "--max-waypoints",
        type=_positive("--max-waypoints"),
        default=None,
        help=f"waypoints a genome may grow to; 0: no bound (the paper) [default: {_N.max_waypoints or 0}]",
    )
    g.add_argument(
        "--independent-share",
        type=_prob,
        default=None,
        help="share of each generation's children drawn independently, as random_waypoints draws, instead of "
        f"bred (0: every child bred, the paper) [default: {_N.independent_share}]",
    )
    g.add_argument(
        "--start-from-end",
        type=_prob,
        default=None,
        help="with varied starts, the share of start mutations that start from the scene the parent's movement "
        f"left instead of a new layout [default: {_N.start_from_end}]",
    )
    g.add_argument(
        "--width", type=_positive("--width"), default=None, help=f"camera width [default: {_W.camera_width}]"
    )
    g.add_argument(
        "--height",
        type=_positive("--height"),
        default=None,
        help=f"camera height [default: {_W.camera_height}]",
    )
    g.add_argument(
        "--fps", type=_positive("--fps"), default=None, help=f"recorded frames per second [default: {_W.fps}]"
    )
    g.add_argument(
        "--cameras",
        default=None,
        help="cameras to record, comma-separated, from: " + ", ".join(CAMERA_PRESETS) + "; the head camera, "
        "which the search looks through, always ('[[world.cameras]]' in --config places others) "
        f"[default: {','.join(v.name for v in default_cameras())}]",
    )
    g.add_argument(
        "--depth",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="record each camera's depth map (LeRobot's depth video, in millimetres); off by default: it costs "
        "61%% of the executed episodes per second on 2 cores [default: off]",
    )
    g.add_argument(
        "--segmentation",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="record each camera's instance masks (background, table, floor, robot, each object) [default: on]",
    )
    g.add_argument(
        "--starts",
        choices=START_MODES,
        default=None,
        help="where episodes start: 'varied', object layouts drawn from the task's regions and settled by physics "
        "(NovEB children keep their parent's start unless a start mutation draws a new one: [noveb] "
        "start_mutation_prob), or 'fixed', the paper's scene every time (with the rest of the defaults, the search "
        "as babblegen ran it before varied starts became the default) [default: varied]",
    )
    g.add_argument(
        "--objects",
        choices=OBJECT_SETS,
        default=None,
        help="which objects stand on the table: 'paper', the paper's gray box, can, blue box and ball every episode; "
        "'varied', every new start draws its own (shape, size, mass, friction, restitution, colour; recorded per "
        "episode as factors of variation); 'heldout', shapes and property bands no varied draw produces, for test "
        "sets. varied and heldout need --starts varied [default: varied with --starts varied (wall_tabletop: its own "
        "objects), paper with --starts fixed]",
    )
    g.add_argument(
        "--num-objects",
        type=int,
        default=None,
        metavar="N",
        help="objects per start with --objects varied or heldout, 1 to 8 (paper: its 4) [default: 4]",
    )
    g.add_argument(
        "--paper",
        action="store_true",
        help="the paper's configuration: --starts fixed --objects paper (the scene and search of the NovEB paper)",
    )
    g.add_argument(
        "--checkpoint-every",
        type=_positive("--checkpoint-every"),
        default=None,
        help="generations between commit points [default: 10]",
    )
    g.add_argument(
        "--workers",
        type=_positive("--workers"),
        default=None,
        help=f"rollout processes; 1 runs them in this process [default: one per core, {default_workers()} here]",
    )
    g.add_argument(
        "--ray",
        default=None,
        help="evaluate on a Ray cluster: 'auto' (the running one, else a local one started for the run), "
        "'local', or an address [default: off]",
    )
    g.add_argument(
        "--allow-mixed-machines",
        action="store_true",
        default=None,
        help="let Ray nodes (or a resume) whose machine fingerprint differs from this machine's take part; run.json "
        "records the run as mixed [default: refused, docs/reproducibility.md]",
    )
    g.add_argument(
        "--rerun",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="write Rerun recordings to DIR/babblegen/rerun/ [default: on]",
    )
    g.add_argument(
        "--rerun-frames",
        choices=RERUN_FRAMES,
        default=None,
        help="what the recordings log of each episode: 'ends', its first and last frame (every view) and the paths "
        "of the movement (babblegen view plays any episode frame by frame from the dataset), or 'all' its frames "
        "[default: ends]",
    )
    g.add_argument(
        "--video-codec",
        choices=VIDEO_CODECS,
        default=None,
        help="head-camera video codec; libsvtav1 is LeRobot's own default, h264 encodes about 6x faster for "
        "about the same fidelity and size; h264_mbtree is x264 as runs made before (its macroblock-tree rate "
        "control, whose approximate reciprocals give each CPU maker's own bytes) [default: h264]",
    )
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    return g


def overrides(args: argparse.Namespace) -> dict:
    if args.paper:
        if args.starts == "varied" or args.objects not in (None, "paper"):
            raise ConfigError("--paper is --starts fixed --objects paper; drop --starts/--objects or --paper")
        args.starts, args.objects = "fixed", "paper"
    return {
        "task": args.task,
        "explorer": args.explorer,
        "seed": args.seed,
        "max_attempts": args.max_attempts,
        "descriptor": args.descriptor,
        "checkpoint_every": args.checkpoint_every,
        "workers": args.workers,
        "ray": args.ray,
        "allow_mixed_machines": args.allow_mixed_machines,
        "rerun": args.rerun,
        "rerun_frames": args.rerun_frames,
        "video_codec": args.video_codec,
        "noveb": {
            "generations": args.generations,
            "population": args.population,
            "children": args.children,
            "lag": args.lag,
            "k": args.k,
            "mutation_prob": args.mutation_prob,
            "sigma": args.sigma,
            "extend_prob": args.extend_prob,
            "remove_prob": args.remove_prob,
            "remove_above": args.remove_above,
            "max_waypoints": args.max_waypoints,
            "independent_share": args.independent_share,
            "start_from_end": args.start_from_end,
        },
        "world": {
            "camera_width": args.width,
            "camera_height": args.height,
            "fps": args.fps,
            "starts": args.starts,
            "objects": args.objects,
            "num_objects": args.num_objects,
        },
    }


def camera_overrides(args: argparse.Namespace, data: dict) -> None:
    """--cameras, --depth and --segmentation into ``data["world"]["cameras"]`` (applied to the cameras the file
    or the defaults give when --cameras is not given)."""
    if args.cameras is None and args.depth is None and args.segmentation is None:
        return
    world = data.setdefault("world", {})
    if args.cameras is not None:
        names = [n.strip() for n in args.cameras.split(",") if n.strip()]
        try:
            world["cameras"] = cameras_from_names(names, args.depth, args.segmentation)
        except ValueError as e:
            raise ConfigError(f"--cameras: {e}") from None
        return
    views = world.get("cameras") or [dataclasses.asdict(v) for v in default_cameras()]
    world["cameras"] = [
        {
            **dict(v),
            **({} if args.depth is None else {"depth": args.depth}),
            **({} if args.segmentation is None else {"segmentation": args.segmentation}),
        }
        for v in views
    ]
