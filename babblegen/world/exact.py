"""Small-matrix arithmetic whose every result is the same on any x86-64 CPU.

numpy hands ``@``, ``np.dot``, ``np.linalg.inv`` and optimised ``einsum`` to BLAS and LAPACK, and OpenBLAS picks
its kernels by CPU (and by ``OPENBLAS_CORETYPE``): some fuse a multiply and an add into one rounding, some sum in
another order. A world whose inverse kinematics or collision checks went through them recorded other joint states
on another machine, and after a contact other outcomes (``benchmarks/check_dispatch.py``). Here each product is an
elementwise multiply and each sum a chain of elementwise adds in a fixed order: numpy rounds every one of those to
IEEE double on its own, whatever the vector width, so the results do not depend on the CPU. For the 3 x 3 and 7 x 7
sizes the world uses they are also about as fast.
"""

from __future__ import annotations

import numpy as np

__all__ = ["inv3", "matmul", "matvec", "rigid_inverse", "row_norm"]


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for (..., n, k) and (..., k, m) (batch dimensions broadcast), summed over k in order."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    out = a[..., :, 0:1] * b[..., 0:1, :]
    for j in range(1, a.shape[-1]):
        out = out + a[..., :, j : j + 1] * b[..., j : j + 1, :]
    return out


def matvec(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a @ v`` for (..., n, k) and (..., k) (batch dimensions broadcast), summed over k in order."""
    a, v = np.asarray(a, dtype=np.float64), np.asarray(v, dtype=np.float64)
    out = a[..., :, 0] * v[..., None, 0]
    for j in range(1, a.shape[-1]):
        out = out + a[..., :, j] * v[..., None, j]
    return out


def inv3(m: np.ndarray) -> np.ndarray:
    """Inverses of (..., 3, 3) matrices by the adjugate and determinant (well-conditioned ones: IK's damped
    J J^T + lambda^2 I)."""
    m = np.asarray(m, dtype=np.float64)
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    co = np.stack(
        [
            np.stack([e * i - f * h, c * h - b * i, b * f - c * e], axis=-1),
            np.stack([f * g - d * i, a * i - c * g, c * d - a * f], axis=-1),
            np.stack([d * h - e * g, b * g - a * h, a * e - b * d], axis=-1),
        ],
        axis=-2,
    )
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    return co / det[..., None, None]


def rigid_inverse(t: np.ndarray) -> np.ndarray:
    """Inverse of (..., 4, 4) rigid transforms: rotation transposed, translation rotated back."""
    t = np.asarray(t, dtype=np.float64)
    out = np.zeros_like(t)
    rot_t = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -matvec(rot_t, t[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def row_norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norms along the last axis, the squares summed in order."""
    x = np.asarray(x, dtype=np.float64)
    total = x[..., 0] * x[..., 0]
    for j in range(1, x.shape[-1]):
        total = total + x[..., j] * x[..., j]
    return np.sqrt(total)
