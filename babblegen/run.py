"""The generation loop: ask, evaluate, describe, tell, write; commit points; resume; clean interruption.

Directory layout of a run (the LeRobot dataset root):
    meta/ data/ videos/          LeRobot v3.0 dataset (one executed trajectory = one episode)
    babblegen/run.json           configuration, package versions, task description
    babblegen/attempts.jsonl     one row per attempted movement (the sidecar table)
    babblegen/checkpoint.pkl     the last commit point: explorer state, counters, dataset file record
    babblegen/rerun/             Rerun recordings (when enabled)
"""

from __future__ import annotations

import importlib.metadata
import math
import os
import pickle
import platform
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.config import ConfigError, RunConfig
from babblegen.exporters.lerobot import EpisodeWriter, atomic_write, features, rollback
from babblegen.exporters.sidecar import (
    ATTEMPTS,
    CHECKPOINT,
    RUN_INFO,
    AttemptLog,
    read_run_info,
    sidecar_dir,
)
from babblegen.interrupts import Interrupted, Interrupts
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

    def lines(self) -> list[str]:
        rate = self.attempts / self.seconds if self.seconds > 0 else 0.0
        return [
            f"{'interrupted' if self.interrupted else 'finished'}: {self.attempts} attempts, {self.executed} executed "
            f"episodes, {self.contacts} with contact, archive {self.archive}, {self.generations} generations, "
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
        self.counters = {"attempts": 0, "executed": 0, "contacts": 0, "generations": 0, "worker_failures": 0}
        self.writer: EpisodeWriter | None = None
        self.log: AttemptLog | None = None
        self.sinks: list[Any] = []

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
        self.descriptor = make_descriptor(cfg.descriptor)
        explorer_cfg = {f: getattr(cfg.noveb, f) for f in ("population", "generations", "k")}
        if cfg.explorer == "noveb":
            explorer_cfg = cfg.noveb
        if cfg.max_attempts is not None:
            gens = math.ceil(cfg.max_attempts / cfg.noveb.population)
            explorer_cfg = (
                {**explorer_cfg, "generations": gens}
                if isinstance(explorer_cfg, dict)
                else type(explorer_cfg)(**{**explorer_cfg.__dict__, "generations": gens})
            )
        self.explorer = make_explorer(
            cfg.explorer,
            explorer_cfg,
            rng_seed=cfg.seed,
            joint_limits=np.asarray(kin_info["limits"]),
            start_norm=np.asarray(kin_info["start_norm"]),
        )
        self.total_generations = (
            explorer_cfg["generations"] if isinstance(explorer_cfg, dict) else explorer_cfg.generations
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
        import json

        atomic_write(sdir / RUN_INFO, json.dumps(info, indent=2, default=_json_default).encode())
        self.log = AttemptLog(sdir / ATTEMPTS)

    def _open_resumed(self) -> None:
        sdir = sidecar_dir(self.out)
        ckpt_path = sdir / CHECKPOINT
        if not ckpt_path.exists():
            # died before its first commit point: nothing worth keeping, start the same run afresh
            keep = sdir / RUN_INFO
            data = keep.read_bytes()
            for p in self.out.iterdir():
                shutil.rmtree(p) if p.is_dir() else p.unlink()
            self._open_new()
            atomic_write(keep, data)
            return
        with open(ckpt_path, "rb") as f:
            ckpt = pickle.load(f)
        rollback(self.out, ckpt["dataset"])
        AttemptLog.truncate(sdir / ATTEMPTS, ckpt["sidecar_offset"])
        self.explorer.load_state_dict(ckpt["explorer"])
        self.counters.update(ckpt["counters"])
        self.writer = EpisodeWriter.reopen(self.out, read_run_info(self.out)["repo_id"])
        self.log = AttemptLog(sdir / ATTEMPTS)
        for sink in self.sinks:
            sink.rollback(self.counters["executed"])

    def _commit(self, reopen: bool = True) -> None:
        record = self.writer.commit() if reopen else (self.writer.finalize() or _snapshot(self.out))
        for sink in self.sinks:
            sink.flush()
        state = {
            "format_version": FORMAT_VERSION,
            "explorer": self.explorer.state_dict(),
            "counters": dict(self.counters),
            "sidecar_offset": self.log.offset(),
            "dataset": record,
        }
        atomic_write(sidecar_dir(self.out) / CHECKPOINT, pickle.dumps(state))

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
        self._setup()
        if self.config.rerun:
            from babblegen.exporters.rerun_log import RerunSink

            self.sinks.append(RerunSink(self.out, self.task, self.joint_names))
        if self.resumed:
            self._open_resumed()
        else:
            self._open_new()
        if self.resumed:
            echo(
                f"resuming {self.out} at generation {self.counters['generations']} "
                f"({self.counters['attempts']} attempts, {self.counters['executed']} episodes)"
            )
        interrupted = False
        bar = _progress(progress, self.total_generations * self.config.noveb.population, self.counters["attempts"])
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
                    if self.log is not None:
                        self.log.close()
                    self.evaluator.close()
        return RunSummary(
            self.out,
            self.counters["attempts"],
            self.counters["executed"],
            self.counters["contacts"],
            self.explorer.archive_size,
            self.counters["generations"],
            time.perf_counter() - t0,
            interrupted,
        )

    def _submit(self):
        cands = self.explorer.ask()
        self.evaluator.submit([command_for(c) for c in cands], [c.index for c in cands])
        return cands

    def _loop(self, bar) -> None:
        """Generations, pipelined: the next generation is submitted before this one's episodes are written,
        so workers simulate while the (single) writer writes."""
        if self.explorer.done:
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
            next_cands = None if self.explorer.done else self._submit()
            self._write_generation(cands, rollouts, codes, evaluations, t_desc, t_wait, bar)
            if self.counters["generations"] % self.config.checkpoint_every == 0:
                with self._interrupts.protected():
                    self._commit()
            if next_cands is None:
                return
            cands = next_cands

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
                if bar is not None:
                    bar.update(1)
        self.counters["generations"] += 1
        if bar is not None:
            bar.set_postfix(
                executed=self.counters["executed"],
                archive=self.explorer.archive_size,
                contacts=self.counters["contacts"],
                refresh=False,
            )


def _progress(enabled: bool, total: int, initial: int):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="attempt", dynamic_ncols=True, smoothing=0.05)


def _snapshot(root: Path) -> dict:
    from babblegen.exporters.lerobot import snapshot

    return snapshot(root)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
