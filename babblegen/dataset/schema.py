"""The dataset's schema: every feature babblegen writes to a LeRobot dataset, its name, shape and ``info`` (camera
parameters, depth conventions, mask ids), and the episode table's own columns, as DESIGN.md and docs/dataset.md
describe them. Writers declare the features with it; readers find the columns by its names."""

from __future__ import annotations

from babblegen.contact_events import pair_names
from babblegen.world.cameras import task_instance_names, view_parameters

HEAD = "observation.images.head"
STATE = "observation.state"  # the arm's joint positions
ACTION = "action"  # the commanded joint positions
EE_POS = "observation.ee_pos"  # the tool point (x, y, z)
ENVIRONMENT_STATE = "observation.environment_state"  # every object's pose (x, y, z, qw, qx, qy, qz)
CONTACTS = "observation.contacts"  # whether the arm touched each object since the previous frame
OBJECT_CONTACTS = "observation.object_contacts"  # N s per pair since the previous frame (`babblegen.contact_events`)
KINDS = ("rgb", "depth", "segmentation")
IMAGE_NAMES = ["height", "width", "channels"]
# an episode's objects as factors of variation: the episode table's ``objects/<slot>/<factor>`` columns
FACTORS = ("shape", "size", "mass", "density", "static_friction", "dynamic_friction", "restitution", "color")


def image_key(camera: str, kind: str = "rgb") -> str:
    """The feature of one camera's images: ``observation.images.<camera>``, ``..._depth`` (LeRobot's
    convention for depth maps), ``..._segmentation``."""
    return f"observation.images.{camera}" + ("" if kind == "rgb" else f"_{kind}")


def pose_key(camera: str) -> str:
    """The per-frame pose of a moving camera."""
    return f"observation.cam2world.{camera}"


def camera_features(cameras, task, settings) -> dict:
    """The image features of ``cameras`` (`WorldSettings.cameras`): each camera's colour video, depth video
    (LeRobot's ``is_depth_map``, in millimetres) and instance masks (16-bit PNG, an ``ids`` map from id to name),
    each with the camera's ``intrinsics`` (3x3, pixels) and, for a camera that does not move, ``cam2world``
    (4x4, OpenCV axes: x right, y down, z forward, in the world frame); a moving camera's pose per frame."""
    out: dict = {}
    ids = dict(enumerate(task_instance_names(task)))
    for view in cameras:
        height, width = view.size(settings)
        params = view_parameters(view, task, (height, width))
        info = {"intrinsics": params["intrinsics"].tolist(), "camera.mount": view.mount}
        if params["cam2world"] is not None:
            info["cam2world"] = params["cam2world"].tolist()
        out[image_key(view.name)] = {"dtype": "video", "shape": (height, width, 3), "names": IMAGE_NAMES, "info": info}
        if view.depth:
            depth_info = {**info, "is_depth_map": True, "depth_unit": "mm"}
            out[image_key(view.name, "depth")] = {
                "dtype": "video",
                "shape": (height, width, 1),
                "names": IMAGE_NAMES,
                "info": depth_info,
            }
        if view.segmentation:
            seg_info = {**info, "ids": {str(k): v for k, v in ids.items()}}
            out[image_key(view.name, "segmentation")] = {
                "dtype": "image",
                "shape": (height, width, 1),
                "names": IMAGE_NAMES,
                "info": seg_info,
            }
        if params["cam2world"] is None:
            out[pose_key(view.name)] = {
                "dtype": "float32",
                "shape": (16,),
                "names": [f"m{r}{c}" for r in range(4) for c in range(4)],
            }
    return out


def image_sources(features: dict) -> dict[str, tuple[str, str]]:
    """Each image feature's (camera, kind) by :func:`image_key`'s naming."""
    out = {}
    for key, ft in features.items():
        if ft["dtype"] not in ("video", "image") or not key.startswith("observation.images."):
            continue
        camera = key.removeprefix("observation.images.")
        kind = next((k for k in KINDS[1:] if camera.endswith(f"_{k}")), "rgb")
        out[key] = (camera.removesuffix(f"_{kind}") if kind != "rgb" else camera, kind)
    return out


def features(
    joint_names: list[str], object_names: list[str], height: int, width: int, cameras=None, task=None, settings=None
) -> dict:
    """The dataset schema (see DESIGN.md): the cameras' images (:func:`camera_features`; without ``cameras``, the
    head camera's colour video alone, as runs stored before cameras were a setting), joints, commanded joints,
    tool point, objects, the arm's contacts, and the contact impulses between objects, the table and the floor
    (`babblegen.contact_events`)."""
    pose_fields = ("x", "y", "z", "qw", "qx", "qy", "qz")
    if cameras is None:
        images = {HEAD: {"dtype": "video", "shape": (height, width, 3), "names": IMAGE_NAMES}}
    else:
        images = camera_features(cameras, task, settings)
    poses = {k: v for k, v in images.items() if k.startswith("observation.cam2world.")}
    images = {k: v for k, v in images.items() if k not in poses}
    return {
        **images,
        **poses,
        STATE: {"dtype": "float32", "shape": (len(joint_names),), "names": list(joint_names)},
        ACTION: {"dtype": "float32", "shape": (len(joint_names),), "names": list(joint_names)},
        EE_POS: {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
        ENVIRONMENT_STATE: {
            "dtype": "float32",
            "shape": (7 * len(object_names),),
            "names": [f"{o}.{f}" for o in object_names for f in pose_fields],
        },
        CONTACTS: {
            "dtype": "float32",
            "shape": (len(object_names),),
            "names": list(object_names),
        },
        OBJECT_CONTACTS: {
            "dtype": "float32",
            "shape": (len(pair_names(object_names)),),
            "names": pair_names(object_names),
        },
    }


def with_default_features(feats: dict) -> dict:
    """The schema as LeRobot stores it: ours plus its own per-frame columns (timestamp, indexes)."""
    from lerobot.utils.constants import DEFAULT_FEATURES

    return {**feats, **DEFAULT_FEATURES}


def object_columns(objects: list[dict]) -> dict:
    """An episode's objects (a sidecar row's ``objects``) as columns of the episode table:
    ``objects/<slot>/<factor>`` for every factor of `FACTORS` (a hull's points stay in the sidecar)."""
    return {f"objects/{o['name']}/{factor}": o[factor] for o in objects for factor in FACTORS}
