"""Parallel rollouts: the same seed gives the same dataset with 1 worker, 2 worker processes or Ray actors,
and a worker that dies mid-run is replaced without losing or changing anything."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import time

import numpy as np
import pytest

from babblegen.cli import main
from babblegen.dataset.lerobot import load_dataset
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.evaluation import LocalEvaluator, Preparers
from babblegen.parallel import ProcessEvaluator, RayEvaluator
from babblegen.tasks import get_task
from babblegen.world.rollout import Command
from babblegen.world.world import WorldSettings

# generations overlap (lag 2: three in flight), so workers take movements of several generations at once, and the
# results must still be applied in attempt order
BASE = ["--max-attempts", "40", "--checkpoint-every", "1", "--width", "64", "--height", "64", "--no-progress"]
BASE += ["--children", "8", "--lag", "2"]
ARGS = [*BASE, "--starts", "fixed"]
SETTINGS = WorldSettings(camera_width=64, camera_height=64)
# numpy without its AVX-512 code, as on a CPU without it (benchmarks/check_dispatch.py)
NO_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
# lavapipe as on a CPU with AVX2 and FMA but not AVX-512 (Mesa's "avx" override clears AVX-512 alone): other
# JIT-compiled shader code, the same pixels. As on a CPU without AVX ("sse4.1": no AVX, AVX2 or FMA) it renders a
# pixel in a few hundred frames one level apart, which is why the promise is AVX2 with FMA (docs/reproducibility.md;
# benchmarks/check_render_dispatch.py measures it).
LAVAPIPE_NO_AVX512 = {"GALLIUM_OVERRIDE_CPU_CAPS": "avx"}


def comparable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("timings", "worker_failures")} for r in rows]


def assert_same_dataset(a, b) -> None:
    assert comparable(read_attempts(a)) == comparable(read_attempts(b))
    da, db = load_dataset(a, read_run_info(a)["repo_id"]), load_dataset(b, read_run_info(b)["repo_id"])
    assert da.meta.total_episodes == db.meta.total_episodes > 0
    for key in ("observation.state", "action", "observation.ee_pos", "observation.environment_state"):
        np.testing.assert_array_equal(da.hf_dataset[key], db.hf_dataset[key])
    # the same pixels, encoded the same way: worker processes render most frames after the movement
    videos_a, videos_b = video_digests(a), video_digests(b)
    assert videos_a == videos_b and len(videos_a) > 0
    # the data tables too, byte for byte: they hold the instance masks (PNG); and the metadata
    tables_a, tables_b = digests(a, "data/**/*.parquet"), digests(b, "data/**/*.parquet")
    assert tables_a == tables_b and len(tables_a) > 0
    assert digests(a, "meta/**/*") == digests(b, "meta/**/*")


def video_digests(root) -> dict[str, str]:
    return digests(root, "videos/**/*.mp4")


def digests(root, pattern: str) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.glob(pattern) if p.is_file()
    }


@pytest.fixture(scope="module")
def one_worker(tmp_path_factory):
    out = tmp_path_factory.mktemp("par") / "one"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "1", *ARGS]) == 0
    return out


def test_two_workers_write_the_same_dataset_as_one(one_worker, tmp_path):
    out = tmp_path / "two"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "2", *ARGS]) == 0
    assert_same_dataset(one_worker, out)
    assert read_run_info(out)["config"]["workers"] == 2
    # contact-rich: each worker's world saw a different contact history than the single world did
    touched = [any(r["touched"].values()) for r in read_attempts(out) if r["feasible"]]
    assert sum(touched) >= 5 and any(a and b for a, b in zip(touched, touched[1:], strict=False)), touched


def test_every_camera_and_kind_is_the_same_with_two_workers_as_with_one(tmp_path):
    """Head, front and wrist cameras, colour, depth and masks: every frame between the first and last is rendered
    after the movement, on whichever worker is free, and encoded there after whatever that worker encoded before
    (x264's and x265's output depended on that at 64 pixels: `lerobot_codecs`)."""
    views = ["--cameras", "head,front,wrist", "--depth", "--segmentation", "--max-attempts", "16"]
    runs = {}
    for workers in ("1", "2"):
        runs[workers] = tmp_path / f"w{workers}"
        assert main(["generate", "--out", str(runs[workers]), "--seed", "2", "--workers", workers, *ARGS, *views]) == 0
    assert_same_dataset(runs["1"], runs["2"])
    keys = {path.split("/")[1] for path in video_digests(runs["2"])}  # videos/<feature>/chunk-*/file-*.mp4
    cameras = ("head", "front", "wrist")
    assert keys == {f"observation.images.{c}{kind}" for c in cameras for kind in ("", "_depth")}
    features = load_dataset(runs["2"], read_run_info(runs["2"])["repo_id"]).meta.features
    assert {f"observation.images.{c}_segmentation" for c in cameras} | {"observation.cam2world.wrist"} <= set(features)


def test_four_worker_processes_on_two_cores_write_the_same_dataset_as_one(one_worker, tmp_path):
    """Oversubscribed: four workers share two cores, so movements finish in an order unlike one worker's."""
    out = tmp_path / "four"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "4", *ARGS]) == 0
    assert_same_dataset(one_worker, out)
    generations = [r["generation"] for r in read_attempts(out)]
    assert max(generations) >= 4 and generations == sorted(generations)


def test_kill_9_of_a_run_with_workers_then_resume_writes_the_same_dataset(one_worker, tmp_path):
    out = tmp_path / "killed"
    kill_then_resume(out, ARGS)
    assert_same_dataset(one_worker, out)


def kill_then_resume(out, args: list[str]) -> None:
    """A run with 2 workers killed with SIGKILL (with its workers) past a commit point, then resumed."""
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--seed", "2", "--workers", "2"]
    proc = subprocess.Popen([*cmd, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    rows = out / "babblegen" / "attempts.jsonl"
    deadline = time.time() + 300
    while not (rows.exists() and rows.read_bytes().count(b"\n") >= 20):  # past a commit point, before the end
        assert proc.poll() is None and time.time() < deadline
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)  # the run and its workers, at once
    proc.wait(timeout=60)
    assert main(["generate", "--out", str(out), "--resume", "--workers", "2", "--no-progress"]) == 0


@pytest.mark.parametrize(
    "setting",
    [{"NPY_DISABLE_CPU_FEATURES": NO_AVX512}, LAVAPIPE_NO_AVX512],
    ids=["numpy_without_avx512", "lavapipe_without_avx512"],
)
def test_another_cpu_dispatch_writes_the_same_dataset(one_worker, tmp_path, setting):
    """numpy picks SIMD code by CPU, and lavapipe compiles its shaders for it: a machine without AVX-512 records the
    same values, since the world's arithmetic is elementwise (babblegen.world.exact) and lavapipe's pixels are the
    same with or without AVX-512. (OpenBLAS's own kernel
    choice is checked by hand, benchmarks/check_dispatch.py: tests leave OPENBLAS_CORETYPE as the machine sets
    it.)"""
    import subprocess
    import sys

    out = tmp_path / "other-dispatch"
    env = {**os.environ, **setting}  # as benchmarks/check_dispatch.py
    cmd = [sys.executable, "-m", "babblegen.cli", "generate", "--out", str(out), "--seed", "2", "--workers", "1"]
    done = subprocess.run([*cmd, *ARGS], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert_same_dataset(one_worker, out)


VARIED = [*BASE, "--starts", "varied"]


@pytest.fixture(scope="module")
def one_worker_varied(tmp_path_factory):
    out = tmp_path_factory.mktemp("par") / "one-varied"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "1", *VARIED]) == 0
    rows = [r for r in read_attempts(out) if r["feasible"]]
    assert len({json.dumps(r["start_poses"]) for r in rows}) >= len(rows) // 3, "many starts"
    assert {r["start"]["source"] for r in rows} == {"drawn", "inherited"}
    return out


def test_a_varied_start_dataset_records_each_start_where_its_episode_begins(one_worker_varied):
    out = one_worker_varied
    rows = [r for r in read_attempts(out) if r["feasible"]]
    ds = load_dataset(out, read_run_info(out)["repo_id"])
    episode = np.asarray(ds.hf_dataset["episode_index"])
    env = np.asarray(ds.hf_dataset["observation.environment_state"]).reshape(len(episode), -1, 7)
    names = read_run_info(out)["object_names"]
    for r in rows:
        first = np.flatnonzero(episode == r["episode_index"])[0]
        np.testing.assert_allclose(env[first], [r["start_poses"][n] for n in names], atol=2e-6)
        if r["start"]["source"] in ("drawn", "moved"):
            assert r["start"]["drawn_at"] == r["attempt"]
        else:  # inherited from its parent, which ran from it
            parent = next(p for p in read_attempts(out) if p["attempt"] == r["parent"])
            assert parent["start"]["drawn_at"] == r["start"]["drawn_at"]
    card = (out / "README.md").read_text()
    assert "varied: each start is a layout" in card
    assert read_run_info(out)["config"]["descriptor"] == "change16"


def test_varied_starts_with_four_worker_processes_write_the_same_dataset_as_one(one_worker_varied, tmp_path):
    out = tmp_path / "four-varied"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "4", *VARIED]) == 0
    assert_same_dataset(one_worker_varied, out)


def test_varied_starts_killed_then_resumed_write_the_same_dataset(one_worker_varied, tmp_path):
    out = tmp_path / "killed-varied"
    kill_then_resume(out, VARIED)
    assert_same_dataset(one_worker_varied, out)
    assert read_run_info(out)["config"]["world"]["starts"] == "varied"


# children that start from the scene their parent's movement left, and children drawn independently of the parents;
# every new start draws its own five objects
MADE = [*VARIED, "--start-from-end", "0.5", "--independent-share", "0.25", "--objects", "varied", "--num-objects", "5"]


@pytest.fixture(scope="module")
def one_worker_made(tmp_path_factory):
    out = tmp_path_factory.mktemp("par") / "one-made"
    assert main(["generate", "--out", str(out), "--seed", "2", "--workers", "1", *MADE]) == 0
    rows = [r for r in read_attempts(out) if r["feasible"]]
    assert "made" in {r["start"]["source"] for r in rows}
    assert any(r["parent"] is None and r["generation"] > 0 for r in rows), "independent children"
    by_attempt = {r["attempt"]: r for r in read_attempts(out)}
    assert len({json.dumps(r["objects"]) for r in rows}) >= 5, "starts draw their own objects"
    for r in rows:
        assert len(r["objects"]) == 5
        if r["start"]["source"] == "made":  # the scene an attempt left, with that attempt's objects
            assert r["objects"] == by_attempt[r["start"]["made_from"]]["objects"]
        if r["start"]["source"] == "inherited":
            assert r["objects"] == by_attempt[r["parent"]]["objects"]
    return out


def test_made_starts_are_the_same_with_four_workers_after_kill_9_and_when_verified(one_worker_made, tmp_path):
    """A made start is the scene an earlier attempt left, as its sidecar row records it: the same with 4 worker
    processes, after kill -9 and --resume (which reads those scenes back from the sidecar), and re-simulated."""
    four = tmp_path / "four-made"
    assert main(["generate", "--out", str(four), "--seed", "2", "--workers", "4", *MADE]) == 0
    assert_same_dataset(one_worker_made, four)
    killed = tmp_path / "killed-made"
    kill_then_resume(killed, MADE)
    assert_same_dataset(one_worker_made, killed)
    assert main(["verify", str(one_worker_made), "--episodes", "0"]) == 0


def test_ray_auto_starts_a_local_cluster_and_writes_the_same_dataset(one_worker, tmp_path):
    ray = pytest.importorskip("ray")
    assert not ray.is_initialized()
    out = tmp_path / "ray"
    try:
        assert main(["generate", "--out", str(out), "--seed", "2", "--ray", "auto", "--workers", "2", *ARGS]) == 0
        assert not ray.is_initialized(), "the cluster the run started is shut down with it"
    finally:
        ray.shutdown()
    assert_same_dataset(one_worker, out)


@pytest.mark.parametrize("starts", ["fixed", "varied", "made"])
def test_two_ray_nodes_write_the_same_dataset_as_one_worker(
    one_worker, one_worker_varied, one_worker_made, tmp_path, starts
):
    """A real multi-node cluster on this machine: two Ray nodes with one CPU each, so the two rollout actors
    (one CPU each) must run on different nodes; the second node's processes run numpy without its AVX-512 code and
    lavapipe as on a CPU without AVX-512, as a node with another CPU would."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        other_cpu = {"NPY_DISABLE_CPU_FEATURES": NO_AVX512, **LAVAPIPE_NO_AVX512}
        node = cluster.add_node(num_cpus=1, env_vars=other_cpu)
        cluster.wait_for_nodes()
        address = cluster.address
        ray.init(address=address)
        on_node = NodeAffinitySchedulingStrategy(node.node_id, soft=False)
        setting = ray.remote(lambda: {k: os.environ.get(k) for k in other_cpu})
        assert ray.get(setting.options(scheduling_strategy=on_node, num_cpus=1).remote()) == other_cpu
        ray.shutdown()
        out = tmp_path / "two-nodes"
        args = {"fixed": ARGS, "varied": VARIED, "made": MADE}[starts]
        argv = ["generate", "--out", str(out), "--seed", "2", "--ray", address, "--workers", "2", *args]
        assert main(argv) == 0
    finally:
        ray.shutdown()
        cluster.shutdown()
    assert_same_dataset({"fixed": one_worker, "varied": one_worker_varied, "made": one_worker_made}[starts], out)
    assert read_run_info(out)["config"]["ray"] == address


def test_a_ray_node_that_computes_otherwise_is_refused_unless_mixed_machines_are_allowed(tmp_path, capsys):
    """A two-node cluster whose second node's processes compute another fingerprint (as a machine of another kind
    would): the run stops at the start with one line naming that node; allowed, it runs and run.json says mixed."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    from babblegen.fingerprint import SALT_ENV

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        node = cluster.add_node(num_cpus=1, env_vars={SALT_ENV: "another kind of machine"})
        cluster.wait_for_nodes()
        argv = ["generate", "--seed", "2", "--ray", cluster.address, "--workers", "2", *ARGS, "--max-attempts", "8"]
        refused = tmp_path / "refused"
        assert main([argv[0], "--out", str(refused), *argv[1:]]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("babblegen: error: Ray node "), err
        assert f"(node {node.node_id[:12]}) computes differently from this machine" in err[0]
        assert "--allow-mixed-machines" in err[0]
        assert not (refused / "babblegen" / "run.json").exists()
        mixed = tmp_path / "mixed"
        assert main([argv[0], "--out", str(mixed), *argv[1:], "--allow-mixed-machines"]) == 0
    finally:
        ray.shutdown()
        cluster.shutdown()
    record = read_run_info(mixed)["fingerprint"]
    (where, theirs), *more = record["nodes"].items()
    assert record["mixed"] is True and not more
    assert node.node_id[:12] in where and theirs != record["hash"]
    assert read_run_info(mixed)["config"]["allow_mixed_machines"] is True


def _commands(n: int) -> list[Command]:
    rng = np.random.default_rng(7)
    return [Command("ee_waypoints", rng.uniform(0, 1, (1, 3))) for _ in range(n)]


def test_killed_worker_is_replaced_and_its_rollout_retried():
    task = get_task("noveb_tabletop")
    commands, attempts = _commands(6), list(range(100, 106))
    reference = LocalEvaluator(task, SETTINGS, run_seed=9)
    expected = reference.evaluate(commands, attempts)
    reference.close()

    ev = ProcessEvaluator(task, SETTINGS, run_seed=9, n=2)
    try:
        ev.submit(commands, attempts)
        victim = ev.workers[0]
        deadline = time.time() + 60
        while victim.job is None and time.time() < deadline:
            time.sleep(0.01)
        os.kill(victim.process.pid, signal.SIGKILL)
        got = ev.collect()
        assert ev.failures == 1
        assert sum(r.timings["worker_failures"] for r in got) == 1
        assert all(w.process.is_alive() for w in ev.workers)
    finally:
        ev.close()
    for g, e in zip(got, expected, strict=True):
        assert (g.feasible, g.reason) == (e.feasible, e.reason)
        if e.feasible:
            np.testing.assert_array_equal(g.frames.state, e.frames.state)
            np.testing.assert_array_equal(g.final_poses, e.final_poses)


class ImageDigest:
    """An episode preparation that takes ``seconds`` (long enough for a test to kill the worker in the middle of
    it); its result is the number of frames and a digest of their pixels."""

    def __init__(self, seconds: float):
        self.seconds = seconds

    def __call__(self, frames) -> tuple[int, str]:
        time.sleep(self.seconds)
        return len(frames.images), hashlib.sha256(frames.images.tobytes()).hexdigest()


def test_episodes_are_rendered_and_prepared_after_the_batch_and_by_a_replacement_if_their_worker_dies():
    task, commands, attempts = get_task("noveb_tabletop"), _commands(6), list(range(6))
    reference = LocalEvaluator(task, SETTINGS, run_seed=9, prepare=Preparers({"n": ImageDigest(0)}))
    inline = dict(zip(attempts, reference.evaluate(commands, attempts), strict=True))
    reference.close()

    ev = ProcessEvaluator(task, SETTINGS, 9, n=2, prepare=Preparers({"n": ImageDigest(2)}))
    try:
        t = time.perf_counter()
        rollouts = ev.evaluate(commands, attempts)
        executed = [(r, a) for r, a in zip(rollouts, attempts, strict=True) if r.feasible]
        assert len(executed) >= 3
        assert not any(ev.attach_prepared(r, a, wait=False) for r, a in executed), "preparations come later"
        assert all(r.frames.images is None and len(r.frames.end_images) == 2 for r, _ in executed)
        assert all(np.array_equal(r.after_image, inline[a].after_image) for r, a in executed)
        os.kill(ev.workers[0].process.pid, signal.SIGKILL)  # it owes preparations
        for r, a in executed:
            assert ev.attach_prepared(r, a, wait=True)
            assert r.prepared == inline[a].prepared, "the same pixels as a rollout rendered in one go"
            assert r.timings["prepare"] >= 2 and r.timings["render"] > 0
        assert ev.failures == 1 and all(w.process.is_alive() for w in ev.workers)
        assert time.perf_counter() - t < 2 * len(executed) + 60
    finally:
        ev.close()


def test_ray_actor_killed_mid_batch_is_replaced():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        ev = RayEvaluator(get_task("noveb_tabletop"), SETTINGS, run_seed=9, address="auto", n=2)
        commands, attempts = _commands(4), list(range(4))
        ev.submit(commands, attempts)
        ray.kill(ev.actors[0])
        got = ev.collect()
        assert len(got) == 4 and ev.failures >= 1
        ev.close()
    finally:
        ray.shutdown()


def test_an_error_in_a_worker_process_is_retried_on_fresh_workers_then_reported():
    ev = ProcessEvaluator(get_task("noveb_tabletop"), SETTINGS, run_seed=9, n=2, retries=1)
    try:
        good = _commands(2)
        with pytest.raises(RuntimeError, match=r"(?s)attempt 7 failed on 2 worker process.*unknown command kind"):
            ev.evaluate([good[0], Command("no_such_kind", np.zeros((1, 3))), good[1]], [6, 7, 8])
        assert ev.failures == 2, "one failure, then one retry on a fresh worker"
        assert all(w.process.is_alive() for w in ev.workers)
        assert len(ev.evaluate(good, [10, 11])) == 2, "the pool still works"
    finally:
        ev.close()


def test_an_error_in_a_ray_actor_follows_the_same_policy():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        ev = RayEvaluator(get_task("noveb_tabletop"), SETTINGS, run_seed=9, address="auto", n=1, retries=1)
        with pytest.raises(RuntimeError, match=r"(?s)attempt 3 failed on 2 Ray actors.*unknown command kind"):
            ev.evaluate([Command("no_such_kind", np.zeros((1, 3)))], [3])
        assert ev.failures == 2
        ev.close()
    finally:
        ray.shutdown()


def test_an_episode_prepared_by_its_owner_after_it_was_handed_to_an_idle_worker_is_not_handed_on_again():
    """The coordinator's bookkeeping when two workers race for one preparation: the owner sends it just as the
    coordinator hands it to an idle worker. Workers here are pipes the test answers for."""
    import multiprocessing as mp
    import threading

    from babblegen.parallel.processes import _Worker

    ev = ProcessEvaluator.__new__(ProcessEvaluator)
    ev._arrived, ev._prepared, ev._handed_over = threading.Condition(), {}, {}
    ends = [mp.Pipe() for _ in range(3)]
    ev.workers = [_Worker(process=None, conn=coordinator_end) for coordinator_end, _ in ends]
    owner, thief, third = ev.workers
    rollout = "the rollout of attempt 7"
    owner.owed[7] = None
    ev._unprepared = {7: rollout}

    ev._share_work(busy={0})  # the owner runs a movement: the idle thief takes its preparation over
    assert ends[0][1].recv() == ("forget", 7)
    assert ends[1][1].recv() == ("prepare", 7, rollout) and list(thief.owed) == [7]
    ends[0][1].send(("prepared", (7, {"n": 1}, {"prepare": 0.1})))  # sent before the owner read its "forget"
    assert ev._receive(owner) is None
    assert ev._prepared == {7: ({"n": 1}, {"prepare": 0.1})} and ev._unprepared == {}
    assert thief.owed == {} and ends[1][1].recv() == ("forget", 7)
    ev._share_work(busy={1})  # the thief runs a movement now, the third worker is idle: nothing to hand over
    assert not ends[2][1].poll() and third.owed == {}
