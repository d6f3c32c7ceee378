"""`babblegen evaluate`: what each dataset teaches a world model, on held-out test sets and in planning."""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path

from babblegen.worldmodel.episodes import EvaluationError

DESCRIPTION = """\
Train a learned simulator (CPU, minutes) on each training source and score it on held-out test sets: which objects
move (F1), where they end up (the median error of their final x, y against "nothing moves" and the training set's
mean displacement; their yaw), overall and per outcome stratum (nothing moved, one object, several objects, toppled
/ rolled / off the table), and in planning: for goals taken from a test set's episodes (an object's end position
from the episode's start), the model alone searches waypoint genomes with the cross-entropy method (--planner cem)
and its choice is executed once in the simulator; beside it one random genome, the best of --plan-candidates
random genomes (each executed) and the goal's own movement replayed, each with a 95 % bootstrap interval over
goals. --planner rank: the model ranks K executed candidates, the goal's own movement among them.

Each --train source is NAME=DIR[,DIR...], one dataset per repeat; each --test set is NAME=DIR[,DIR...], the union of
its datasets, seeded apart from every training dataset. --attempts cuts every training dataset to its first N
attempts (equal simulation); with --equal episodes (or both, the default) every source is then cut to as many
episodes as the smallest holds. Writes OUT/evaluation.md, OUT/evaluation.json, OUT/ends.png (where each model
ends the test sets' moved objects, in units of their true moves) and, for two budgets or more, OUT/budgets.png.
The models: babblegen/worldmodel/simulator.py (graph) and baseline.py (mlp); the measures:
docs/world_model.md."""


def _named_dirs(text: str) -> tuple[str, list[Path]]:
    name, sep, dirs = text.partition("=")
    paths = [Path(d) for d in dirs.split(",") if d]
    if not sep or not name or not paths:
        raise argparse.ArgumentTypeError(f"expected NAME=DIR[,DIR...], got {text!r}")
    return name, paths


def _budgets(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected attempt counts like 1200,4000, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"attempt counts must be positive, got {text!r}")
    return sorted(set(values))


def register(sub) -> None:
    p = sub.add_parser(
        "evaluate",
        help="what each dataset teaches a world model: held-out prediction and planning in the simulator",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--train", type=_named_dirs, action="append", required=True, metavar="NAME=DIR[,DIR...]")
    p.add_argument("--test", type=_named_dirs, action="append", required=True, metavar="NAME=DIR[,DIR...]")
    p.add_argument(
        "--attempts",
        type=_budgets,
        default=None,
        metavar="N[,N...]",
        help="attempt budgets: each training dataset cut to its first N attempts [default: whole]",
    )
    p.add_argument(
        "--equal",
        choices=("attempts", "episodes", "both"),
        default="both",
        help="compare at equal attempts, at equal episodes, or both [default: both]",
    )
    p.add_argument(
        "--plan-test",
        default=None,
        metavar="NAME",
        help="the test set whose episodes give the planning goals [default: the first --test]",
    )
    p.add_argument("--plan-goals", type=int, default=200, help="planning goals; 0: no planning [default: 200]")
    p.add_argument(
        "--planner",
        choices=("cem", "rank"),
        default="cem",
        help="cem: the model alone searches genomes, its choice is executed; rank: the model ranks executed "
        "candidates [default: cem]",
    )
    p.add_argument(
        "--plan-candidates",
        type=int,
        default=16,
        help="random genomes per goal, each executed (the baselines); rank: the candidates per goal [default: 16]",
    )
    p.add_argument("--cem-samples", type=int, default=64, help="cem: genomes per goal and iteration [default: 64]")
    p.add_argument("--cem-iterations", type=int, default=4, help="cem: iterations [default: 4]")
    p.add_argument(
        "--cem-disagreement",
        type=float,
        default=0.0,
        metavar="W",
        help="cem, graph: metres of cost per centimetre of the ensemble members' disagreement on the goal object "
        "[default: 0]",
    )
    p.add_argument(
        "--ceiling-goals",
        type=int,
        default=40,
        help="cem: goals also searched with the true simulator as the model, the ceiling every model is measured "
        "against (each goal about 256 simulated movements; kept in OUT/ceiling_TEST.json); 0: none [default: 40]",
    )
    p.add_argument(
        "--model",
        choices=("graph", "mlp"),
        default="graph",
        help="graph: the learned simulator, an ensemble of graph networks over the objects' surfaces, the arm's "
        "collision spheres and the table; mlp: the baseline, one network per object over its push frame's bounding "
        "box and properties [default: graph]",
    )
    p.add_argument("--members", type=int, default=None, help="graph: ensemble members [default: 5]")
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="at most this many gradient steps per model, stopped early on its own validation episodes "
        "[default: 8000 graph, 12000 mlp]",
    )
    p.add_argument(
        "--save-models",
        type=Path,
        default=None,
        metavar="DIR",
        help="graph: write every trained model to DIR (load one with babblegen.worldmodel.api.load_model)",
    )
    p.add_argument("--seed", type=int, default=0, help="repeat r trains with seed SEED + r [default: 0]")
    p.add_argument("--workers", type=int, default=None, help="processes [default: one per core]")
    p.add_argument("--no-progress", action="store_true", help="no progress bar of the training steps")
    p.add_argument("--out", type=Path, default=Path("evaluation"), help="output folder [default: evaluation]")
    p.set_defaults(func=cmd_evaluate)  # fmt: skip


def cmd_evaluate(args: argparse.Namespace) -> int:
    from babblegen.worldmodel.baseline import TrainSettings
    from babblegen.worldmodel.episodes import EpisodeSet, read_dataset
    from babblegen.worldmodel.experiment import Source, check_apart, run_experiment
    from babblegen.worldmodel.planning import PlanningSettings, build_task
    from babblegen.worldmodel.planning_oracle import measured_ceiling
    from babblegen.worldmodel.report import write
    from babblegen.worldmodel.simulator import GraphSettings

    for flag in ("train", "test"):
        names = [name for name, _ in getattr(args, flag)]
        if len(set(names)) < len(names):
            raise EvaluationError(f"--{flag} names must differ: {names}")
    repeats = max(len(dirs) for _, dirs in args.train)
    if any(len(dirs) not in (1, repeats) for _, dirs in args.train):
        raise EvaluationError(f"every --train source needs 1 or {repeats} datasets (one per repeat)")
    test_names = [name for name, _ in args.test]
    plan_test = args.plan_test or test_names[0]
    if plan_test not in test_names:
        raise EvaluationError(f"--plan-test {plan_test!r} names no --test set ({', '.join(test_names)})")
    if args.plan_goals < 0 or args.plan_candidates < 2:
        raise EvaluationError("--plan-goals must be >= 0 and --plan-candidates >= 2")
    if args.cem_samples < 2 or args.cem_iterations < 1:
        raise EvaluationError("--cem-samples must be >= 2 and --cem-iterations >= 1")
    if args.ceiling_goals < 0 or args.cem_disagreement < 0:
        raise EvaluationError("--ceiling-goals and --cem-disagreement must be >= 0")
    workers = args.workers or os.cpu_count() or 1
    if workers < 1:
        raise EvaluationError(f"--workers must be at least 1, got {workers}")

    started = time.perf_counter()
    cache: dict[Path, object] = {}

    def load(path: Path):
        key = path.resolve()
        if key not in cache:
            cache[key] = read_dataset(path)
            print(f"  {path}: {cache[key].label}, {len(cache[key].episodes)} episodes")
        return cache[key]

    print("test sets:")
    test_sets = {name: [load(d) for d in dirs] for name, dirs in args.test}
    print("training sources:")
    sources = [Source(name, [load(d) for d in dirs]) for name, dirs in args.train]
    check_apart(sources, test_sets)
    tests = {name: EpisodeSet.union([d.episodes for d in parts]) for name, parts in test_sets.items()}
    EpisodeSet.union([*tests.values(), *(d.episodes for s in sources for d in s.datasets)])  # one scene

    plan_settings = PlanningSettings(
        planner=args.planner,
        goals=args.plan_goals,
        candidates=args.plan_candidates,
        seed=args.seed,
        cem_samples=args.cem_samples,
        cem_iterations=args.cem_iterations,
        cem_elites=max(2, args.cem_samples // 6),
        cem_disagreement=args.cem_disagreement,
        ceiling_goals=args.ceiling_goals,
    )
    plan, ceiling = None, None
    if args.plan_goals:
        plan = build_task(tests[plan_test], plan_settings, workers, args.out / f"planning_{plan_test}.npz")
        if plan is None:
            print(f"planning: {plan_test} holds no goal (no episode moved an object 5 cm onto the table): skipped")
        elif args.ceiling_goals and args.planner == "cem":
            key = plan_settings.key(tests[plan_test])
            cache = args.out / f"ceiling_{plan_test}.json"
            ceiling = measured_ceiling(plan, plan_settings, args.ceiling_goals, workers, cache, key)
    steps = {} if args.steps is None else {"steps": args.steps}
    if args.model == "graph":
        members = {} if args.members is None else {"members": args.members}
        train = GraphSettings(seed=args.seed, **steps, **members)
        if train.members < 1:
            raise EvaluationError(f"--members must be at least 1, got {train.members}")
    else:
        if args.members is not None or args.save_models is not None:
            raise EvaluationError("--members and --save-models are for --model graph")
        train = TrainSettings(seed=args.seed, **steps)
    if train.steps < 1:
        raise EvaluationError(f"--steps must be at least 1, got {train.steps}")
    modes = ["attempts", "episodes"] if args.equal == "both" else [args.equal]
    settings = {
        "train": {name: [str(d) for d in dirs] for name, dirs in args.train},
        "test": {name: [str(d) for d in dirs] for name, dirs in args.test},
        "model": {"kind": args.model, **asdict(train)},
        "planning": {**asdict(plan_settings), "test": plan_test},
        "command": " ".join(sys.argv),
    }

    def finish(result: dict) -> list[Path]:
        result["settings"] = settings
        if plan is not None:
            result["planning"]["test"] = plan_test
            result["planning"]["settings"] = settings["planning"]
        return write(result, args.out)

    result = run_experiment(
        sources, tests, args.attempts or [None], modes, train, plan, plan_settings, workers, echo=print,
        progress=finish, save=args.save_models, ceiling=ceiling, bar=not args.no_progress,
    )  # fmt: skip
    written = finish(result)
    print(f"done in {time.perf_counter() - started:.0f} s: " + ", ".join(str(p) for p in written))
    return 0
