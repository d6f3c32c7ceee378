"""The run configuration: one dataclass tree, built from defaults < a TOML file < command-line flags,
validated before anything is written, and stored with every dataset."""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from babblegen.descriptors import DESCRIPTORS
from babblegen.explorers import EXPLORERS
from babblegen.explorers.noveb import NovEBConfig, upgrade_stored_config
from babblegen.starts import run_starts
from babblegen.tasks import TASKS, get_task
from babblegen.world.settings import LEGACY_CAMERAS, WorldSettings

# The head camera's video codecs (settings: babblegen.exporters.lerobot_codecs.video_encoder). H.264 is the
# default: on frames like 128x128 it costs about a third of the CPU time of LeRobot's own default, SVT-AV1, for
# about the same fidelity and size (benchmarks/bench_codecs.py), and every LeRobot video backend decodes it.
# "h264": x264 without macroblock-tree rate control (whose rcpps gives each CPU maker's own bits); "h264_mbtree": x264
# with it, at CRF 22, as runs made before (exporters/lerobot_codecs.py); "libsvtav1": LeRobot's default
VIDEO_CODECS = ("h264", "libsvtav1", "h264_mbtree")
RERUN_FRAMES = ("ends", "all")  # what a run's Rerun recording logs per episode (exporters.rerun.columns)


class ConfigError(ValueError):
    """Bad user input: reported as a one-line message and a non-zero exit."""


@dataclass
class RunConfig:
    task: str = "noveb_tabletop"
    explorer: str = "noveb"  # "noveb" or "random"
    seed: int = 0
    # stop after this many attempted movements (None, or 0 in a file or flag: when the generations end); the
    # default is about what the paper's 2,000 generations of 12 attempt once repeated genomes are reused
    max_attempts: int | None = 8000
    # "auto": with fixed starts a 256-bit pHash of the full head image ("phash16"; the paper: 64-bit "phash"), with
    # varied starts the pHash of what changed between the before and after images ("change16")
    descriptor: str = "auto"
    checkpoint_every: int = 10  # generations between commit points (crash-safe resume granularity)
    workers: int = field(default_factory=lambda: default_workers())  # rollout processes: one per core
    ray: str | None = None  # None, "auto" or a cluster address
    # let machines that compute differently (their fingerprints differ: babblegen.fingerprint) write one dataset: a
    # Ray node of another kind, or a resume on one. Off, such a node or resume is refused: what a mixed run records
    # depends on which machine ran which movement. On, run.json records the run as mixed.
    allow_mixed_machines: bool = False
    rerun: bool = True  # write Rerun recordings beside the dataset (DIR/babblegen/rerun/)
    # what the recordings log of each episode: "ends" (its first and last frame, every view, and the paths of the
    # movement; `babblegen view` plays any episode frame by frame from the dataset) or "all" (every frame)
    rerun_frames: str = "ends"
    video_codec: str = "h264"  # the head camera's video: "h264" or "libsvtav1" (LeRobot's default)
    noveb: NovEBConfig = field(default_factory=NovEBConfig)
    # a run's objects default to "auto", resolved for its task when it is validated (WorldSettings.for_task)
    world: WorldSettings = field(default_factory=lambda: WorldSettings(objects="auto"))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        data = dict(data)
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ConfigError(f"unknown config keys: {', '.join(sorted(unknown))}")
        noveb = _sub(NovEBConfig, data.pop("noveb", {}), "noveb")
        world = data.pop("world", {})
        world = _sub(WorldSettings, {"objects": "auto", **world} if isinstance(world, dict) else world, "world")
        _check_types(cls, data, "")
        try:
            return cls(noveb=noveb, world=world, **data)
        except TypeError as e:
            raise ConfigError(str(e)) from None

    def explorer_config(self) -> dict[str, Any]:
        """The chosen explorer's options: NovEB's whole section; for the random controls, the batch size, number
        of batches and novelty measurement, taken from the same section so the runs compare."""
        noveb = asdict(self.noveb)
        if self.explorer == "noveb":
            return noveb
        shared = ("population", "generations", "k", "archive_per_generation", "archive_policy")
        return {key: noveb[key] for key in shared}

    def descriptor_config(self) -> dict[str, Any]:
        """Keyword arguments of :func:`babblegen.descriptors.make_descriptor` for this run."""
        return {"name": self.resolved_descriptor()}

    def resolved_descriptor(self) -> str:
        """The descriptor's name, "auto" chosen by the starts: the after image's pHash when every episode starts
        from the same scene, what changed between the before and after images when starts vary (an after image
        alone would reward new starts, not new interactions)."""
        if self.descriptor != "auto":
            return self.descriptor
        return "change16" if self.world.starts == "varied" else "phash16"

    def validate(self) -> None:
        """Raise ConfigError for values that cannot work, with the valid choices where there are some."""
        if self.task not in TASKS:
            raise ConfigError(f"unknown task {self.task!r}; choose one of: {', '.join(sorted(TASKS))}")
        if self.explorer not in EXPLORERS:
            raise ConfigError(f"unknown explorer {self.explorer!r}; choose one of: {', '.join(sorted(EXPLORERS))}")
        if self.descriptor != "auto" and self.descriptor not in DESCRIPTORS:
            raise ConfigError(
                f"unknown descriptor {self.descriptor!r}; choose one of: auto, {', '.join(sorted(DESCRIPTORS))}"
            )
        if self.world.starts == "varied" and TASKS[self.task].starts is None:
            raise ConfigError(
                f"task {self.task!r} declares no start distribution (TaskSpec.starts), so it cannot vary its starts; "
                "use --starts fixed"
            )
        self.world = self.world.for_task(TASKS[self.task])  # stored as resolved
        if self.world.objects != "paper":
            if self.world.starts != "varied":
                raise ConfigError(
                    f"--objects {self.world.objects} draws each start's objects, so it needs --starts varied"
                )
            self._check_placement()
        self.descriptor = self.resolved_descriptor()  # stored as chosen
        n = self.noveb
        if n.k >= n.population:
            raise ConfigError(
                f"k ({n.k}) must be below the population ({n.population}): the first generation has no archive, "
                "so each individual has only population - 1 neighbours"
            )
        if self.max_attempts == 0:
            self.max_attempts = None  # no limit: the generations end the run
        if self.max_attempts is not None and self.max_attempts < 1:
            raise ConfigError(f"max_attempts must be at least 1 (or 0: no limit), got {self.max_attempts}")
        if self.seed < 0:
            raise ConfigError(f"seed must be non-negative, got {self.seed}")
        if self.checkpoint_every < 1:
            raise ConfigError(f"checkpoint_every must be at least 1, got {self.checkpoint_every}")
        if self.workers < 1:
            raise ConfigError(f"workers must be at least 1, got {self.workers}")
        if self.rerun_frames not in RERUN_FRAMES:
            raise ConfigError(f"unknown rerun_frames {self.rerun_frames!r}; choose one of: {', '.join(RERUN_FRAMES)}")
        if self.video_codec not in VIDEO_CODECS:
            raise ConfigError(f"unknown video codec {self.video_codec!r}; choose one of: {', '.join(VIDEO_CODECS)}")

    def _check_placement(self, starts: int = 20) -> None:
        """Refuse drawn objects that the start regions cannot hold: the run's first starts are drawn here."""
        sampler = run_starts(get_task(self.task), self.world, self.seed)
        try:
            for attempt in range(starts):
                sampler.draw(attempt)
        except ValueError as e:
            raise ConfigError(str(e)) from None


RESUME_MAY_CHANGE = (
    "max_attempts",
    "generations",
    "workers",
    "ray",
    "allow_mixed_machines",
    "rerun",
    "rerun_frames",
    "checkpoint_every",
)


def resumed_config(stored: dict[str, Any], overrides: dict[str, Any] | None = None) -> RunConfig:
    """The configuration a resumed run continues with: the stored one, extended (``generations``,
    ``max_attempts``) or run differently (workers, Ray, Rerun, commit interval) by ``overrides``, a flat dict
    of setting names from any section. Changing anything that would change the results is refused."""
    data = json.loads(json.dumps(stored))  # a deep copy
    data.setdefault("video_codec", "libsvtav1")  # runs stored before the setting existed recorded AV1
    data.setdefault("rerun_frames", "all")  # runs stored before the setting existed recorded every frame
    data["noveb"] = upgrade_stored_config(data.get("noveb", {}))
    data["world"].setdefault("cameras", [dict(c) for c in LEGACY_CAMERAS])  # stored before cameras were settings
    data["world"].setdefault("return_home", "retrace")  # stored before the setting existed: the arm retraced
    data["world"].setdefault("max_move_seconds", 0.0)  # ... and any movement was executed
    data["world"].setdefault("count_approach", True)  # ... and a bound counted the way to the first waypoint
    if "pcm" not in data["world"] and data.get("video_codec", "libsvtav1") == "h264":
        data["video_codec"] = "h264_mbtree"  # stored before either change: x264 ran its macroblock tree
    data["world"].setdefault("pcm", True)  # ... and PhysX generated contacts with persistent manifolds
    data["world"].setdefault("box_hulls", False)  # stored before the setting existed: boxes were PhysX's boxes
    data["world"].setdefault("starts", "fixed")  # stored before starts varied: every episode began from the task's
    data["world"].setdefault("objects", "paper")  # stored before objects were drawn: the task's own, every episode
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        section = next((sec for sec in (data, data["noveb"], data["world"]) if key in sec), None)
        if section is None:
            raise ConfigError(f"unknown setting {key!r}")
        if section[key] == value:
            continue
        if key not in RESUME_MAY_CHANGE:
            raise ConfigError(f"--resume cannot change {key!r} of an existing run (stored: {section[key]!r})")
        section[key] = value
    config = RunConfig.from_dict(data)
    config.validate()
    return config


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity, which containers and taskset restrict)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _sub(cls: type, values: dict[str, Any] | Any, section: str) -> Any:
    if dataclasses.is_dataclass(values):
        return values
    if not isinstance(values, dict):
        raise ConfigError(f"[{section}] must be a table")
    unknown = set(values) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ConfigError(f"unknown keys in [{section}]: {', '.join(sorted(unknown))}")
    _check_types(cls, values, f"[{section}] ")
    try:
        return cls(**values)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"[{section}] {e}") from None


_SCALARS = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,)}


def _check_types(cls: type, values: dict[str, Any], where: str) -> None:
    """Refuse a TOML value of the wrong type (a string seed, a fractional fps) before it reaches the run."""
    for f in dataclasses.fields(cls):
        if f.name not in values or dataclasses.is_dataclass(values[f.name]):
            continue
        value, kinds = values[f.name], str(f.type).replace(" ", "").split("|")
        if value is None and "None" in kinds:
            continue
        allowed = tuple(t for k in kinds for t in _SCALARS.get(k, ()))
        if not allowed:
            continue  # a type this check does not know: the dataclass validates it
        if not isinstance(value, allowed) or (isinstance(value, bool) and bool not in allowed):
            expected = " or ".join(k for k in kinds if k != "None") + (" or none" if "None" in kinds else "")
            raise ConfigError(f"{where}{f.name} must be {expected}, got {value!r}")


def load_toml(path: str | Path) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"config file {path} is not valid TOML: {e}") from None


def merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Recursive dict merge; values in `override` win, None values in `override` are ignored."""
    out = dict(base)
    for k, v in override.items():
        if v is None:
            continue
        if isinstance(v, dict):
            if k in out and not isinstance(out[k], dict):
                raise ConfigError(f"[{k}] must be a table, got {out[k]!r}")
            out[k] = merge(out.get(k) or {}, v)
        else:
            out[k] = v
    return out
