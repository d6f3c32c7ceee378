"""What each training source teaches the world model: train one model per source, budget and repeat, score it on
every held-out test set and in planning, and gather the scores.

Budgets: every source is cut to its first N attempts (``equal = "attempts"``: equal simulation), and then each to
as many episodes as the smallest of them holds (``equal = "episodes"``). Repeat r trains on the r-th dataset of every
source (a source of one dataset uses it in every repeat), with the seed ``seed + r``. Training episodes whose
movement and start appear in a test set are dropped. Models train in worker processes, one thread each; a model
depends on its data and seed alone, never on the number of workers.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.worldmodel.baseline import TrainSettings, WorldModel
from babblegen.worldmodel.episodes import STRATA, Dataset, EpisodeSet, EvaluationError, outcomes
from babblegen.worldmodel.metrics import ends_in_true_units, mean_displacement, score
from babblegen.worldmodel.planning import (
    PlanningSettings,
    PlanningTask,
    baseline_scores,
    bootstrap_ci,
    plan_scores,
)
from babblegen.worldmodel.poses import object_state
from babblegen.worldmodel.simulator import GraphSettings, LearnedSimulator

NOTHING = "nothing moves"


@dataclass
class Source:
    name: str
    datasets: list[Dataset]


def held_out(train: EpisodeSet, tests: dict[str, EpisodeSet]) -> EpisodeSet:
    """``train`` without the episodes whose movement and start a test set holds."""
    seen = set(np.concatenate([t.identity for t in tests.values()]).tolist())
    return train.take(np.flatnonzero([i not in seen for i in train.identity]))


def check_apart(sources: list[Source], tests: dict[str, list[Dataset]]) -> None:
    """Test sets must be seeded apart from all training: a test dataset of a training dataset's task and seed (the
    same run, a copy of it, or another explorer on the same starts) is refused."""
    trained = {(d.run["task"]["name"], d.seed): d.root for s in sources for d in s.datasets}
    for name, parts in tests.items():
        for d in parts:
            clash = trained.get((d.run["task"]["name"], d.seed))
            if clash is not None:
                raise EvaluationError(
                    f"test set {name!r} ({d.root}) has seed {d.seed}, as the training dataset {clash}: test sets "
                    f"must be seeded apart from all training"
                )


def budgets(sources: list[Source], attempts: int | None, equal: str) -> tuple[list[dict[str, EpisodeSet]], list[int]]:
    """Per repeat, each source's training episodes at this budget; and the episodes each repeat trains on."""
    repeats = max(len(s.datasets) for s in sources)
    out, sizes = [], []
    for r in range(repeats):
        sets = {s.name: s.datasets[r % len(s.datasets)].budget(attempts=attempts) for s in sources}
        if equal == "episodes":
            n = min(len(e) for e in sets.values())
            sets = {name: e.take(np.arange(n)) for name, e in sets.items()}
        out.append(sets)
        sizes.append(min(len(e) for e in sets.values()))
    return out, sizes


# --- the work of one model, in a worker process ---------------------------------------------------------------

_shared: dict = {}


def _init(
    tests: dict[str, EpisodeSet], plan: PlanningTask | None, plan_settings: PlanningSettings, save: Path | None,
    steps: Any = None,  # the training bar's queue (a manager's proxy): (model, steps taken) go on it
) -> None:  # fmt: skip
    import torch

    torch.set_num_threads(1)
    _shared.update(tests=tests, plan=plan, plan_settings=plan_settings, save=save, steps=steps)


def fit_model(
    train: EpisodeSet, settings: GraphSettings | TrainSettings, progress: Callable[[int], None] | None = None
) -> LearnedSimulator | WorldModel:
    """The model ``settings`` describe (`GraphSettings`: the learned simulator; `TrainSettings`: the baseline),
    trained on ``train``; ``progress`` is told the learned simulator's training steps as they are taken."""
    if isinstance(settings, GraphSettings):
        return LearnedSimulator.fit(train, settings, progress)
    return WorldModel.fit(train, settings)


def model_file(save: Path, name: str, attempts: int | None, equal: str, repeat: int) -> Path:
    """Where `babblegen evaluate --save-models` keeps one model."""
    budget = "all" if attempts is None else f"{attempts}attempts"
    return save / f"{name}_{budget}_equal-{equal}_repeat{repeat + 1}.pt"


def _fit_and_score(job: tuple[int, str, int, EpisodeSet, GraphSettings | TrainSettings, tuple]) -> dict:
    index, name, repeat, train, settings, (attempts, equal) = job
    tests, plan, steps = _shared["tests"], _shared["plan"], _shared["steps"]
    model = fit_model(train, settings, None if steps is None else lambda step: steps.put((index, step)))
    mean = mean_displacement(train)
    out = {"source": name, "repeat": repeat, "episodes": len(train), "steps": model.trained_steps}
    if _shared["save"] is not None and hasattr(model, "save"):
        out["saved"] = str(model.save(model_file(_shared["save"], name, attempts, equal, repeat)))
    out["scores"] = {}
    for t, e in tests.items():
        pred = model.predict(e)
        out["scores"][t] = score(pred, e, mean)
        if repeat == 0:  # where each moved object ends, for the report's figure (ends.png)
            out.setdefault("ends", {})[t] = moved_ends(pred, e)
    if plan is not None:
        out["planning"] = plan_scores(model, plan, _shared["plan_settings"])
    return out


def moved_ends(pred: np.ndarray, test: EpisodeSet) -> list[list[float]]:
    """Per object that moved in ``test``: where ``pred`` (E, K, 4) ends it, in units of its true displacement
    (`metrics.ends_in_true_units`), to 3 decimals."""
    moved, _ = outcomes(test)
    units = ends_in_true_units(pred, object_state(test.first), object_state(test.final))[moved]
    return np.round(units, 3).tolist()


def nothing_moves(tests: dict[str, EpisodeSet]) -> dict:
    """The scores of predicting that nothing moves."""
    return {t: score(object_state(e.first), e, np.zeros((len(e.scene.objects), 2))) for t, e in tests.items()}


def run_experiment(
    sources: list[Source],
    tests: dict[str, EpisodeSet],
    attempt_budgets: list[int | None],
    equal_modes: list[str],
    train: GraphSettings | TrainSettings,
    plan: PlanningTask | None,
    plan_settings: PlanningSettings,
    workers: int,
    echo=print,
    progress=None,
    save: Path | None = None,
    ceiling: dict | None = None,
    bar: bool = False,
) -> dict:
    """Every (budget, equal mode): per source, the episodes trained on and the scores of each repeat;
    ``progress``, if given, is called with the result so far after each model (a long evaluation keeps what it
    measured); ``bar``: a progress bar of the training steps of every model, the workers' together."""
    blocks, jobs = [], []
    for attempts in attempt_budgets:
        for equal in equal_modes:
            per_repeat, sizes = budgets(sources, attempts, equal)
            block = {"attempts": attempts, "equal": equal, "sizes": sizes, "sources": {}}
            for r, sets in enumerate(per_repeat):
                for name, episodes in sets.items():
                    settings = replace(train, seed=train.seed + r)
                    job = (len(jobs), name, r, held_out(episodes, tests), settings, (attempts, equal))
                    jobs.append((len(blocks), job))
            blocks.append(block)
    tests_info = {}
    for name, e in tests.items():
        moved, stratum = outcomes(e)
        tests_info[name] = {
            "episodes": len(e),
            "moved_object_episodes": int(moved.sum()),
            "strata": {s: int((stratum == i).sum()) for i, s in enumerate(STRATA)},
        }
    out = {"tests": tests_info, "nothing_moves": nothing_moves(tests), "blocks": blocks}
    if plan is not None:
        out["planning"] = {
            "planner": plan_settings.planner,
            "goals": int(len(plan.goal_object)),
            "strata": {s: int(mask.sum()) for s, mask in plan.strata.items()},
            "baselines": baseline_scores(plan, plan_settings.success_cm),
        }
        if ceiling is not None:
            out["planning"]["ceiling"] = ceiling
    echo(f"training {len(jobs)} models on {workers} worker(s)")
    context = get_context("spawn")
    steps = _StepsBar(len(jobs), train.steps, context) if bar else None
    try:
        _train_all(jobs, blocks, out, workers, context, steps, (tests, plan, plan_settings, save), ceiling, echo,
                   progress)  # fmt: skip
    finally:
        if steps is not None:
            steps.close()
    return out


def _train_all(jobs, blocks, out, workers, context, steps, shared, ceiling, echo, progress) -> None:
    """`run_experiment`'s models, trained and scored in the workers, their results applied in submission order."""
    plan = shared[1]
    with ProcessPoolExecutor(
        workers, mp_context=context, initializer=_init,
        initargs=(*shared, None if steps is None else steps.queue),
    ) as pool:  # fmt: skip
        futures = [(b, pool.submit(_fit_and_score, job)) for b, job in jobs]
        for done, (b, future) in enumerate(futures, start=1):  # in submission order, whatever finishes first
            while steps is not None and not future.done():
                steps.wait()
            result = future.result()
            blocks[b]["sources"].setdefault(result["source"], []).append(result)
            if plan is not None:
                blocks[b]["planning"] = pooled_planning(blocks[b]["sources"], plan, ceiling)
            line = f"  [{done}/{len(jobs)}] {_describe(blocks[b], result)}"
            if steps is None:
                echo(line)
            else:
                steps.finished(done - 1, line)
            out["models"] = {"done": done, "total": len(jobs)}
            if progress is not None:
                progress(out)


class _StepsBar:
    """A progress bar of every model's training steps: the workers put (model, steps taken) on ``queue``; a model
    that is done counts whole (it may stop early)."""

    def __init__(self, models: int, steps: int, context) -> None:
        from tqdm import tqdm

        self.manager = context.Manager()
        self.queue, self.steps = self.manager.Queue(), steps
        self.taken = [0] * models
        self.bar = tqdm(total=models * steps, unit="step", desc="training", dynamic_ncols=True, smoothing=0.1)

    def wait(self, seconds: float = 0.5) -> None:
        """Count the steps the workers told, waiting up to ``seconds`` for the first."""
        import queue

        try:
            item = self.queue.get(timeout=seconds)
        except queue.Empty:
            return
        while True:
            self._count(*item)
            try:
                item = self.queue.get_nowait()
            except queue.Empty:
                return

    def finished(self, model: int, line: str) -> None:
        self._count(model, self.steps)
        self.bar.write(line)

    def close(self) -> None:
        self.bar.close()
        self.manager.shutdown()

    def _count(self, model: int, taken: int) -> None:
        if taken > self.taken[model]:
            self.bar.update(taken - self.taken[model])
            self.taken[model] = taken


def pooled_planning(sources: dict[str, list[dict]], plan: PlanningTask, ceiling: dict | None = None) -> dict:
    """Per source, its planning success pooled over the repeats trained so far: per goal the mean over repeats,
    then the mean over goals with a 95 % bootstrap interval over goals, overall and per goal stratum; and on the
    ceiling's goals, beside the ceiling's own success there and the share of it."""
    out = {}
    for name, results in sources.items():
        per_goal = np.mean([r["planning"]["goal_success"] for r in results], axis=0)
        entry = {"model": float(per_goal.mean()), "ci95": bootstrap_ci(per_goal), "repeats": len(results)}
        entry["strata"] = {}
        for s, mask in plan.strata.items():
            value = float(per_goal[mask].mean()) if mask.any() else float("nan")
            entry["strata"][s] = {"model": value, "ci95": bootstrap_ci(per_goal[mask])}
        if ceiling is not None and ceiling["goals"]:
            mine = per_goal[ceiling["goals"]]
            entry["on_ceiling_goals"] = {
                "model": float(mine.mean()),
                "ci95": bootstrap_ci(mine),
                "ceiling": ceiling["rate"],
                "share": float(mine.mean() / ceiling["rate"]) if ceiling["rate"] else float("nan"),
            }
        out[name] = entry
    return out


def _describe(block: dict, result: dict) -> str:
    budget = "whole datasets" if block["attempts"] is None else f"{block['attempts']} attempts"
    first = next(iter(result["scores"].values()))["all"]
    plan = f", planning {result['planning']['model']:.2f}" if "planning" in result else ""
    return (
        f"{result['source']} (repeat {result['repeat'] + 1}, {budget}, equal {block['equal']}, "
        f"{result['episodes']} episodes): F1 {first['f1']:.3f}, error {first['ratio']:.2f}x nothing moves{plan}"
    )
