"""Rollouts on Ray actors, for more than one machine: one actor per worker slot, each with its own World, under
the same scheduling and failure policy as local processes (`babblegen.parallel.scheduler`).

Every actor computes its machine's fingerprint when it starts (`babblegen.fingerprint`), and the coordinator its
own, in a child process. An actor whose fingerprint differs, at the start or replacing one, stops the run with one
line naming its node, unless the run allows mixed machines; then the run goes on and records the node's.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time

from babblegen.config import ConfigError
from babblegen.evaluation import Describe, Prepare
from babblegen.fingerprint import finish_subprocess, start_in_subprocess
from babblegen.parallel.scheduler import Failure, PoolEvaluator
from babblegen.scene import TaskSpec
from babblegen.world.rollout import Command, Rollout
from babblegen.world.settings import WorldSettings

log = logging.getLogger(__name__)


class RayEvaluator(PoolEvaluator):
    """One Ray actor per worker slot, each with its own World; same scheduling and failure policy."""

    kind = "Ray actor"
    poll_seconds = 0.02  # nothing wakes `ray.wait` when work is submitted: look again this often

    def __init__(
        self,
        task: TaskSpec,
        settings: WorldSettings,
        run_seed: int,
        address: str,
        n: int | None = None,
        timeout: float = 300.0,
        retries: int = 2,
        prepare: Prepare | None = None,
        describe: Describe | None = None,
        allow_mixed: bool = False,
    ):
        import ray  # an optional dependency

        self.ray = ray
        self.allow_mixed, self.other_machines = allow_mixed, {}
        computing = start_in_subprocess(task.name, settings)  # while the actors start
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            options = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
            try:
                ray.init(address=None if address == "local" else address, **options)
            except ConnectionError:
                if address != "auto":
                    computing.kill()
                    raise ConfigError(f"--ray {address}: no Ray cluster there") from None
                log.info("no running Ray cluster; starting a local one")
                ray.init(address=None, **options)
        n = n or max(int(ray.cluster_resources().get("CPU", 1)), 1)
        super().__init__(n, timeout, retries)

        @ray.remote(num_cpus=1, max_restarts=0)
        class RolloutActor:
            def __init__(
                self,
                task_name: str,
                settings: WorldSettings,
                run_seed: int,
                prepare: Prepare | None,
                describe: Describe | None,
            ):
                os.environ.setdefault("LP_NUM_THREADS", "1")
                import torch

                torch.set_num_threads(1)
                from babblegen.evaluation import warm_up
                from babblegen.fingerprint import fingerprint
                from babblegen.tasks import get_task
                from babblegen.world.world import World

                self.world = World(get_task(task_name), settings, seed=run_seed)
                warm_up(self.world, prepare)
                self.run_seed, self.prepare, self.describe = run_seed, prepare, describe
                self.fingerprint = fingerprint(self.world)
                context = ray.get_runtime_context()
                self.node = f"{ray.util.get_node_ip_address()} (node {context.get_node_id()[:12]})"

            def ping(self) -> tuple[str, str]:
                """Its node, and its fingerprint there."""
                return self.node, self.fingerprint

            def rollout(self, attempt: int, command: Command) -> Rollout:
                from babblegen.evaluation import seeded_rollout

                return seeded_rollout(self.world, command, self.run_seed, attempt, self.prepare, describe=self.describe)

        self._actor_cls = RolloutActor
        self._args = (task.name, settings, run_seed, prepare, describe)
        self.actors = [self._actor_cls.remote(*self._args) for _ in range(n)]
        try:
            self.fingerprint = finish_subprocess(computing)
            for node, fingerprint in ray.get([a.ping.remote() for a in self.actors]):
                self._admit(node, fingerprint)
        except BaseException:
            computing.kill()
            self._stop_actors()
            raise
        self._refs: dict[int, object] = {}

    def _admit(self, node: str, fingerprint: str) -> None:
        """Refuse an actor whose machine computes differently from this one, unless mixed machines are allowed
        (then remember its node)."""
        if fingerprint == self.fingerprint:
            return
        if not self.allow_mixed:
            raise ConfigError(
                f"Ray node {node} computes differently from this machine (fingerprint {fingerprint}, here "
                f"{self.fingerprint}), so the dataset would depend on which node ran which movement; use machines "
                "of one kind, or allow it with --allow-mixed-machines (run.json then records the run as mixed)"
            )
        if node not in self.other_machines:
            log.warning("Ray node %s computes differently from this machine; the run is mixed", node)
            self.other_machines = {**self.other_machines, node: fingerprint}

    def _send(self, slot: int, attempt: int, command: Command, more: bool) -> None:
        self._refs[slot] = self.actors[slot].rollout.remote(attempt, command)

    def _wait(self, busy: list[int], timeout: float) -> list[tuple[int, Rollout | Failure]]:
        ray = self.ray
        refs = {self._refs[s]: s for s in busy}
        if not refs:
            time.sleep(min(timeout, 0.05))
            return []
        ready, _ = ray.wait(list(refs), num_returns=1, timeout=timeout)
        if ready:  # and whatever else has finished meanwhile
            ready, _ = ray.wait(list(refs), num_returns=len(refs), timeout=0)
        out: list[tuple[int, Rollout | Failure]] = []
        for ref in ready:
            slot = refs[ref]
            del self._refs[slot]
            try:
                out.append((slot, ray.get(ref)))
            except ray.exceptions.RayActorError as e:
                out.append((slot, Failure(f"died ({type(e).__name__})")))
            except ray.exceptions.RayTaskError as e:
                out.append((slot, Failure(f"raised an error:\n{e}")))
        return out

    def _replace(self, slot: int) -> None:
        self._refs.pop(slot, None)
        self.ray.kill(self.actors[slot])
        self.actors[slot] = self._actor_cls.remote(*self._args)
        # (one that dies starting fails its first rollout, and the failure policy replaces it)
        with contextlib.suppress(self.ray.exceptions.RayActorError):
            self._admit(*self.ray.get(self.actors[slot].ping.remote()))

    def _stop_actors(self) -> None:
        for a in self.actors:
            self.ray.kill(a)
        if self._owns_ray:
            self.ray.shutdown()

    def close(self) -> None:
        self._stop_dispatch()
        self._stop_actors()
