"""The segment writer against LeRobot's own writer: the same frames give the same dataset.

babblegen appends episodes encoded in its workers and writes them in segments (exporters/lerobot_writer.py); LeRobot's
recording path is ``add_frame`` + ``save_episode`` with its default settings (exporters/lerobot_reference.py). A
user loading either with ``LeRobotDataset`` must get the same frames, images, episode table, info and statistics.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from babblegen.config import VIDEO_CODECS
from babblegen.dataset.lerobot import load_dataset
from babblegen.dataset.schema import HEAD, features
from babblegen.exporters.lerobot import rollback, snapshot
from babblegen.exporters.lerobot_encoding import encode_episode
from babblegen.exporters.lerobot_reference import ReferenceWriter
from babblegen.exporters.lerobot_writer import SegmentWriter
from babblegen.world.rollout import Frames

FPS, SIDE = 10, 64
JOINTS, OBJECTS = [f"joint_{i}" for i in range(7)], ["gray_box", "can", "blue_box", "ball"]
TASK = "noveb babbling in a test"
LENGTHS = [7, 12, 24, 3, 15]  # a 3-frame episode too: the shortest movement LeRobot's stats accept


def with_views(frames: Frames, seed: int) -> Frames:
    """The head camera's depth and masks and a second camera's colour, depth and masks: depth in whole
    millimetres, most within the encoded range (0.2 to 4.295 m), some nearer, farther and nothing seen (0), and
    ids of the scene's instances."""
    rng = np.random.default_rng(100 + seed)
    n = len(frames)

    def depth() -> np.ndarray:
        yy, xx = np.mgrid[0:SIDE, 0:SIDE]
        d = np.stack([600 + 20 * yy + 7 * xx + 13 * t + rng.integers(0, 3, (SIDE, SIDE)) for t in range(n)])
        d[:, :4] = 0  # nothing seen
        d[:, 4:6, :8] = 150  # nearer than the range
        d[:, 6:8, :8] = 5000  # beyond it
        return d.astype(np.uint16)

    def ids() -> np.ndarray:
        return (np.arange(SIDE * SIDE).reshape(SIDE, SIDE)[None] // 300 + rng.integers(0, 2, (n, 1, 1))) % 8

    front = np.roll(frames.images, 5, axis=2)
    frames.views = {
        "head": {"depth": depth(), "segmentation": ids().astype(np.uint8)},
        "front": {"rgb": front, "depth": depth(), "segmentation": ids().astype(np.uint8)},
    }
    return frames


def schema(layout: str) -> dict:
    if layout == "head":
        return features(JOINTS, OBJECTS, SIDE, SIDE)
    from babblegen.tasks import get_task
    from babblegen.world.settings import WorldSettings, cameras_from_names

    cameras = cameras_from_names(["front"], depth=True, segmentation=True)  # head and front, every kind
    settings = WorldSettings(camera_width=SIDE, camera_height=SIDE, cameras=cameras)
    return features(JOINTS, OBJECTS, SIDE, SIDE, settings.cameras, get_task("noveb_tabletop"), settings)


def synthetic_frames(length: int, seed: int, layout: str = "head") -> Frames:
    """Smoothly moving colour ramps (video-like, so the encoder behaves as on camera frames) and random
    recordings (with ``layout`` "views", other cameras and kinds too: :func:`with_views`)."""
    if layout == "views":
        return with_views(synthetic_frames(length, seed), seed)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:SIDE, 0:SIDE]
    images = np.stack(
        [
            np.stack([(xx * 4 + t * 9 + seed * 30) % 256, (yy * 4 + t * 5) % 256, np.full_like(xx, seed * 40)], -1)
            for t in range(length)
        ]
    ).astype(np.uint8)

    def f32(*shape):
        return rng.normal(size=shape).astype(np.float32)

    return Frames(
        state=f32(length, 7),
        action=f32(length, 7),
        ee_pos=f32(length, 3),
        object_poses=f32(length, 4, 7),
        contacts=(rng.random((length, 4)) > 0.8).astype(np.float32),
        images=images,
        object_contacts=(rng.exponential(0.05, (length, 14)) * (rng.random((length, 14)) > 0.6)).astype(np.float32),
    )


@pytest.fixture(scope="module", params=[(c, "head") for c in VIDEO_CODECS] + [("h264", "views")], ids=str)
def datasets(tmp_path_factory, request):
    """The same five episodes through LeRobot's writer, and through the segment writer in two segments with a
    resume between them that rolls back an uncommitted segment; once per video codec with the head camera's
    colour alone, and once with two cameras' colour, depth and masks."""
    codec, layout = request.param
    root = tmp_path_factory.mktemp("writers")
    episodes = [synthetic_frames(n, seed, layout) for seed, n in enumerate(LENGTHS)]
    feats = schema(layout)

    reference = ReferenceWriter.create(root / "reference", "test/reference", FPS, feats, "pr2_arm", codec)
    for frames in episodes:
        reference.add_episode(frames, TASK)
    reference.finalize()

    ours = root / "segments"
    writer = SegmentWriter.create(ours, "test/segments", FPS, feats, "pr2_arm", codec)
    for frames in episodes[:2]:
        writer.add(encode_episode(frames, FPS, writer.features, codec), TASK)
    writer.flush()
    committed = snapshot(ours)
    for seed in (7, 8):  # written after the commit point, then lost in a crash
        writer.add(encode_episode(synthetic_frames(5, seed, layout), FPS, writer.features, codec), TASK)
    writer.flush()
    rollback(ours, committed)
    writer = SegmentWriter.reopen(ours, "test/segments", codec)
    for frames in episodes[2:]:
        writer.add(encode_episode(frames, FPS, writer.features, codec), TASK)
    writer.flush()
    return load_dataset(root / "reference"), load_dataset(ours)


def test_every_frame_and_image_is_the_same(datasets):
    reference, ours = datasets
    assert len(ours) == len(reference) == sum(LENGTHS)
    originals = np.concatenate([synthetic_frames(n, seed).images for seed, n in enumerate(LENGTHS)]) / 255
    shifted = np.roll(originals, 5, axis=2)  # the second camera's (views layout)
    deterministic = json.loads((ours.root / "meta/info.json").read_text())["features"][HEAD]["info"]["video.codec"]
    deterministic = deterministic != "h264"
    for i in range(len(reference)):
        want, got = reference[i], ours[i]
        assert set(got) == set(want)
        for key, value in want.items():
            if key == "task":
                assert got[key] == value == TASK
            elif key not in (HEAD, "observation.images.front") or deterministic:  # same encoder, same settings
                np.testing.assert_array_equal(np.asarray(got[key]), np.asarray(value), err_msg=f"frame {i} {key}")
            else:  # LeRobot's writer runs x264's AVX-512 code where the CPU has it: not the same bytes every run
                image = np.asarray(got[key]).transpose(1, 2, 0)
                errors = np.abs((originals if key == HEAD else shifted) - image).mean(axis=(1, 2, 3))
                assert errors.argmin() == i and errors[i] < 0.03, f"frame {i}: {errors[i]:.3f}"
                np.testing.assert_allclose(image, np.asarray(value).transpose(1, 2, 0), atol=0.1)


def test_the_episode_table_matches(datasets):
    reference, ours = datasets
    want, got = reference.meta.episodes, ours.meta.episodes
    assert got.column_names == want.column_names
    assert got["length"] == LENGTHS
    for column in ("episode_index", "tasks", "length", "dataset_from_index", "dataset_to_index"):
        assert got[column] == want[column]
    # our episodes sit in two segment files, LeRobot's in one: each episode spans the same video time
    video = "videos/observation.images.head"
    durations = [np.subtract(e[f"{video}/to_timestamp"], e[f"{video}/from_timestamp"]) for e in (want, got)]
    for key in reference.meta.video_keys:  # every video alike
        assert got[f"videos/{key}/from_timestamp"] == got[f"{video}/from_timestamp"]
    np.testing.assert_allclose(durations[1], durations[0], atol=1e-9)
    np.testing.assert_allclose(durations[0], np.asarray(LENGTHS) / FPS, atol=1e-9)
    assert got["data/file_index"] == [0, 0, 1, 1, 1]  # a new file per segment, the rolled-back one reused


def test_info_and_statistics_match(datasets):
    reference, ours = datasets
    info = [json.loads((d.root / "meta/info.json").read_text()) for d in (reference, ours)]
    assert info[1] == info[0]
    stats = [json.loads((d.root / "meta/stats.json").read_text()) for d in (reference, ours)]
    assert set(stats[1]) == set(stats[0])
    for key, per_stat in stats[0].items():
        assert set(stats[1][key]) == set(per_stat)
        for name, value in per_stat.items():  # aggregated in a different order: rounding differences only
            # except the image mean and std, which LeRobot accumulates in float32 over every pixel and babblegen
            # computes exactly from pixel-value counts (exporters/lerobot_encoding.image_stats)
            rtol = 1e-4 if key.startswith("observation.images.") and name in ("mean", "std") else 1e-9
            np.testing.assert_allclose(stats[1][key][name], value, rtol=rtol, atol=1e-12, err_msg=f"{key} {name}")


def test_depth_and_masks_come_back_as_rendered(datasets):
    """Depth in millimetres within the encoded range comes back exactly (``depth_output_unit="m"``: in metres),
    clipped outside it; the ids exactly (stored as 16-bit PNG, read back as the ids)."""
    _, ours = datasets
    if "observation.images.front_depth" not in ours.meta.features:
        pytest.skip("the head camera's colour alone")
    from babblegen.dataset.lerobot import load_dataset

    in_metres = load_dataset(ours.root, "test/segments", depth_output_unit="m")
    frames = [synthetic_frames(n, seed, "views") for seed, n in enumerate(LENGTHS)]
    info = ours.meta.features["observation.images.front_depth"]["info"]
    assert info["is_depth_map"] and info["depth_unit"] == "mm" and info["video.depth_min"] == 0.2
    ids = ours.meta.features["observation.images.front_segmentation"]["info"]["ids"]
    assert ids["0"] == "background" and ids["3"] == "robot" and ids["4"] == OBJECTS[0]
    i = 0
    for f in frames:
        for t in range(len(f)):
            for camera in ("head", "front"):
                want = np.clip(f.views[camera]["depth"][t], 200, 4295)
                got = np.asarray(ours[i][f"observation.images.{camera}_depth"])[0]
                np.testing.assert_array_equal(np.rint(got), want, err_msg=f"frame {i} {camera} depth (mm)")
                metres = np.asarray(in_metres[i][f"observation.images.{camera}_depth"])[0]
                np.testing.assert_allclose(metres, want / 1000.0, atol=1e-6)
                mask = np.asarray(ours[i][f"observation.images.{camera}_segmentation"])[0]
                np.testing.assert_array_equal(mask, f.views[camera]["segmentation"][t])
            i += 1


def test_the_recorded_codec_is_the_one_asked_for_and_a_resume_cannot_switch_it(datasets, tmp_path, request):
    _, ours = datasets
    codec = request.node.callspec.params["datasets"][0]
    info = json.loads((ours.root / "meta/info.json").read_text())["features"]["observation.images.head"]["info"]
    assert info["video.codec"] == {"h264": "h264", "h264_mbtree": "h264", "libsvtav1": "av1"}[codec]
    assert info["video.g"] == 2 and info["video.crf"] == {"h264": 27, "h264_mbtree": 22, "libsvtav1": 30}[codec]
    other = "libsvtav1" if codec != "libsvtav1" else "h264"
    with pytest.raises(ValueError, match=f"cannot take episodes encoded with {other}"):
        SegmentWriter.reopen(ours.root, "test/segments", other)


def test_the_data_table_is_byte_for_byte_the_one_hugging_face_encodes():
    """The segment writer builds each data parquet's Arrow table from the numpy columns itself: the file must be
    the one ``datasets.Dataset.from_dict`` with LeRobot's features would have written."""
    import io

    import datasets as hf_datasets
    import pyarrow.parquet as pq
    from lerobot.datasets.feature_utils import get_hf_features_from_features

    from babblegen.dataset.schema import with_default_features
    from babblegen.exporters.lerobot_writer import arrow_table

    hf = get_hf_features_from_features(with_default_features(features(JOINTS, OBJECTS, SIDE, SIDE)))
    rng = np.random.default_rng(3)
    n = 257
    columns = {
        key: rng.normal(size=(n, f.length)).astype(np.float32)
        if isinstance(f, hf_datasets.List)
        else (rng.normal(size=n).astype(np.float32) if f.dtype == "float32" else rng.integers(0, 10**9, n))
        for key, f in hf.items()
    }
    expected = hf_datasets.Dataset.from_dict(columns, features=hf, split="train").with_format("arrow")[:]
    got = arrow_table(columns, hf)
    files = []
    for table in (expected, got):
        buf = io.BytesIO()
        pq.write_table(table, buf, compression="snappy", use_dictionary=True)
        files.append(buf.getvalue())
    assert files[0] == files[1]
    images = hf_datasets.Features({"x": hf_datasets.Image()})
    assert arrow_table({"x": np.zeros((2, 4, 4, 3), np.uint8)}, images) is None  # left to Hugging Face


def test_a_dataset_written_before_object_contacts_takes_episodes_that_record_them(tmp_path):
    """A run resumed from a dataset made before ``observation.object_contacts``: its episodes keep the dataset's own
    features (the new column and its statistics left out), and it loads."""
    from babblegen.dataset.schema import OBJECT_CONTACTS

    old = {k: v for k, v in features(JOINTS, OBJECTS, SIDE, SIDE).items() if k != OBJECT_CONTACTS}
    writer = SegmentWriter.create(tmp_path / "old", "test/old", FPS, old, "pr2_arm", "h264")
    writer.add(encode_episode(synthetic_frames(6, 0), FPS, writer.features, "h264"), TASK)
    writer.flush()
    new_schema = {**writer.features, **{OBJECT_CONTACTS: features(JOINTS, OBJECTS, SIDE, SIDE)[OBJECT_CONTACTS]}}
    writer.add(encode_episode(synthetic_frames(7, 1), FPS, new_schema, "h264"), TASK)
    writer.flush()
    ds = load_dataset(tmp_path / "old", "test/old")
    assert ds.meta.total_episodes == 2 and ds.num_frames == 13
    assert OBJECT_CONTACTS not in ds.meta.features and OBJECT_CONTACTS not in ds.meta.stats
    assert OBJECT_CONTACTS not in ds.hf_dataset.column_names
    ds.meta.episodes.to_pandas()  # every episode row readable together
