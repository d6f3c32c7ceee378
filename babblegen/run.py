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

import os
import shutil
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from babblegen.assembly import arm_info, build_descriptor, build_evaluator, build_explorer, build_task
from babblegen.config import ConfigError, RunConfig, resumed_config
from babblegen.dataset.paths import RUN_INFO, is_babblegen_dataset, sidecar_dir
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.descriptors import describe_rollout
from babblegen.explorers.base import ask_while_possible
from babblegen.exporters.sidecar import attempt_row, clone_row, recorded_poses
from babblegen.interrupts import for_command, stopped_by
from babblegen.outputs import RunOutputs
from babblegen.progress import Progress
from babblegen.provenance import machine, versions
from babblegen.shapes import ObjectSpec
from babblegen.store import AttemptRecord, RunStore, atomic_write
from babblegen.tasks import get_robot
from babblegen.world.rollout import Command

FORMAT_VERSION = 1  # of run.json


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
    resumed_at: int = 0  # attempts made before this sitting (a resumed run)
    signal: str | None = None  # the stop received (SIGINT / SIGTERM), also when it came as the run finished
    written: bool = True  # False: stopped before its dataset held an episode, this sitting left nothing behind

    def lines(self) -> list[str]:
        made = self.attempts - self.resumed_at
        rate = made / self.seconds if self.seconds > 0 else 0.0
        sitting = f" ({made} in this sitting)" if self.resumed_at else ""
        return [
            f"{'interrupted' if self.interrupted else 'finished'}: {self.attempts} attempts{sitting}, "
            f"{self.executed} executed "
            f"episodes, {self.contacts} with contact, archive {self.archive}, {self.generations} generations "
            f"({self.clones} clones of tried genomes reused, not simulated), "
            f"{self.seconds:.0f} s ({rate:.2f} attempts/s)",
            f"dataset: {self.out}",
        ]


def check_output(out: Path, resume: bool) -> None:
    """Refuse anything that would touch an existing dataset by mistake; nothing is written here."""
    if resume:
        if not out.exists():
            raise ConfigError(f"--resume: {out} does not exist")
        if out.is_dir() and not any(p for p in out.iterdir() if p.name != ".babblegen-write-test"):
            raise ConfigError(
                f"--resume: nothing was written to {out} yet (the run stopped while it was starting); run the same "
                "command without --resume"
            )
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
    start = None if candidate.start is None else candidate.start.placement
    objects = None if candidate.start is None else candidate.start.objects
    return Command(candidate.kind, np.asarray(candidate.genome, dtype=np.float64), start, objects)


class Run:
    """A babbling run writing to ``out``. Build with :meth:`start` (new) or :meth:`resume`, then :meth:`execute`.

    The loop is the paper's: ask the explorer for a generation, roll it out, describe each outcome, tell the
    explorer, and hand every attempt to the run store, which writes it to every sink and commits them together.
    """

    def __init__(self, out: Path, config: RunConfig, resumed: bool):
        self.out, self.config, self.resumed = Path(out), config, resumed
        self.counters = dict.fromkeys(("attempts", "executed", "contacts", "generations", "clones"), 0)
        self.counters["worker_failures"] = 0
        self.store = RunStore(self.out)

    @classmethod
    def start(cls, out: str | Path, config: RunConfig) -> Run:
        out = Path(out)
        config.validate()
        check_output(out, resume=False)
        return cls(out, config, resumed=False)

    @classmethod
    def resume(cls, out: str | Path, overrides: dict[str, Any] | None = None) -> Run:
        """Continue the run at ``out`` with its stored configuration (see :func:`resumed_config`)."""
        out = Path(out)
        check_output(out, resume=True)
        return cls(out, resumed_config(read_run_info(out)["config"], overrides), resumed=True)

    @property
    def repo_id(self) -> str:
        return f"babblegen/{self.out.name or 'dataset'}"

    # --- opening --------------------------------------------------------------------------------------------
    def _build_parts(self, check_interrupt: Callable[[], None]) -> None:
        cfg = self.config
        self.task = build_task(cfg)
        self.robot = get_robot(self.task.robot_uid)
        arm = arm_info(self.task)
        self.joint_names = list(arm["joints"])
        self.outputs = RunOutputs(self.out, cfg, self.task, self.joint_names)
        self.descriptor = build_descriptor(cfg)
        self.explorer = build_explorer(cfg, arm)
        self.evaluator = build_evaluator(self.task, cfg, prepare=self.outputs.preparers(), describe=self.descriptor)
        self.task_text = self.outputs.task_text
        try:  # while worker processes start (seconds), import what the sinks need here
            self.outputs.import_libraries()
            check_interrupt()  # a library's bare ``except:`` may have swallowed a stop
            self.evaluator.wait_ready()
        except BaseException:
            evaluator, self.evaluator = self.evaluator, None
            evaluator.close()
            raise

    def _sinks(self, repo_id: str) -> list[tuple[str, Any]]:
        """The run's sinks (`RunOutputs.sinks`)."""
        return self.outputs.sinks(repo_id, self.counters if self.resumed else None)

    def _open_new(self) -> None:
        self._fresh = True  # this sitting makes the dataset (`_discard`)
        self.store.open_sinks(self._sinks(self.repo_id)[:1])  # LeRobot creates the root directory
        self.store.write_info(
            {
                "format_version": FORMAT_VERSION,
                "repo_id": self.repo_id,
                "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "command": sys.argv,
                "config": self.config.to_dict(),
                "versions": versions(),
                "machine": machine(),
                "fingerprint": self._fingerprint_record(),
                "task": self.task.to_dict(),
                "robot": self.robot.to_dict(),
                "joint_names": self.joint_names,
                "object_names": self.task.object_names,
                "episode_task": self.task_text,
            }
        )
        self.store.lock.acquire(self.out)
        self.store.open_sinks(self._sinks(self.repo_id)[1:])

    def _fingerprint_record(self, others: dict[str, str] | None = None) -> dict[str, Any]:
        """run.json's ``fingerprint``: this machine's (`babblegen.fingerprint`), and whether the run is mixed, with
        the machines that compute otherwise (``nodes``, each one's fingerprint) when it is."""
        others = {**(others or {}), **self.evaluator.other_machines}
        record: dict[str, Any] = {"hash": self.evaluator.fingerprint, "mixed": bool(others)}
        if others:
            record["nodes"] = others
        return record

    def _check_machines(self) -> None:
        """A resume on a machine that computes otherwise than the one that made the run is refused unless mixed
        machines are allowed; run.json records mixed machines (also those that join later: a replaced Ray actor)."""
        info = self.store.info()
        stored = info.get("fingerprint")
        if stored is None:  # made before fingerprints were recorded: nothing to compare
            return
        others = dict(stored.get("nodes", {}))
        here = self.evaluator.fingerprint
        if here != stored["hash"] and here not in others.values():
            if not self.config.allow_mixed_machines:
                raise ConfigError(
                    f"--resume: this machine computes differently from the one that made {self.out} (fingerprint "
                    f"{here}, {stored['hash']} recorded), so the dataset would depend on where each part was made; "
                    "resume on a machine of its kind, or allow it with --allow-mixed-machines (run.json then records "
                    "the run as mixed)"
                )
            others[f"resumed on {machine().get('cpu', 'this machine')}"] = here
        record = self._fingerprint_record(others)
        record["hash"] = stored["hash"]
        if record != stored:
            info["fingerprint"] = record
            self.store.write_info(info)

    def _open_resumed(self, echo) -> None:
        store = self.store
        if not store.has_checkpoint():
            if (store.dir / "checkpoint.pkl").exists():
                raise ConfigError(
                    f"--resume: {self.out} was made by an older babblegen that stored its state as a pickle, "
                    "which this version does not load (it could run code); start a new run"
                )
            # died before its first commit point: nothing worth keeping, start the same run afresh
            self._check_machines()
            info = store.dir / RUN_INFO
            data = info.read_bytes()
            store.lock.release()
            for p in self.out.iterdir():
                shutil.rmtree(p) if p.is_dir() else p.unlink()
            self._open_new()
            atomic_write(info, data)  # the same run, started afresh
            store.record_extension(self.config.to_dict())  # with what this resume changed
            return
        ckpt = store.read_checkpoint(lambda message: print(f"babblegen: warning: {message}", file=sys.stderr))
        self._check_machines()
        store.record_extension(self.config.to_dict())
        self.explorer.load_state_dict(ckpt["explorer"])
        self.counters.update(ckpt["counters"])
        store.open_sinks(self._sinks(store.info()["repo_id"]), ckpt["sinks"])
        if self.explorer.starts is not None:  # the scenes committed movements left, as the sidecar recorded them
            names = self.task.object_names
            drawn = self.config.world.objects != "paper"
            for row in read_attempts(self.out):
                if row.get("feasible") and row.get("final_poses"):
                    objects = tuple(ObjectSpec.from_factors(o) for o in row["objects"]) if drawn else None
                    poses = np.array([row["final_poses"][n] for n in names])
                    self.explorer.starts.record_end(row["attempt"], poses, objects)
        echo(
            f"resuming {self.out} at generation {self.counters['generations']} "
            f"({self.counters['attempts']} attempts, {self.counters['executed']} episodes)"
        )

    # --- running --------------------------------------------------------------------------------------------
    def execute(self, progress: bool = True, echo=print) -> RunSummary:
        """Run to completion or to a stop (SIGINT / SIGTERM, at any moment: `babblegen.interrupts`). The dataset is
        finalized and loads either way; a stop before it holds an episode leaves nothing behind (`_discard`)."""
        t0 = time.perf_counter()
        self.evaluator, self._fresh, self._opened = None, False, False
        interrupted, bar, resumed_at = False, None, self.counters["attempts"]
        with for_command() as stop:
            self._interrupts = stop
            try:
                with stop.raising():
                    if self.resumed:
                        self.store.lock.acquire(self.out)  # before anything is rolled back: another run may write
                    self._build_parts(stop.check)
                    with stop.protected():  # a dataset is opened whole or not at all
                        self._open_resumed(echo) if self.resumed else self._open_new()
                        self.store.start_writer()  # commit points are written while the search goes on
                        self._opened, resumed_at = True, self.counters["attempts"]
                    bar = Progress(self.config, self.counters, self.explorer, progress)
                    self._loop(bar)
                    with stop.protected():
                        self.store.commit(self.explorer.state_dict(), self.counters, final=True)
                        stop.record_only()  # finished: a signal from now on is recorded only
            except BaseException as e:
                if not stopped_by(e) and stop.pending is None:
                    raise
                interrupted = True
                if not stopped_by(e):  # raised as a signal arrived, by whatever the signal cut short
                    print(f"babblegen: warning: stopping on {stop.pending}: {type(e).__name__}: {e}", file=sys.stderr)
            finally:
                with stop.closing():
                    self._close(bar)
            written = self._opened
            if interrupted and self._fresh and self.counters["executed"] == 0:
                self._discard()
                written = False
        c = self.counters
        return RunSummary(
            self.out,
            c["attempts"],
            c["executed"],
            c["contacts"],
            self.explorer.archive_size if written else 0,
            c["generations"],
            time.perf_counter() - t0,
            interrupted,
            c["clones"],
            resumed_at,
            stop.pending,
            written,
        )

    def _close(self, bar) -> None:
        if bar is not None:
            bar.close()
        try:
            self.store.close()
        finally:  # also when closing the store fails (a full disk): the workers are stopped
            if self.evaluator is not None:
                self.evaluator.close()

    def _discard(self) -> None:
        """A stop before the dataset this sitting made held an episode (LeRobot loads no dataset of none): nothing of
        it is kept. A new run's directory is left empty, as it was found; a resumed run that had started afresh keeps
        its run.json alone, which --resume starts again."""
        info = self.store.dir / RUN_INFO
        kept = info.read_bytes() if self.resumed and info.exists() else None
        for p in self.out.iterdir() if self.out.is_dir() else []:
            shutil.rmtree(p) if p.is_dir() else p.unlink()
        if kept is not None:
            self.store.dir.mkdir(parents=True, exist_ok=True)
            atomic_write(info, kept)

    def _finished(self) -> bool:
        """The stopping rule: all generations told, or ``max_attempts`` movements attempted. Clones (children
        repeating a genome already tried) are not attempts."""
        cfg = self.config
        if self.explorer.generation >= cfg.noveb.generations:
            return True
        return cfg.max_attempts is not None and self.explorer.attempts_asked >= cfg.max_attempts

    def _submit(self, batches: list[list]) -> list[list]:
        for candidates in batches:
            self.evaluator.submit([command_for(c) for c in candidates], [c.index for c in candidates])
        return batches

    def _loop(self, bar: Progress) -> None:
        """ask -> rollout -> describe -> tell -> write, one generation at a time, with every generation the
        explorer lets overlap (NovEB's ``lag``) asked and running meanwhile: after each tell, the explorer is asked
        for all it allows (`ask_while_possible`), so what is asked depends on the order of tells alone, never on
        timing. Generations are told in the order asked. An attempt is written once its episode is prepared
        (workers prepare episodes when they have no movement to simulate), in attempt order; at a commit point,
        every attempt told so far is."""
        limit, generations = self.config.max_attempts, self.config.noveb.generations
        open_batches = deque(self._submit(self.explorer.open_batches()))  # in flight at the commit point resumed
        if not self._finished():
            open_batches.extend(self._submit(ask_while_possible(self.explorer, limit, generations)))
        unwritten: deque[tuple] = deque()  # told attempts, in order, waiting for their episode's preparation
        while open_batches:
            candidates = open_batches.popleft()
            t = time.perf_counter()
            rollouts = self.evaluator.collect()
            waited = time.perf_counter() - t
            self._record_ends(candidates, rollouts)
            if self.evaluator.other_machines:  # a mixed run (allowed): record the machines that joined it
                self._check_machines()
            codes, describe_s = self._describe(rollouts)
            evaluations = self.explorer.tell(candidates, codes)
            clones = self.explorer.last_clones
            if not self._finished():
                open_batches.extend(self._submit(ask_while_possible(self.explorer, limit, generations)))
            for record in zip(candidates, rollouts, codes, evaluations, describe_s, strict=True):
                unwritten.append((*record, waited))
            last = not open_batches
            commit = last or (self.counters["generations"] + 1) % self.config.checkpoint_every == 0
            self._write_prepared(unwritten, bar, wait=commit)
            with self._interrupts.protected():
                self.store.write_clones([clone_row(c) for c in clones])
                self.counters["clones"] += len(clones)
                self.counters["generations"] += 1
                if commit and not last:
                    self.store.commit(self.explorer.state_dict(), self.counters)
            bar.generation_told()

    def _record_ends(self, candidates: list, rollouts: list) -> None:
        """The scenes executed movements left, which later starts may begin from (`StartSampler.made`)."""
        starts = self.explorer.starts
        if starts is not None:
            for cand, rollout in zip(candidates, rollouts, strict=True):
                if rollout.feasible:
                    objects = None if cand.start is None else cand.start.objects
                    starts.record_end(cand.index, np.array(recorded_poses(rollout.final_poses)), objects)

    def _write_prepared(self, unwritten: deque, bar: Progress, wait: bool) -> None:
        """Write the attempts at the front of ``unwritten`` whose episodes are prepared (``wait``: all of them)."""
        while unwritten:
            cand, rollout = unwritten[0][:2]
            if not self.evaluator.attach_prepared(rollout, cand.index, wait):
                return
            self._write_attempt(*unwritten.popleft(), bar)

    def _describe(self, rollouts) -> tuple[list, list[float]]:
        """Each rollout's behaviour code (made where it ran; here for an evaluator that did not) and its seconds."""
        codes, seconds = [], []
        for r in rollouts:
            if r.feasible and r.code is None:
                t = time.perf_counter()
                r.code = describe_rollout(self.descriptor, r)
                r.timings["descriptor"] = time.perf_counter() - t
            codes.append(r.code if r.feasible else None)
            seconds.append(r.timings.pop("descriptor", 0.0))
        return codes, seconds

    def _write_attempt(self, cand, rollout, code, evaluation, describe_s: float, waited: float, bar: Progress) -> None:
        with self._interrupts.protected():
            c = self.counters
            failures = int(rollout.timings.pop("worker_failures", 0))
            episode = c["executed"] if rollout.feasible else None
            descriptor_hex = None if code is None else self.descriptor.hex(code)
            row = attempt_row(cand, rollout, descriptor_hex, evaluation, episode, self.config.explorer, self.task)
            row["timings"] = {k: round(v, 5) for k, v in rollout.timings.items()}
            row["timings"].update(descriptor=round(describe_s, 5), write=0.0, wait_for_batch=round(waited, 5))
            row["worker_failures"] = failures
            self.store.write(AttemptRecord(row, rollout))
            c["worker_failures"] += failures
            c["attempts"] += 1
            if rollout.feasible:
                c["executed"] += 1
                c["contacts"] += int(rollout.touched.any())
            bar.attempt_written()
