"""The world's arithmetic is the same on any x86-64 CPU: no BLAS or LAPACK call decides a recorded value.

OpenBLAS picks its kernels by CPU, and a kernel that fuses multiply and add, or sums in another order, rounds
differently: with OpenBLAS's own kernel choice a run's attempt 132 ended elsewhere (benchmarks/check_dispatch.py).
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from babblegen.world.exact import inv3, matmul, matvec, rigid_inverse, row_norm

WORLD = Path(__file__).resolve().parents[1] / "babblegen" / "world"
# what numpy hands to BLAS or LAPACK (einsum too, when it optimises)
BLAS_CALLS = {"dot", "vdot", "inner", "matmul", "tensordot", "einsum", "einsum_path", "multi_dot", "kron"}


def python_matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Plain Python floats, each sum in order: one rounding per multiply and per add."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for j in range(b.shape[1]):
            total = float(a[i, 0]) * float(b[0, j])
            for k in range(1, a.shape[1]):
                total = total + float(a[i, k]) * float(b[k, j])
            out[i, j] = total
    return out


def test_products_round_as_plain_python_arithmetic():
    rng = np.random.default_rng(0)
    for n, k, m in ((3, 3, 3), (7, 3, 7), (3, 7, 3), (7, 7, 1)):
        a, b = rng.normal(size=(20, n, k)), rng.normal(size=(20, k, m))
        got = matmul(a, b)
        for i in range(20):
            assert np.array_equal(got[i], python_matmul(a[i], b[i]))
        v = b[..., 0]
        assert np.array_equal(matvec(a, v), matmul(a, v[..., None])[..., 0])
    x = rng.normal(size=(50, 7))
    assert np.array_equal(row_norm(x), [np.sqrt(python_matmul(row[None], row[:, None])[0, 0]) for row in x])


def test_inverses_invert():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(30, 3, 3)) + 3 * np.eye(3)
    np.testing.assert_allclose(matmul(m, inv3(m)), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    angle = rng.uniform(-np.pi, np.pi, 30)
    t = np.zeros((30, 4, 4))
    t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1] = np.cos(angle), -np.sin(angle), np.sin(angle), np.cos(angle)
    t[:, 2, 2] = t[:, 3, 3] = 1.0
    t[:, :3, 3] = rng.normal(size=(30, 3))
    np.testing.assert_allclose(matmul(rigid_inverse(t), t), np.broadcast_to(np.eye(4), t.shape), atol=1e-12)


@pytest.mark.parametrize(
    "path", sorted(p for p in WORLD.glob("*.py") if p.name != "reference.py"), ids=lambda p: p.name
)
def test_the_world_makes_no_blas_call(path):
    """`@`, np.dot, np.linalg and friends are BLAS's or LAPACK's: the world's modules use `babblegen.world.exact`
    instead (reference.py, ManiSkill's own stepping kept for a test, is not the world's)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.BinOp | ast.AugAssign) and isinstance(node.op, ast.MatMult):
            found.append(f"line {node.lineno}: @")
        elif isinstance(node, ast.Attribute) and (node.attr in BLAS_CALLS or node.attr == "linalg"):
            found.append(f"line {node.lineno}: {node.attr}")
    assert not found, f"{path.name}: {found}"
