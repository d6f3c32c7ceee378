"""Run state as plain JSON that no reader can execute: numpy arrays and bytes become tagged base64 objects.

A pickle would run code from whoever made the dataset; this format only ever yields dicts, lists, numbers,
strings, numpy arrays and bytes. Floats round-trip exactly (JSON keeps Python's shortest repr).
"""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np

FORMAT = "babblegen-state/1"


class StateFileError(ValueError):
    """The bytes are not a complete state file of this format."""


def _encode(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        data = np.ascontiguousarray(obj)
        return {
            "__ndarray__": base64.b64encode(data.tobytes()).decode(),
            "dtype": data.dtype.str,
            "shape": list(data.shape),
        }
    if isinstance(obj, bytes):
        return {"__bytes__": base64.b64encode(obj).decode()}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple):
        return [_encode(v) for v in obj]
    raise TypeError(f"cannot store {type(obj).__name__} in a state file")


def _decode(d: dict[str, Any]) -> Any:
    if "__ndarray__" in d:
        dtype = np.dtype(d["dtype"])
        if dtype.hasobject:
            raise StateFileError("object arrays are not allowed in a state file")
        return np.frombuffer(base64.b64decode(d["__ndarray__"]), dtype=dtype).reshape(d["shape"]).copy()
    if "__bytes__" in d:
        return base64.b64decode(d["__bytes__"])
    return d


def dumps(state: dict[str, Any]) -> bytes:
    return json.dumps({"format": FORMAT, "state": state}, default=_encode, separators=(",", ":")).encode()


def loads(data: bytes) -> dict[str, Any]:
    try:
        doc = json.loads(data, object_hook=_decode)
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError, KeyError, TypeError) as e:
        raise StateFileError(f"not a readable state file ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("state"), dict):
        raise StateFileError(f"not a {FORMAT} state file")
    return doc["state"]
