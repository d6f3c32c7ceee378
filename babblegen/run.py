"""The generation loop: ask, evaluate, describe, tell, write; commit points; resume; clean interruption.

Directory layout of a run (the LeRobot dataset root):
    meta/ data/ videos/          LeRobot v3.0 dataset (one executed trajectory = one episode)
    babblegen/run.json           configuration, package versions, task description
    babblegen/attempts.jsonl     one row per attempted movement (the sidecar table)
    babblegen/checkpoint.json    the last commit point: explorer state, counters, dataset file record
    babblegen/checkpoint.prev.json   the commit point before it (the fallback if the last is damaged)
    babblegen/rerun/             Rerun recordings (when enabled)
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import platform
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.config import ConfigError, RunConfig
from babblegen.exporters.dataset_card import write_card
from babblegen.exporters.lerobot import EpisodeWriter, atomic_write, features, rollback
from babblegen.exporters.sidecar import (
    ATTEMPTS,
    CHECKPOINT,
    CLONES,
    PREVIOUS_CHECKPOINT,
    RUN_INFO,
    AttemptLog,
    read_run_info,
    sidecar_dir,
)
from babblegen.interrupts import Interrupted, Interrupts
from babblegen.lock import DatasetLock
from babblegen.world.rollout import Command, Rollout

FORMAT_VERSION = 1
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
)


@dataclass
class RunSummary:
    out: Path
    attempts: int
    executed: int
    contacts: int
    archive: int
    generations: int
    seconds: float
    interrupted: bool = False
    clones: int = 0

    def lines(self) -> list[str]:
        rate = self.attempts / self.seconds if self.seconds > 0 else 0.0
        return [
            f"{'interrupted' if self.interrupted else 'finished'}: {self.attempts} attempts, {self.executed} executed "
            f"episodes, {self.contacts} with contact, archive {self.archive}, {self.generations} generations "
            f"({self.clones} clones of tried genomes reused, not simulated), "
            f"{self.seconds:.0f} s ({rate:.2f} attempts/s)",
            f"dataset: {self.out}",
        ]


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for p in PACKAGES:
        try:
            out[p] = importlib.metadata.version(p)
        except importlib.metadata.PackageNotFoundError:
            out[p] = "not installed"
    return out


def is_babblegen_dataset(path: Path) -> bool:
    return (sidecar_dir(path) / RUN_INFO).is_file()


def check_output(out: Path, resume: bool) -> None:
    """Refuse anything that would touch an existing dataset by mistake; nothing is written here."""
    if resume:
        if not out.exists():
            raise ConfigError(f"--resume: {out} does not exist")
        if not is_babblegen_dataset(out):
            raise ConfigError(f"--resume: {out} is not a babblegen dataset (no {sidecar_dir(out) / RUN_INFO})")
        if not os.access(out, os.W_OK):
            raise ConfigError(f"--resume: {out} is not writable")
        return
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(
            f"{out} already exists and is not empty; use --resume to continue a babblegen run there, "
            "or choose another --out"
        )
    try:  # the only reliable test of writability (root ignores permission bits)
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".babblegen-write-test"
        probe.touch()
        probe.unlink()
    except OSError as e:
        raise ConfigError(f"cannot write to {out}: {e.strerror or e}") from None


def command_for(candidate) -> Command:
    return Command(candidate.kind, np.asarray(candidate.genome, dtype=np.float64))


class Run:
    """A babbling run writing to `out`. Build with `Run.start` (new) or `Run.resume`."""

    def __init__(self, out: Path, config: RunConfig, resumed: bool):
        self.out, self.config, self.resumed = Path(out), config, resumed
        self.counters = {
            "attempts": 0,
            "executed": 0,
            "contacts": 0,
            "generations": 0,
            "clones": 0,
            "worker_failures": 0,
        }
        self.writer: EpisodeWriter | None = None
        self.log: AttemptLog | None = None
        self.clone_log: AttemptLog | None = None
        self.sinks: list[Any] = []
        self.lock = DatasetLock(sidecar_dir(self.out))

    # --- construction -------------------------------------------------------------------------------------
    @classmethod
    def start(cls, out: str | Path, config: RunConfig) -> Run:
        out = Path(out)
        config.validate()
        check_output(out, resume=False)
        return cls(out, config, resumed=False)

    @classmethod
    def resume(cls, out: str | Path, overrides: dict[str, Any] | None = None) -> Run:
        """Continue the run at `out` with its stored configuration; `overrides` may extend it (generations,
        max_attempts) or change how it runs (workers, ray, rerun), nothing that would change its results."""
        out = Path(out)
        check_output(out, resume=True)
        info = read_run_info(out)
        data = info["config"]
        allowed = {"max_attempts", "generations", "workers", "ray", "rerun", "checkpoint_every"}
        for key, value in (overrides or {}).items():
            if value is None:
                continue
            section = next((sec for sec in (data, data["noveb"], data["world"]) if key in sec), None)
            if section is None:
                raise ConfigError(f"unknown setting {key!r}")
            if section[key] == value:
                continue
            if key not in allowed:
                raise ConfigError(f"--resume cannot change {key!r} of an existing run (stored: {section[key]!r})")
            section[key] = value
        config = RunConfig.from_dict(data)
        config.validate()
        return cls(out, config, resumed=True)

    # --- the loop -----------------------------------------------------------------------------------------
    def _setup(self):
        from babblegen.descriptors import make_descriptor
        from babblegen.evaluation import LocalEvaluator, arm_info
        from babblegen.explorers import make_explorer
        from babblegen.tasks import get_task

        cfg = self.config
        self.task = get_task(cfg.task)
        if cfg.workers > 1 or cfg.ray:
            from babblegen.parallel import make_parallel_evaluator

            self.evaluator = make_parallel_evaluator(self.task, cfg)
        else:
            self.evaluator = LocalEvaluator(self.task, cfg.world, cfg.seed)
        kin_info = arm_info(self.task)
        self.joint_names = list(kin_info["joints"])
        self.descriptor = make_descriptor(**cfg.descriptor_config())
        self.explorer = make_explorer(
            cfg.explorer,
            cfg.explorer_config(),
            rng_seed=cfg.seed,
            joint_limits=np.asarray(kin_info["limits"]),
            start_norm=np.asarray(kin_info["start_norm"]),
        )
        self.task_text = f"{cfg.explorer} babbling in {cfg.task}"
        self.repo_id = f"babblegen/{self.out.name or 'dataset'}"

    def _open_new(self) -> None:
        cfg = self.config
        sdir = sidecar_dir(self.out)
        feats = features(self.joint_names, self.task.object_names, cfg.world.camera_height, cfg.world.camera_width)
        if self.out.exists() and not any(self.out.iterdir()):
            self.out.rmdir()  # LeRobot refuses an existing root, even an empty one
        self.writer = EpisodeWriter.create(self.out, self.repo_id, cfg.world.fps, feats, robot_type="pr2_like_arm")
        sdir.mkdir(parents=True, exist_ok=True)
        info = {
            "format_version": FORMAT_VERSION,
            "repo_id": self.repo_id,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "command": sys.argv,
            "config": cfg.to_dict(),
            "versions": versions(),
            "task": self.task.to_dict(),
            "joint_names": self.joint_names,
            "object_names": self.task.object_names,
            "episode_task": self.task_text,
        }
        atomic_write(sdir / RUN_INFO, json.dumps(info, indent=2, default=_json_default).encode())
        self.log = AttemptLog(sdir / ATTEMPTS)
        self.clone_log = AttemptLog(sdir / CLONES)

    def _open_resumed(self) -> None:
        sdir = sidecar_dir(self.out)
        if not (sdir / CHECKPOINT).exists() and not (sdir / PREVIOUS_CHECKPOINT).exists():
            if (sdir / "checkpoint.pkl").exists():
                raise ConfigError(
                    f"--resume: {self.out} was made by an older babblegen that stored its state as a pickle, "
                    "which this version does not load (it could run code); start a new run"
                )
            # died before its first commit point: nothing worth keeping, start the same run afresh
            keep = sdir / RUN_INFO
            data = keep.read_bytes()
            for p in self.out.iterdir():
                shutil.rmtree(p) if p.is_dir() else p.unlink()
            self.lock.release()
            self._open_new()
            atomic_write(keep, data)
            self.lock.acquire(self.out)
            return
        ckpt = self._read_checkpoint(sdir)
        info = read_run_info(self.out)
        if info["config"] != self.config.to_dict():  # extended: the stored config says what the run now is
            info["config"] = self.config.to_dict()
            info.setdefault("resumed", []).append({"at": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": sys.argv})
            atomic_write(sdir / RUN_INFO, json.dumps(info, indent=2, default=_json_default).encode())
        rollback(self.out, ckpt["dataset"])
        AttemptLog.truncate(sdir / ATTEMPTS, ckpt["sidecar_offset"])
        AttemptLog.truncate(sdir / CLONES, ckpt.get("clones_offset", 0))
        self.explorer.load_state_dict(ckpt["explorer"])
        self.counters.update(ckpt["counters"])
        self.writer = EpisodeWriter.reopen(self.out, read_run_info(self.out)["repo_id"])
        self.log = AttemptLog(sdir / ATTEMPTS)
        self.clone_log = AttemptLog(sdir / CLONES)
        for sink in self.sinks:
            sink.rollback(self.counters["executed"])

    def _read_checkpoint(self, sdir: Path) -> dict[str, Any]:
        """The last commit point, or the one before it when the last is missing or damaged."""
        from babblegen.exporters.state_file import StateFileError, loads

        problems = []
        for name in (CHECKPOINT, PREVIOUS_CHECKPOINT):
            try:
                ckpt = loads((sdir / name).read_bytes())
                missing = {"explorer", "counters", "sidecar_offset", "dataset"} - set(ckpt)
                if missing:
                    raise StateFileError(f"missing {', '.join(sorted(missing))}")
            except (OSError, StateFileError) as e:
                problems.append(f"{name}: {e}")
                continue
            if problems:
                print(
                    f"babblegen: warning: {problems[0]}; resuming from the commit point before it",
                    file=sys.stderr,
                )
            return ckpt
        raise ConfigError(
            f"--resume: the run state in {sdir} is damaged and there is no earlier commit point to fall back to "
            f"({'; '.join(problems)}); the episodes written so far still load with LeRobot"
        )

    def _commit(self, reopen: bool = True) -> None:
        record = self.writer.commit() if reopen else (self.writer.finalize() or _snapshot(self.out))
        for sink in self.sinks:
            sink.flush()
        state = {
            "format_version": FORMAT_VERSION,
            "explorer": self.explorer.state_dict(),
            "counters": dict(self.counters),
            "sidecar_offset": self.log.offset(),
            "clones_offset": self.clone_log.offset(),
            "dataset": record,
        }
        from babblegen.exporters.state_file import dumps

        sdir = sidecar_dir(self.out)
        data = dumps(state)
        if (sdir / CHECKPOINT).exists():
            os.replace(sdir / CHECKPOINT, sdir / PREVIOUS_CHECKPOINT)  # a crash here resumes from this one
        atomic_write(sdir / CHECKPOINT, data)
        write_card(self.out, read_run_info(self.out), self.counters)

    def _row(self, cand, rollout: Rollout, code, evaluation, episode: int | None, seconds: dict) -> dict:
        names = self.task.object_names
        row: dict[str, Any] = {
            "attempt": cand.index,
            "generation": cand.generation,
            "explorer": self.config.explorer,
            "kind": cand.kind,
            "genome": np.asarray(cand.genome).tolist(),
            "parent": cand.parent,
            "feasible": rollout.feasible,
            "reason": rollout.reason,
            "episode_index": episode,
            "descriptor": None if code is None else self.descriptor.hex(code),
            "novelty": evaluation.novelty,
            "archived": evaluation.archived,
            "ee_targets": None if rollout.ee_targets is None else np.round(rollout.ee_targets, 5).tolist(),
            "planner": rollout.planner,
        }
        if rollout.feasible:
            contact_frames = rollout.frames.contacts.sum(axis=0)
            row.update(
                n_frames=len(rollout.frames),
                touched={n: bool(t) for n, t in zip(names, rollout.touched, strict=True)},
                contact_frames={n: int(c) for n, c in zip(names, contact_frames, strict=True)},
                displacement={n: round(float(d), 6) for n, d in zip(names, rollout.displacement, strict=True)},
                final_poses={n: np.round(p, 6).tolist() for n, p in zip(names, rollout.final_poses, strict=True)},
                final_ee_pos=self._farthest_ee(rollout),
            )
        row["timings"] = {k: round(v, 5) for k, v in {**rollout.timings, **seconds}.items()}
        return row

    @staticmethod
    def _farthest_ee(rollout: Rollout) -> list[float]:
        """The tool position at the trajectory's final waypoint (the paper's Fig. 2 point)."""
        if rollout.ee_targets is not None:
            return np.round(rollout.ee_targets[-1], 5).tolist()
        ee = rollout.frames.ee_pos
        far = int(np.argmax(np.linalg.norm(ee - ee[0], axis=1)))
        return np.round(ee[far], 5).tolist()

    def execute(self, progress: bool = True, echo=print) -> RunSummary:
        """Run to completion or interruption. The dataset is finalized and loads either way."""
        t0 = time.perf_counter()
        if self.resumed:
            self.lock.acquire(self.out)  # before anything is rolled back: another run may be writing
        self._setup()
        if self.config.rerun:
            from babblegen.exporters.rerun_log import RerunSink

            self.sinks.append(RerunSink(self.out, self.task, self.joint_names))
        try:
            if self.resumed:
                self._open_resumed()
            else:
                self._open_new()
                self.lock.acquire(self.out)
        except BaseException:
            self.evaluator.close()
            self.lock.release()
            raise
        if self.resumed:
            echo(
                f"resuming {self.out} at generation {self.counters['generations']} "
                f"({self.counters['attempts']} attempts, {self.counters['executed']} episodes)"
            )
        interrupted = False
        bar = self._progress_bar(progress)
        with Interrupts() as self._interrupts:
            try:
                self._loop(bar)
                with self._interrupts.protected():
                    self._commit(reopen=False)
            except (Interrupted, KeyboardInterrupt):
                interrupted = True
            finally:
                with self._interrupts.closing():
                    if bar is not None:
                        bar.close()
                    # Whatever happened, close the dataset so what is written loads.
                    if self.writer is not None:
                        self.writer.finalize()
                    for sink in self.sinks:
                        sink.close()
                    for log in (self.log, self.clone_log):
                        if log is not None:
                            log.close()
                    self.evaluator.close()
                    self.lock.release()
        return RunSummary(
            self.out,
            self.counters["attempts"],
            self.counters["executed"],
            self.counters["contacts"],
            self.explorer.archive_size,
            self.counters["generations"],
            time.perf_counter() - t0,
            interrupted,
            self.counters["clones"],
        )

    def _finished(self) -> bool:
        """The run's stopping rule: all generations told, or ``max_attempts`` movements attempted. Clones
        (children repeating a genome already tried) are not attempts."""
        cfg = self.config
        if self.explorer.generation >= cfg.noveb.generations:
            return True
        return cfg.max_attempts is not None and self.explorer.attempts_asked >= cfg.max_attempts

    def _submit(self):
        left = None if self.config.max_attempts is None else self.config.max_attempts - self.explorer.attempts_asked
        cands = self.explorer.ask(max_new=left)
        self.evaluator.submit([command_for(c) for c in cands], [c.index for c in cands])
        return cands

    def _loop(self, bar) -> None:
        """Generations, pipelined: the next generation is submitted before this one's episodes are written,
        so workers simulate while the (single) writer writes."""
        if self._finished() and not self.explorer.batch_open:
            return
        cands = self._submit()
        while True:
            t = time.perf_counter()
            rollouts = self.evaluator.collect()
            t_wait = time.perf_counter() - t
            codes, t_desc = [], []
            for r in rollouts:
                t = time.perf_counter()
                codes.append(self.descriptor(r.after_image) if r.feasible else None)
                t_desc.append(time.perf_counter() - t)
            evaluations = self.explorer.tell(cands, codes)
            clones = self.explorer.last_clones
            next_cands = None if self._finished() else self._submit()
            self._write_generation(cands, rollouts, codes, evaluations, t_desc, t_wait, bar)
            with self._interrupts.protected():
                for clone in clones:
                    self.clone_log.append(clone_row(clone))
                self.counters["clones"] += len(clones)
            if self.counters["generations"] % self.config.checkpoint_every == 0:
                with self._interrupts.protected():
                    self._commit()
            if next_cands is None:
                return
            cands = next_cands

    def _progress_bar(self, enabled: bool):
        """Counts attempts when ``max_attempts`` bounds the run, generations otherwise."""
        if not enabled:
            return None
        from tqdm import tqdm

        if self.config.max_attempts is not None:
            total, initial, unit = self.config.max_attempts, self.counters["attempts"], "attempt"
        else:
            total, initial, unit = self.config.noveb.generations, self.counters["generations"], "gen"
        return tqdm(total=total, initial=initial, unit=unit, dynamic_ncols=True, smoothing=0.05)

    def _write_generation(self, cands, rollouts, codes, evaluations, t_desc, t_wait, bar) -> None:
        for cand, r, code, ev, td in zip(cands, rollouts, codes, evaluations, t_desc, strict=True):
            with self._interrupts.protected():
                episode = None
                failures = int(r.timings.pop("worker_failures", 0))
                t = time.perf_counter()
                if r.feasible:
                    episode = self.writer.add_episode(r.frames, self.task_text)
                    self.counters["executed"] += 1
                    self.counters["contacts"] += int(r.touched.any())
                t_write = time.perf_counter() - t
                row = self._row(cand, r, code, ev, episode, {"descriptor": td, "write": t_write})
                row["timings"]["wait_for_batch"] = round(t_wait, 5)
                row["timings"]["written_at"] = round(time.time(), 3)
                row["worker_failures"] = failures
                self.counters["worker_failures"] += failures
                self.log.append(row)
                for sink in self.sinks:
                    sink.log(row, r)
                self.counters["attempts"] += 1
                if bar is not None and self.config.max_attempts is not None:
                    bar.update(1)
        self.counters["generations"] += 1
        if bar is not None:
            if self.config.max_attempts is None:
                bar.update(1)
            bar.set_postfix(
                attempts=self.counters["attempts"],
                episodes=self.counters["executed"],
                contact=self.counters["contacts"],
                archive=self.explorer.archive_size,
                refresh=False,
            )


def clone_row(clone) -> dict[str, Any]:
    """A sidecar row for a child that reused an earlier attempt's outcome (``DIR/babblegen/clones.jsonl``)."""
    return {
        "generation": clone.generation,
        "kind": clone.kind,
        "genome": np.asarray(clone.genome).tolist(),
        "parent": clone.parent,
        "source": clone.source,
        "novelty": clone.novelty,
        "survived": clone.survived,
    }


def _snapshot(root: Path) -> dict:
    from babblegen.exporters.lerobot import snapshot

    return snapshot(root)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
