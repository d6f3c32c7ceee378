"""The loop a rollout worker process runs (`ProcessEvaluator` spawns it): one World, kept warm, answering the
coordinator's requests over a pipe."""

from __future__ import annotations

import os
import signal
import sys
import traceback
from collections.abc import Iterator

from babblegen.evaluation import Describe, Prepare, render_and_prepare_stepwise, seeded_rollout, warm_up
from babblegen.fingerprint import fingerprint
from babblegen.tasks import get_task
from babblegen.world.rollout import Rollout
from babblegen.world.settings import WorldSettings
from babblegen.world.world import World

# How long a worker with episodes to prepare waits for its next rollout when more are queued, before it prepares
# one (the coordinator answers a returned rollout with the next request in milliseconds).
NEXT_REQUEST_GRACE_S = 0.05
_DONE = object()


def worker_main(
    conn, task_name: str, settings: WorldSettings, run_seed: int, prepare: Prepare | None, describe: Describe | None
) -> None:
    """Build a World once, then answer requests until told to stop (``None``) or the coordinator is gone:

    - ``("run", attempt, command, more)``: simulate and describe (``describe``: the behaviour code of the after
      image); the rollout goes back at once (a Python error is sent back instead: the coordinator replaces this
      worker and retries, as for a crash);
    - ``("prepare", attempt, rollout)``: prepare a rollout another worker simulated;
    - ``("forget", attempt)``: another worker prepares this one.

    With ``prepare`` (encoding the episode), a rollout goes back with only its first and last frames rendered
    (`World.rollout`'s ``defer_render``); rendering the others and preparing the episode wait until no request
    is pending, pause every few frames for one that arrives, and go back as a ``"prepared"`` message. The
    movements, which the search waits for, come first; rendering and encoding fill the time a worker would
    otherwise wait for the others. ``more`` says whether rollouts are queued behind this one, so whether the next
    request is about to arrive.

    The process ends with ``os._exit``: the interpreter's teardown would print the bindings' reference-leak
    reports, and a coordinator that is gone (its pipe closed: a crash, a full disk) is no error of this process's
    to print a traceback for.
    """
    # Ctrl-C in a terminal, `timeout` and batch schedulers signal the whole process group: the coordinator stops
    # the run and then the workers (both signals are blocked already: `babblegen.interrupts.spawning`)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    code = 0
    try:
        _serve(conn, task_name, settings, run_seed, prepare, describe)
    except (EOFError, ConnectionError, BrokenPipeError):
        pass  # the coordinator is gone: nothing to answer, nobody to tell
    except BaseException:
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _serve(
    conn, task_name: str, settings: WorldSettings, run_seed: int, prepare: Prepare | None, describe: Describe | None
) -> None:
    os.environ.setdefault("LP_NUM_THREADS", "1")  # one rendering thread per worker process
    import torch

    torch.set_num_threads(1)  # one core per worker: idle torch threads would spin against the other processes
    world = World(get_task(task_name), settings, seed=run_seed)
    try:
        warm_up(world, prepare)
        conn.send(("ready", fingerprint(world)))
        pending: dict[int, Rollout] = {}  # to render and prepare here (simulated here or handed over), in order
        work: tuple[int, Rollout, Iterator[None]] | None = None  # the preparation under way, and its steps
        more = False
        while True:
            if (work or pending) and not conn.poll(NEXT_REQUEST_GRACE_S if more else 0.0):
                more = False  # (no request came: the queued rollouts went to other workers)
                if work is None:
                    attempt = next(iter(pending))
                    rollout = pending.pop(attempt)
                    work = (attempt, rollout, render_and_prepare_stepwise(world, rollout, prepare))
                attempt, rollout, steps = work
                if next(steps, _DONE) is _DONE:
                    timings = {k: rollout.timings[k] for k in ("render", "prepare") if k in rollout.timings}
                    conn.send(("prepared", (attempt, rollout.prepared, timings)))
                    work = None
                continue
            msg = conn.recv()
            if msg is None:
                return
            kind, attempt, *rest = msg
            if kind == "forget":
                pending.pop(attempt, None)
                if work is not None and work[0] == attempt:
                    work = None
                continue
            if kind == "prepare":
                pending[attempt] = rest[0]
                continue
            command, more = rest
            try:
                rollout = seeded_rollout(
                    world, command, run_seed, attempt, defer_render=prepare is not None, describe=describe
                )
            except Exception:
                conn.send(("error", traceback.format_exc(limit=-3)))
                continue
            conn.send(("ok", rollout))
            if prepare is not None and rollout.feasible:
                pending[attempt] = rollout
    finally:
        world.close()
