"""Rerun recordings: the run's segments and `babblegen view` files load back through Rerun's own Python API,
hold the expected entities and timelines, agree with the LeRobot dataset, and the run's sink survives crashes
(rollback) and its own failures (disabled with a warning, the run goes on)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from babblegen.cli import main
from babblegen.dataset.lerobot import load_dataset
from babblegen.dataset.sidecar import read_attempts, read_run_info
from babblegen.exporters.rerun import INDEX, RerunSink, recording_files
from babblegen.tasks.pr2_arm import ARM_JOINTS
from babblegen.world.rollout import Command, Frames, Rollout

TIMELINES = {"frame_index", "timestamp", "index", "episode_index", "attempt"}
RERUN_CLI = Path(sys.executable).parent / "rerun"


def read_recording(*paths: Path) -> dict[str, list[tuple[bool, pa.RecordBatch]]]:
    """Every chunk of the recording stores in `paths`, by entity: (is_static, record batch)."""
    out: dict[str, list[tuple[bool, pa.RecordBatch]]] = defaultdict(list)
    for p in paths:
        for chunk in RrdReader(p).stream():
            out[chunk.entity_path].append((chunk.is_static, chunk.to_record_batch()))
    return out


def temporal(chunks, entity: str, component: str, order_by: str = "index") -> tuple[np.ndarray, list]:
    """A component's values over all temporal chunks of an entity, sorted by a timeline."""
    times, values = [], []
    for static, batch in chunks[entity]:
        if static or component not in batch.schema.names:
            continue
        times += batch.column(order_by).to_pylist()
        values += batch.column(component).to_pylist()
    order = np.argsort(times, kind="stable")
    return np.asarray(times)[order], [values[i] for i in order]


def dataset_columns(root: Path) -> dict[str, np.ndarray]:
    ds = load_dataset(root, read_run_info(root)["repo_id"])
    table = ds.hf_dataset.with_format("arrow")[:]
    cols = {}
    for name in ("observation.ee_pos", "observation.contacts", "index", "episode_index", "frame_index"):
        arr = table.column(name).combine_chunks()
        cols[name] = np.asarray(arr.to_pylist())
    cols["total_episodes"] = np.asarray(ds.meta.total_episodes)
    return cols


@pytest.fixture(scope="module")
def data(small_noveb_dataset) -> dict[str, np.ndarray]:
    return dataset_columns(small_noveb_dataset)


# --- the run's recording -------------------------------------------------------------------------------------
def test_run_writes_one_verified_segment_per_commit(small_noveb_dataset, data):
    files = recording_files(small_noveb_dataset)
    rows = read_attempts(small_noveb_dataset)
    index = json.loads((small_noveb_dataset / "babblegen" / "rerun" / INDEX).read_text())
    assert len(files) == len({r["generation"] for r in rows}) == len(index["segments"])  # committed every generation
    last = index["segments"][-1]
    assert (last["attempts_end"], last["episodes_end"], last["frames_end"]) == (
        len(rows),
        int(data["total_episodes"]),
        len(data["index"]),
    )
    stores = [RrdReader(p).recordings() for p in files]
    assert all(len(s) == 1 for s in stores)
    assert len({s[0].recording_id for s in stores}) == 1, "segments merge into one recording"
    assert all(RrdReader(p).blueprints() for p in files), "each segment opens on the default layout"
    done = subprocess.run([RERUN_CLI, "rrd", "verify", *files], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_run_recording_has_the_expected_entities_and_timelines(small_noveb_dataset):
    files = recording_files(small_noveb_dataset)
    schema = RrdReader(files[-1]).store().schema()
    assert {c.name for c in schema.index_columns()} == TIMELINES
    entities = {c.entity_path for c in schema.component_columns()}
    names = read_run_info(small_noveb_dataset)["object_names"]
    expected = {
        "/world/table",
        "/world/robot/base/box",
        "/world/robot/arm/box",
        "/world/robot/arm/cylinder",
        "/world/robot/arm/sphere",
        "/world/head_camera",
        "/head_camera/image",
        "/world/tool",
        "/world/tool_path",
        "/world/object_paths",
        "/world/contact_events",
        "/world/start",
        "/contacts",
        "/state",
        "/attempts/novelty",
        "/attempts/archived",
        "/attempts/feasible",
        "/attempts/contacts/total",
        "/attempts/contacts/per_object",
        "/overview/outlines",
        "/overview/final_tool",
        *(f"/world/objects/{n}" for n in names),
        *(f"/overview/final_objects/{n}" for n in names),
    }
    assert expected <= entities, expected - entities
    # the viewer draws an image under a Pinhole black (and as a black quad over the 3D scene): keep them apart
    pinholes = {c.entity_path for c in schema.component_columns() if c.component.startswith("Pinhole:")}
    images = {c.entity_path for c in schema.component_columns() if c.component.startswith("EncodedImage:")}
    assert pinholes and images
    assert not any(i.startswith(p + "/") for i in images for p in pinholes), (pinholes, images)


def episode_ends(data: dict[str, np.ndarray]) -> np.ndarray:
    """Positions (= dataset indices) of every episode's first and last frame."""
    first = np.flatnonzero(data["frame_index"] == 0)
    last = np.append(first[1:] - 1, len(data["index"]) - 1)
    return np.sort(np.concatenate([first, last]))


def test_run_recording_agrees_with_dataset_and_sidecar(small_noveb_dataset, data):
    """The default recording logs each episode's first and last frame (every view) and its whole paths."""
    chunks = read_recording(*recording_files(small_noveb_dataset))
    ends = episode_ends(data)
    index, tool = temporal(chunks, "/world/tool", "Points3D:positions")
    np.testing.assert_array_equal(index, data["index"][ends])
    np.testing.assert_allclose(np.array([p[0] for p in tool]), data["observation.ee_pos"][ends], atol=1e-5)
    _, contacts = temporal(chunks, "/contacts", "Scalars:scalars")
    np.testing.assert_array_equal(np.array(contacts), data["observation.contacts"][ends])
    _, images = temporal(chunks, "/head_camera/image", "EncodedImage:blob")
    assert len(images) == len(ends) and all(bytes(b[0][:2]) == b"\xff\xd8" for b in images), "JPEG"
    _, masks = temporal(chunks, "/head_camera/segmentation", "SegmentationImage:buffer")
    assert len(masks) == len(ends)
    # the tool path is drawn from every frame of its episode
    starts, paths = temporal(chunks, "/world/tool_path", "LineStrips3D:strips")
    np.testing.assert_array_equal(starts, data["index"][data["frame_index"] == 0])
    for start, path in zip(starts, paths, strict=True):
        mine = data["observation.ee_pos"][data["episode_index"] == data["episode_index"][start]]
        np.testing.assert_allclose(np.array(path[0]), mine, atol=1e-5)

    rows = read_attempts(small_noveb_dataset)
    attempts, feasible = temporal(chunks, "/attempts/feasible", "Scalars:scalars", order_by="attempt")
    assert attempts.tolist() == [r["attempt"] for r in rows]
    assert [v[0] for v in feasible] == [float(r["feasible"]) for r in rows]
    _, total = temporal(chunks, "/attempts/contacts/total", "Scalars:scalars", order_by="attempt")
    assert total[-1][0] == sum(any(r["touched"].values()) for r in rows if r["feasible"])
    _, final_tool = temporal(chunks, "/overview/final_tool", "Points3D:positions", order_by="attempt")
    expected = [r["final_ee_pos"] for r in rows if r["feasible"]]
    np.testing.assert_allclose(np.array([p[0] for p in final_tool]), expected, atol=1e-5)


# --- babblegen view --------------------------------------------------------------------------------------------
def test_view_save_writes_a_recording_built_from_the_dataset(small_noveb_dataset, data, tmp_path):
    out = tmp_path / "all.rrd"
    assert main(["view", str(small_noveb_dataset), "--save", str(out)]) == 0
    reader = RrdReader(out)
    assert reader.recordings() and reader.blueprints()
    assert {c.name for c in reader.store().schema().index_columns()} == TIMELINES
    chunks = read_recording(out)
    index, tool = temporal(chunks, "/world/tool", "Points3D:positions")
    np.testing.assert_array_equal(index, data["index"])
    np.testing.assert_allclose(np.array([p[0] for p in tool]), data["observation.ee_pos"], atol=1e-6)
    _, contacts = temporal(chunks, "/contacts", "Scalars:scalars")
    np.testing.assert_array_equal(np.array(contacts), data["observation.contacts"])
    _, images = temporal(chunks, "/head_camera/image", "EncodedImage:blob")
    assert len(images) == len(data["index"])
    # the masks as the dataset holds them (read back from 16-bit PNG, sent as 8-bit ids the viewer draws)
    _, masks = temporal(chunks, "/head_camera/segmentation", "SegmentationImage:buffer")
    stored = load_dataset(small_noveb_dataset, read_run_info(small_noveb_dataset)["repo_id"])
    assert len(masks) == len(data["index"])
    for i in (0, len(masks) - 1):
        want = np.asarray(stored[i]["observation.images.head_segmentation"])[0].astype(np.uint8)
        np.testing.assert_array_equal(np.asarray(masks[i], dtype=np.uint8).reshape(want.shape), want)
    # a finished run's overview is static: every final position, whatever the timeline
    [(static, batch)] = chunks["/overview/final_tool"]
    final = [r["final_ee_pos"] for r in read_attempts(small_noveb_dataset) if r["feasible"]]
    assert static and np.allclose(batch.column("Points3D:positions").to_pylist()[0], final, atol=1e-6)


def test_view_one_episode(small_noveb_dataset, data, tmp_path):
    episode = int(data["total_episodes"]) - 1
    out = tmp_path / "one.rrd"
    assert main(["view", str(small_noveb_dataset), "--episode", str(episode), "--save", str(out)]) == 0
    frames, tool = temporal(read_recording(out), "/world/tool", "Points3D:positions", order_by="frame_index")
    mine = data["episode_index"] == episode
    np.testing.assert_array_equal(frames, data["frame_index"][mine])
    np.testing.assert_allclose(np.array([p[0] for p in tool]), data["observation.ee_pos"][mine], atol=1e-6)


def test_view_without_display_writes_a_file_and_says_where(small_noveb_dataset, tmp_path, monkeypatch, capsys):
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(small_noveb_dataset), str(copy)], check=True)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    assert main(["view", str(copy), "--episode", "0"]) == 0
    written = copy / "babblegen" / "view.rrd"
    assert str(written) in capsys.readouterr().out and RrdReader(written).recordings()


@pytest.mark.parametrize("extra", [[], ["--episode", "100000"]])
def test_view_refuses_what_is_not_there(small_noveb_dataset, tmp_path, capsys, extra):
    target = small_noveb_dataset if extra else tmp_path
    assert main(["view", str(target), *extra, "--save", str(tmp_path / "x.rrd")]) == 2
    assert capsys.readouterr().err.startswith("babblegen: error: ")
    assert not (tmp_path / "x.rrd").exists()


# --- the sink, without a simulator ---------------------------------------------------------------------------
N_OBJ, DOF, T = 4, 7, 6


@pytest.fixture
def sink_dir(tmp_path) -> Path:
    from babblegen.tasks import get_task

    task = get_task("noveb_tabletop")
    (tmp_path / "babblegen").mkdir()
    info = {"config": {"world": {"fps": 10, "camera_height": 16, "camera_width": 16}}, "task": task.to_dict()}
    (tmp_path / "babblegen" / "run.json").write_text(json.dumps(info))
    (tmp_path / "babblegen" / "attempts.jsonl").write_bytes(b"")
    return tmp_path


def fake_attempt(i: int, episode: int | None, rng: np.random.Generator) -> tuple[dict, Rollout]:
    from babblegen.tasks import get_task

    names = get_task("noveb_tabletop").object_names
    row = {"attempt": i, "generation": i // 3, "feasible": episode is not None, "episode_index": episode}
    row.update(novelty=float(i), archived=i % 2 == 0, ee_targets=[[0.7, 0.0, 0.9]])
    cmd = Command("ee_waypoints", np.zeros((1, 3)))
    if episode is None:
        return {**row, "reason": "no_ik"}, Rollout(cmd, False, "no_ik")
    poses = np.tile([0.7, 0.0, 0.75, 1.0, 0.0, 0.0, 0.0], (T, N_OBJ, 1))
    contacts = np.zeros((T, N_OBJ))
    contacts[2, i % N_OBJ] = 1
    frames = Frames(
        state=rng.uniform(-1, 0, (T, DOF)),
        action=np.zeros((T, DOF)),
        ee_pos=rng.uniform(0, 1, (T, 3)),
        object_poses=poses,
        contacts=contacts,
        images=rng.integers(0, 255, (T, 16, 16, 3), dtype=np.uint8),
    )
    row.update(
        reason="",
        n_frames=T,
        touched={n: bool(contacts[:, j].any()) for j, n in enumerate(names)},
        final_poses={n: poses[-1, j].tolist() for j, n in enumerate(names)},
        final_ee_pos=[0.7, 0.0, 0.9],
    )
    return row, Rollout(cmd, True, ee_targets=np.array([[0.7, 0.0, 0.9]]), frames=frames)


def append_rows(root: Path, rows: list[dict]) -> None:
    with open(root / "babblegen" / "attempts.jsonl", "a") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")


def new_sink(root: Path) -> RerunSink:
    from babblegen.tasks import get_task

    task = get_task("noveb_tabletop")
    return RerunSink(root, task, list(ARM_JOINTS))


def test_sink_rollback_drops_what_came_after_the_last_commit(sink_dir):
    rng = np.random.default_rng(0)
    attempts = [fake_attempt(0, 0, rng), fake_attempt(1, None, rng), fake_attempt(2, 1, rng)]
    sink = new_sink(sink_dir)
    for row, rollout in attempts:
        sink.log(row, rollout)
    append_rows(sink_dir, [row for row, _ in attempts])
    sink.flush()  # commit point: 3 attempts, 2 episodes
    for row, rollout in [fake_attempt(3, 2, rng), fake_attempt(4, 3, rng)]:
        sink.log(row, rollout)
        append_rows(sink_dir, [row])
    sink.flush()  # closed, but the process dies before its checkpoint is written
    sink.log(*fake_attempt(5, 4, rng))  # and a segment that was still open
    (sink_dir / "babblegen" / "rerun" / "segment-00009.rrd").write_bytes(b"torn")
    assert sink.enabled

    rows = read_attempts(sink_dir)[:3]  # what resume truncates the table to
    (sink_dir / "babblegen" / "attempts.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    resumed = new_sink(sink_dir)
    resumed.rollback(2)
    rerun_dir = sink_dir / "babblegen" / "rerun"
    assert sorted(p.name for p in rerun_dir.glob("*.rrd")) == ["segment-00000.rrd"]
    again = fake_attempt(3, 2, rng)
    resumed.log(*again)
    resumed.close()
    files = recording_files(sink_dir)
    assert [p.name for p in files] == ["segment-00000.rrd", "segment-00001.rrd"]
    index, _ = temporal(read_recording(*files), "/world/tool", "Points3D:positions")
    assert index.tolist() == list(range(3 * T)), "the dataset-wide frame index continues after the rollback"
    _, total = temporal(read_recording(*files), "/attempts/contacts/total", "Scalars:scalars", order_by="attempt")
    assert [v[0] for v in total] == [1.0, 1.0, 2.0, 3.0]


def test_sink_logs_each_episodes_start_once(sink_dir):
    """The objects' frame-0 poses as labelled boxes at `world/start`: sizes static, one pose per object per
    episode at its first frame (not per frame)."""
    from babblegen.tasks import get_task

    rng = np.random.default_rng(3)
    sink = new_sink(sink_dir)
    starts = []
    for i, episode in enumerate([0, None, 1]):
        row, rollout = fake_attempt(i, episode, rng)
        if episode is not None:
            rollout.frames.object_poses[0, :, :2] = rng.uniform(0.4, 0.9, (N_OBJ, 2))
            starts.append(rollout.frames.object_poses[0, :, :3].copy())
        sink.log(row, rollout)
    sink.close()
    chunks = read_recording(*recording_files(sink_dir))
    [(static, batch)] = [c for c in chunks["/world/start"] if c[0]]
    assert batch.column("Boxes3D:labels").to_pylist()[0] == get_task("noveb_tabletop").object_names
    index, centers = temporal(chunks, "/world/start", "Boxes3D:centers")
    assert index.tolist() == [0, T], "one row per episode, at its first frame"
    np.testing.assert_allclose(np.array(centers), np.stack(starts), atol=1e-6)


def test_sink_failure_warns_once_and_disables_it(sink_dir):
    rng = np.random.default_rng(1)
    sink = new_sink(sink_dir)
    row, rollout = fake_attempt(0, 0, rng)
    rollout.frames.state = rollout.frames.state[:, :3]  # wrong shape: logging it fails
    with pytest.warns(RuntimeWarning, match="Rerun recording stopped"):
        sink.log(row, rollout)
    assert not sink.enabled
    sink.log(*fake_attempt(1, 1, rng))  # no-ops from now on, no second warning, no exception
    sink.flush()
    sink.close()


def test_sink_lets_an_interruption_through(sink_dir, monkeypatch):
    from babblegen.exporters.rerun import columns
    from babblegen.interrupts import Interrupted

    def interrupted(*_args, **_kwargs):
        raise Interrupted("SIGTERM")

    monkeypatch.setattr(columns.EpisodeColumns, "add", interrupted)
    sink = new_sink(sink_dir)
    with pytest.raises(Interrupted):
        sink.log(*fake_attempt(0, 0, np.random.default_rng(2)))
    assert sink.enabled
    sink.close()
    segment = json.loads((sink_dir / "babblegen" / "rerun" / INDEX).read_text())["segments"][0]
    assert segment["attempts_end"] == 1, "a segment cut mid-attempt covers that attempt, so resume drops it"


def test_sink_ends_logs_first_and_last_frames_and_whole_paths(sink_dir, tmp_path):
    """`frames="ends"` (a run's default): per episode, every view at frames 0 and T - 1 only, the paths from all
    T frames; a fraction of the bytes of `frames="all"` for the same episodes."""
    from babblegen.tasks import get_task

    task = get_task("noveb_tabletop")
    all_dir = tmp_path / "all"
    shutil.copytree(sink_dir, all_dir)
    rng = np.random.default_rng(4)
    attempts = [fake_attempt(i, i, rng) for i in range(3)]
    for root, frames in ((sink_dir, "ends"), (all_dir, "all")):
        sink = RerunSink(root, task, list(ARM_JOINTS), frames=frames)
        for row, rollout in attempts:
            sink.log(row, rollout)
        sink.close()
    ends = read_recording(*recording_files(sink_dir))
    index, tool = temporal(ends, "/world/tool", "Points3D:positions")
    assert index.tolist() == [0, T - 1, T, 2 * T - 1, 2 * T, 3 * T - 1]
    want = np.concatenate([r.frames.ee_pos[[0, -1]] for _, r in attempts])
    np.testing.assert_allclose(np.array([p[0] for p in tool]), want, atol=1e-6)
    image_index, images = temporal(ends, "/head_camera/image", "EncodedImage:blob")
    assert image_index.tolist() == index.tolist() and all(bytes(b[0][:2]) == b"\xff\xd8" for b in images)
    _, paths = temporal(ends, "/world/tool_path", "LineStrips3D:strips")
    for (_, rollout), path in zip(attempts, paths, strict=True):
        np.testing.assert_allclose(np.array(path[0]), rollout.frames.ee_pos, atol=1e-6)
    full_index, _ = temporal(read_recording(*recording_files(all_dir)), "/world/tool", "Points3D:positions")
    assert full_index.tolist() == list(range(3 * T))
    size = {d: sum(p.stat().st_size for p in recording_files(d)) for d in (sink_dir, all_dir)}
    assert size[sink_dir] < size[all_dir]


def test_unknown_recording_frames_are_refused(tmp_path):
    from babblegen.exporters.rerun.columns import JpegFrames, logged_frames

    with pytest.raises(ValueError, match="unknown recording frames"):
        logged_frames(5, "middle")
    with pytest.raises(ValueError):
        JpegFrames(frames="middle")
    assert logged_frames(5, "ends").tolist() == [0, 4] and logged_frames(2, "ends").tolist() == [0, 1]
    from babblegen.config import ConfigError, RunConfig

    with pytest.raises(ConfigError, match="rerun_frames"):
        RunConfig.from_dict({"rerun_frames": "middle"}).validate()
    with pytest.raises(SystemExit) as exit_info:
        main(["generate", "--out", str(tmp_path / "x"), "--rerun-frames", "middle"])
    assert exit_info.value.code == 2 and not (tmp_path / "x").exists()


# --- objects drawn per start -------------------------------------------------------------------------------------
def drawn_sink_dir(root: Path, count: int) -> tuple[Path, object]:
    """A run folder like `sink_dir`'s for a run that draws ``count`` objects per start (``--objects varied``)."""
    from babblegen.objects import slot_task
    from babblegen.tasks import get_task

    task = slot_task(get_task("noveb_tabletop"), "varied", count)
    (root / "babblegen").mkdir(parents=True)
    world = {"fps": 10, "camera_height": 16, "camera_width": 16, "objects": "varied", "num_objects": count}
    info = {"config": {"world": world}, "task": task.to_dict()}
    (root / "babblegen" / "run.json").write_text(json.dumps(info))
    (root / "babblegen" / "attempts.jsonl").write_bytes(b"")
    return root, task


def factors(name: str, shape: str, size: list[float], color: list[float], **extra) -> dict:
    return {"name": name, "shape": shape, "size": size, "mass": 0.1, "density": 100.0, "static_friction": 0.5,
            "dynamic_friction": 0.4, "restitution": 0.1, "color": color, **extra}  # fmt: skip


def drawn_attempt(i: int, objects: list[dict], rng: np.random.Generator) -> tuple[dict, Rollout]:
    """An executed attempt (episode ``i``) of a run whose start brought ``objects``."""
    n = len(objects)
    names = [o["name"] for o in objects]
    row = {"attempt": i, "generation": i, "feasible": True, "episode_index": i, "objects": objects}
    poses = np.tile([0.8, 0.1 * i, 0.75, 1.0, 0.0, 0.0, 0.0], (T, n, 1))
    frames = Frames(
        state=rng.uniform(-1, 0, (T, DOF)),
        action=np.zeros((T, DOF)),
        ee_pos=rng.uniform(0, 1, (T, 3)),
        object_poses=poses,
        contacts=np.zeros((T, n)),
        images=rng.integers(0, 255, (T, 16, 16, 3), dtype=np.uint8),
    )
    row.update(
        reason="",
        n_frames=T,
        novelty=1.0,
        archived=True,
        ee_targets=[[0.7, 0.0, 0.9]],
        touched=dict.fromkeys(names, False),
        final_poses={m: poses[-1, j].tolist() for j, m in enumerate(names)},
        final_ee_pos=[0.7, 0.0, 0.9],
    )
    return row, Rollout(Command("ee_waypoints", np.zeros((1, 3))), True, ee_targets=np.zeros((1, 3)), frames=frames)


def parts_at(chunks, entity: str, component: str, index: int) -> list:
    """A part entity's value of one component at dataset index ``index`` ([] where it draws nothing then)."""
    times, values = temporal(chunks, entity, component)
    return values[int(np.flatnonzero(times == index)[-1])]


def close(actual, expected) -> None:
    np.testing.assert_allclose(np.asarray(actual, dtype=np.float64), np.asarray(expected, dtype=np.float64), atol=1e-6)


def test_sink_draws_each_episodes_own_objects_part_by_part(tmp_path):
    """A run that draws its objects: each episode's objects, one entity per part under the slot's posed entity, with
    the episode's sizes and colours; a part the next episode's object lacks draws nothing there."""
    root, task = drawn_sink_dir(tmp_path / "run", 2)
    hull = [[0.03, 0.0, -0.02], [-0.03, 0.015, -0.02], [0.0, -0.015, -0.02], [0.0, 0.0, 0.02]]  # centred on its box
    first = [
        factors("object_0", "dumbbell", [0.03, 0.012, 0.06], [1.0, 0.0, 0.0, 1.0]),
        factors("object_1", "hull", [0.03, 0.015, 0.02], [0.0, 0.0, 1.0, 1.0], vertices=hull),
    ]
    second = [
        factors("object_0", "box", [0.02, 0.03, 0.04], [0.0, 1.0, 0.0, 1.0]),
        factors("object_1", "capsule", [0.025, 0.04], [1.0, 1.0, 0.0, 1.0]),
    ]
    rng = np.random.default_rng(5)
    sink = RerunSink(root, task, list(ARM_JOINTS))
    for i, objects in enumerate([first, second]):
        row, rollout = drawn_attempt(i, objects, rng)
        sink.log(row, rollout)
        append_rows(root, [row])
    sink.close()
    files = recording_files(root)
    done = subprocess.run([RERUN_CLI, "rrd", "verify", *files], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    chunks = read_recording(*files)
    red, green, blue, yellow = 0xFF0000FF, 0x00FF00FF, 0x0000FFFF, 0xFFFF00FF  # RGBA as Rerun packs it
    dumbbell = "/world/objects/object_0/"
    # episode 0 (index 0): the dumbbell's balls 6 cm either side of its centre and the bar between them
    close(parts_at(chunks, dumbbell + "part0_sphere", "Ellipsoids3D:half_sizes", 0), [[0.03] * 3])
    close(parts_at(chunks, dumbbell + "part0_sphere", "Ellipsoids3D:centers", 0), [[-0.06, 0, 0]])
    close(parts_at(chunks, dumbbell + "part1_sphere", "Ellipsoids3D:centers", 0), [[0.06, 0, 0]])
    assert parts_at(chunks, dumbbell + "part1_sphere", "Ellipsoids3D:colors", 0) == [red]
    # the bar: a capsule of radius 1.2 cm whose straight part spans the 6 cm between the balls' surfaces, lying
    # along x (Rerun's capsules run along +z from their translation)
    close(parts_at(chunks, dumbbell + "part2_capsule", "Capsules3D:lengths", 0), [0.06])
    close(parts_at(chunks, dumbbell + "part2_capsule", "Capsules3D:radii", 0), [0.012])
    close(parts_at(chunks, dumbbell + "part2_capsule", "Capsules3D:translations", 0), [[-0.03, 0, 0]])
    q = parts_at(chunks, dumbbell + "part2_capsule", "Capsules3D:quaternions", 0)[0]
    from scipy.spatial.transform import Rotation

    close(Rotation.from_quat(q).apply([0, 0, 1]), [1, 0, 0])
    # the hull: a tetrahedron (4 faces, 3 corners each), its faces' normals pointing outwards
    mesh = "/world/objects/object_1/part0_hull"
    corners = np.array(parts_at(chunks, mesh, "Mesh3D:vertex_positions", 0))
    normals = np.array(parts_at(chunks, mesh, "Mesh3D:vertex_normals", 0))
    assert corners.shape == (12, 3) and len(parts_at(chunks, mesh, "Mesh3D:triangle_indices", 0)) == 4
    assert {tuple(np.round(c, 6)) for c in corners} == {tuple(v) for v in hull}
    assert np.all(np.einsum("ij,ij->i", normals, corners - np.mean(hull, axis=0)) > 0)
    assert parts_at(chunks, mesh, "Mesh3D:albedo_factor", 0) == [blue]
    # episode 1 (index T): a box and a capsule; the dumbbell's balls and the hull draw nothing
    box = dumbbell + "part0_box"
    close(parts_at(chunks, box, "Boxes3D:half_sizes", T), [[0.02, 0.03, 0.04]])
    assert parts_at(chunks, box, "Boxes3D:colors", T) == [green]
    assert parts_at(chunks, "/world/objects/object_1/part0_capsule", "Capsules3D:colors", T) == [yellow]
    for gone in (dumbbell + "part0_sphere", dumbbell + "part1_sphere"):
        assert parts_at(chunks, gone, "Ellipsoids3D:half_sizes", T) == []
    assert parts_at(chunks, dumbbell + "part2_capsule", "Capsules3D:lengths", T) == []
    assert parts_at(chunks, mesh, "Mesh3D:vertex_positions", T) == []
    # each episode's start boxes: its objects' bounding boxes, in their colours
    _, half = temporal(chunks, "/world/start", "Boxes3D:half_sizes")
    close(half, [[[0.09, 0.03, 0.03], [0.03, 0.015, 0.02]], [[0.02, 0.03, 0.04], [0.065, 0.025, 0.025]]])
    _, colors = temporal(chunks, "/world/start", "Boxes3D:colors")
    assert colors == [[red, blue], [green, yellow]]
    # the stand-ins are drawn nowhere
    assert "/world/objects/object_0/shape" not in chunks


def test_a_tee_is_drawn_as_its_two_bars_and_boxed_by_both():
    """A heldout tee (half lengths 5 cm along x and 3 cm along y, bars 2 cm wide, 4 cm high): two boxes whose
    centres sit 3 cm below and 1 cm above the middle of its 8 cm depth; its start box spans both bars."""
    from babblegen.exporters.rerun.scene import bounding_half_sizes, object_parts

    tee = factors("object_0", "tee", [0.05, 0.03, 0.01, 0.02], [0.2, 0.4, 0.6, 1.0])
    parts = object_parts(tee)
    assert [p.entity for p in parts] == ["part0_box", "part1_box"]
    close([p.fields["half_sizes"] for p in parts], [[0.05, 0.01, 0.02], [0.01, 0.03, 0.02]])
    close([p.fields["centers"] for p in parts], [[0.0, -0.03, 0.0], [0.0, 0.01, 0.0]])
    assert all(p.fields["colors"].tolist() == [51, 102, 153, 255] for p in parts)
    close(bounding_half_sizes(tee), [0.05, 0.04, 0.02])


def test_a_resumed_run_empties_the_parts_an_earlier_segment_drew(tmp_path):
    """After a resume the sink no longer knows what the kept segments drew: its first episode's objects still
    replace them, every part entity the new objects lack drawing nothing from then on."""
    root, task = drawn_sink_dir(tmp_path / "run", 1)
    rng = np.random.default_rng(6)
    dumbbell = [factors("object_0", "dumbbell", [0.03, 0.012, 0.06], [1.0, 0.0, 0.0, 1.0])]
    row, rollout = drawn_attempt(0, dumbbell, rng)
    sink = RerunSink(root, task, list(ARM_JOINTS))
    sink.log(row, rollout)
    append_rows(root, [row])
    sink.flush()  # committed; the process ends here
    resumed = RerunSink(root, task, list(ARM_JOINTS), state={"episodes": 1, "attempts": 1})
    resumed.log(*drawn_attempt(1, [factors("object_0", "box", [0.02, 0.03, 0.04], [0.0, 1.0, 0.0, 1.0])], rng))
    resumed.close()
    chunks = read_recording(*recording_files(root))
    entity = "/world/objects/object_0/"
    close(parts_at(chunks, entity + "part0_sphere", "Ellipsoids3D:half_sizes", 0), [[0.03] * 3])
    for part, component in [("part0_sphere", "Ellipsoids3D"), ("part1_sphere", "Ellipsoids3D")]:
        assert parts_at(chunks, entity + part, f"{component}:half_sizes", T) == []
    assert parts_at(chunks, entity + "part2_capsule", "Capsules3D:lengths", T) == []
    close(parts_at(chunks, entity + "part0_box", "Boxes3D:half_sizes", T), [[0.02, 0.03, 0.04]])
