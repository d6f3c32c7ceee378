"""The dataset card: README.md at the dataset root, LeRobot's own card template filled in, so that pushing the
dataset to a hub gives a page that says what it holds and how it was made."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from babblegen.dataset.lerobot import read_dataset_info
from babblegen.dataset.sidecar import read_run_info
from babblegen.objects import HELDOUT_SHAPES, VARIED_SHAPES, ObjectRanges
from babblegen.store import Sink, atomic_write

CARD = "README.md"
LICENSE = "mit"  # babblegen's license; the data is simulated, nobody else's recording
PAPER = (
    "Maestre, Cully, Gonzales, Doncieux: Bootstrapping interactions with objects from raw sensorimotor data: "
    "a Novelty Search based approach"
)
CITATION = """@misc{maestre_noveb,
  title  = {Bootstrapping interactions with objects from raw sensorimotor data: a Novelty Search based approach},
  author = {Maestre, Carlos and Cully, Antoine and Gonzales, Christophe and Doncieux, Stephane}
}"""


def card_text(info: dict[str, Any], run_info: dict[str, Any], counters: dict[str, int]) -> str:
    """The card for a dataset with LeRobot metadata ``info`` (meta/info.json) made by the run ``run_info``."""
    from lerobot.datasets.utils import create_lerobot_dataset_card

    class _Info(dict):  # create_lerobot_dataset_card calls .to_dict() on LeRobot's DatasetInfo
        def to_dict(self) -> dict[str, Any]:
            return dict(self)

    cfg = run_info["config"]
    objects = ", ".join(o["name"] for o in run_info["task"]["objects"])
    explorer = {"noveb": "Novelty-driven Evolutionary Babbling (NovEB)", "random": "random motor babbling"}
    description = f"""Interaction data that nobody scripted, made by babblegen
{run_info["versions"].get("babblegen", "")} with
{explorer.get(cfg["explorer"], cfg["explorer"])} in the simulated scene `{cfg["task"]}`: a PR2-like 7-DoF arm
(`{info.get("robot_type")}`) at a table with {objects}, simulated with SAPIEN 3 / ManiSkill 3 and rendered on the CPU.

- **Episodes:** {counters["executed"]} executed movements out of {counters["attempts"]} attempted
  ({counters["contacts"]} touched an object), {counters["generations"]} generations, seed {cfg["seed"]}.
- **Frames:** {info.get("fps")} per second; `observation.images.head` is the head camera
  ({cfg["world"]["camera_width"]}x{cfg["world"]["camera_height"]}); `observation.state` the 7 joint positions;
  `action` the joint targets sent after observing each frame (LeRobot's convention: `action[t]` leads to
  `observation.state[t+1]`); `observation.ee_pos` the tool point; `observation.environment_state` every object's
  pose (x, y, z, qw, qx, qy, qz); `observation.contacts` which objects the arm touched since the previous frame.
{_camera_lines(info)}
- **Starts:** {starts_text(cfg)}
- **Objects:** {objects_text(cfg)}
- **Task string:** "{run_info.get("episode_task", "")}".
- **Every attempt**, infeasible ones included, with its genome, descriptor, novelty and contacts:
  `babblegen/attempts.jsonl`; the full configuration and software versions: `babblegen/run.json`.

Made with: `{" ".join(run_info.get("command") or [])}`

Configuration:

```json
{json.dumps(cfg, indent=2)}
```
"""
    card = create_lerobot_dataset_card(
        tags=["babblegen", "NovEB", "motor-babbling", "novelty-search", "simulation", "world-model"],
        dataset_info=_Info(info),
        license=LICENSE,
        repo_id=run_info.get("repo_id"),
        dataset_description=description,
        paper=PAPER,
        citation_bibtex=CITATION,
    )
    return str(card)


def starts_text(cfg: dict[str, Any]) -> str:
    """How the run's episodes started (``world.starts``; "fixed" for configurations made before starts varied)."""
    if (cfg.get("world") or {}).get("starts", "fixed") != "varied":
        return "fixed: every episode starts from the task's scene (the objects' poses in `babblegen/run.json`)."
    text = (
        "varied: each start is a layout (x, y, yaw per object) drawn from the task's per-object regions and "
        "settled by physics before the first frame"
    )
    if cfg.get("explorer") == "noveb":
        prob = (cfg.get("noveb") or {}).get("start_mutation_prob", 0.5)
        text += (
            f"; NovEB children keep their parent's start unless a start mutation (probability {prob}) draws a new one"
        )
    else:
        text += "; every attempt draws its own"
    return text + (
        ". Each row of `babblegen/attempts.jsonl` records its start (`start`) and, when executed, the objects' "
        "settled poses at the first frame (`start_poses`)."
    )


def objects_text(cfg: dict[str, Any]) -> str:
    """Which objects stood on the table, and the distribution drawn ones came from (``world.objects``)."""
    world = cfg.get("world") or {}
    kind = world.get("objects", "paper")
    factors = (
        "Each row of `babblegen/attempts.jsonl` holds its objects under `objects` (per slot: shape, size, mass, "
        "density, static and dynamic friction, restitution, colour), and `meta/episodes` the same as "
        "`objects/<slot>/<factor>` columns."
    )
    if kind == "paper":
        return f"paper: the NovEB paper's gray box, can, blue box and ball in every episode. {factors}"
    ranges = ObjectRanges(**(world.get("object_ranges") or {}))
    shapes = VARIED_SHAPES if kind == "varied" else HELDOUT_SHAPES
    part = "outer thirds" if kind == "varied" else "middle third (held out from every varied draw)"
    return (
        f"{kind}: every new start draws its own {world.get('num_objects', 4)} objects (slots `object_0`...): shape "
        f"uniform over {', '.join(shapes)}; every dimension {ranges.size[0]}-{ranges.size[1]} m; from the {part} of "
        f"density {ranges.density[0]:g}-{ranges.density[1]:g} kg/m^3 (log scale; mass = density x volume), static "
        f"friction {ranges.static_friction[0]:g}-{ranges.static_friction[1]:g} (dynamic 0.6-1.0 times it) and "
        f"restitution {ranges.restitution[0]:g}-{ranges.restitution[1]:g}; colour uniform in hue. {factors}"
    )


def _camera_lines(info: dict[str, Any]) -> str:
    """The cameras' features and their conventions, when the dataset has more than the head camera's colour."""
    feats = info.get("features", {})
    extra = [k for k, ft in feats.items() if k.startswith("observation.images.") and k != "observation.images.head"]
    if not extra:
        return ""
    listed = ", ".join(f"`{k}`" for k in extra)
    return f"""- **Cameras:** {listed}. `..._depth`: LeRobot depth videos (`is_depth_map`), stored in millimetres,
  quantized linearly one code per millimetre over the range in the feature's `video.depth_min` / `depth_max`
  (load with `LeRobotDataset(..., depth_output_unit="m")` for metres). `..._segmentation`: instance ids per pixel
  (16-bit PNG, read back as the ids; the feature's `info.ids` names them: background, table, floor, robot, each
  object). Each camera feature's `info` holds `intrinsics` (3x3 pinhole, pixels) and, for a fixed camera,
  `cam2world` (4x4, OpenCV camera axes: x right, y down, z forward, in the world frame: the robot's torso at the
  origin, x forward, y left, z up); a moving camera's pose is `observation.cam2world.<camera>` per frame (4x4,
  row-major)."""


def write_card(root: Path, run_info: dict[str, Any], counters: dict[str, int]) -> Path:
    """Write (or refresh) ROOT/README.md from meta/info.json and the run's state."""
    root = Path(root)
    info = read_dataset_info(root)
    atomic_write(root / CARD, card_text(info, run_info, counters).encode())
    return root / CARD


class DatasetCardSink(Sink):
    """Refreshes the card at every commit point, after the dataset's metadata (so it follows the LeRobot sink).
    It holds no state of its own: the card is rewritten from what the other sinks committed."""

    name = "card"

    def __init__(self, state: dict | None, root: Path):
        self.root = Path(root)

    def commit(self, counters: dict[str, int], final: bool = False) -> dict:
        write_card(self.root, read_run_info(self.root), counters)
        return {}
