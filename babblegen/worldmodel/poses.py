"""Object poses as the world models read and write them: (x, y, z) and a unit quaternion (w, x, y, z), the
dataset's ``observation.environment_state`` layout; the (x, y, z, yaw) states the measures compare; and the
rotations between them."""

from __future__ import annotations

import numpy as np


def wrap(angle: np.ndarray, period: float | np.ndarray = 2 * np.pi) -> np.ndarray:
    """Angles to [-period / 2, period / 2)."""
    period = np.asarray(period, dtype=np.float64)
    safe = np.where(period > 0, period, 2 * np.pi)
    return (angle + safe / 2) % safe - safe / 2


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Rotation about the world's vertical of (..., 4) quaternions (w, x, y, z), radians."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def tilt_of(q: np.ndarray) -> np.ndarray:
    """Angle between the object's own up axis and the world's vertical, radians."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.arccos(np.clip(1 - 2 * (x * x + y * y), -1.0, 1.0))


def object_state(poses: np.ndarray) -> np.ndarray:
    """(..., K, 4) x, y, z, yaw of (..., K, 7) poses."""
    return np.concatenate([poses[..., :3], yaw_of(poses[..., 3:])[..., None]], axis=-1)


def pose_of_state(state: np.ndarray) -> np.ndarray:
    """(..., 7) poses of (..., 4) x, y, z, yaw states: upright, turned by the yaw."""
    half = state[..., 3] / 2
    zeros = np.zeros_like(half)
    return np.concatenate([state[..., :3], np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)], axis=-1)


def as_poses(first: np.ndarray) -> np.ndarray:
    """Starts given as (..., 7) poses, or as (..., 4) states (upright), as (..., 7) poses."""
    first = np.asarray(first, dtype=np.float64)
    return first if first.shape[-1] == 7 else pose_of_state(first)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 4) the quaternion products ``a b`` (w, x, y, z): rotation ``b`` first, then ``a``."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """(..., 4) the inverse rotations of unit quaternions."""
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors ``v`` turned by unit quaternions ``q`` (broadcast over the leading axes)."""
    w, u = q[..., :1], q[..., 1:]
    t = 2 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions of (..., 3) rotation vectors (axis times angle, radians)."""
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = angle / 2
    scale = np.where(angle > 1e-12, np.sin(half) / np.maximum(angle, 1e-12), 0.5)
    return np.concatenate([np.cos(half), r * scale], axis=-1)


def rotvec_of(q: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors of (..., 4) unit quaternions, angles in [0, pi]."""
    q = np.where(q[..., :1] < 0, -q, q)
    sin_half = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2 * np.arctan2(sin_half, q[..., :1])
    return q[..., 1:] * np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-12), 2.0)


def turn_z(v: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(..., 3) vectors turned by ``yaw`` (...,) about the vertical (negative: into a frame of that yaw)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)
