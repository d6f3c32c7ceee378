"""Shape facts from an object's parts, against distances and numbers worked out here by hand: every surface point
lies on the collision surface PhysX builds from the parts (on one part's surface, outside every other part)."""

from __future__ import annotations

import numpy as np
import pytest

from babblegen.objects import ObjectSampler
from babblegen.shapes import SURFACE_POINTS, ObjectSpec

GRAY = (0.5, 0.5, 0.5, 1.0)


def box_distance(p: np.ndarray, centre, half) -> np.ndarray:
    q = np.abs(p - np.asarray(centre)) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def part_distance(p: np.ndarray, part) -> np.ndarray:
    """Signed distance to one part, written out here from its kind and size (not the module's own)."""
    c, s = np.asarray(part.offset), part.size
    d = p - c
    if part.kind == "box":
        return box_distance(p, c, s)
    if part.kind == "sphere":
        return np.linalg.norm(d, axis=1) - s[0]
    if part.kind == "cylinder":  # axis z: radius s[0], half height s[1]
        radial, axial = np.hypot(d[:, 0], d[:, 1]) - s[0], np.abs(d[:, 2]) - s[1]
        outside = np.hypot(np.maximum(radial, 0), np.maximum(axial, 0))
        return outside + np.minimum(np.maximum(radial, axial), 0)
    if part.kind == "capsule":  # axis x: the segment between the caps' centres, widened by the radius
        nearest = np.stack([np.clip(d[:, 0], -s[1], s[1]), np.zeros(len(d)), np.zeros(len(d))], axis=1)
        return np.linalg.norm(d - nearest, axis=1) - s[0]
    from scipy.spatial import ConvexHull  # a hull: its face planes

    eq = ConvexHull(np.asarray(part.vertices)).equations
    return (d @ eq[:, :3].T + eq[:, 3]).max(axis=1)


def drawn_objects() -> list[ObjectSpec]:
    """Objects as runs draw them: 40 varied (every shape kind, hulls of random points among them), 20 held out."""
    varied, heldout = ObjectSampler("varied", 4, seed=3), ObjectSampler("heldout", 4, seed=3)
    return [o for a in range(10) for o in varied.draw(a)] + [o for a in range(5) for o in heldout.draw(a)]


@pytest.mark.parametrize(
    "spec",
    [
        ObjectSpec("box", "box", (0.05, 0.03, 0.04), GRAY, 0.1, (0, 0)),
        ObjectSpec("can", "cylinder", (0.03, 0.06), GRAY, 0.1, (0, 0)),
        ObjectSpec("ball", "sphere", (0.04,), GRAY, 0.1, (0, 0)),
        ObjectSpec("capsule", "capsule", (0.02, 0.03), GRAY, 0.1, (0, 0)),
        ObjectSpec("dumbbell", "dumbbell", (0.025, 0.01, 0.05), GRAY, 0.1, (0, 0)),
        ObjectSpec("ell", "ell", (0.06, 0.05, 0.015, 0.02), GRAY, 0.1, (0, 0)),
        ObjectSpec("tee", "tee", (0.05, 0.03, 0.01, 0.02), GRAY, 0.1, (0, 0)),
        ObjectSpec(
            "hull",
            "hull",
            (0.03, 0.03, 0.03),
            GRAY,
            0.1,
            (0, 0),
            vertices=(
                (0.03, 0, -0.02),
                (-0.03, 0.02, -0.03),
                (0, -0.03, 0.03),
                (0.01, 0.03, 0.0),
                (-0.02, -0.02, 0.02),
            ),
        ),  # fmt: skip
    ]
    + drawn_objects(),
    ids=lambda s: s.shape,
)
def test_surface_points_lie_on_the_collision_surface(spec: ObjectSpec):
    """On the surface of one part (to 1e-9 m) and on or outside every other (a point inside another part would be
    inside the object, not on its surface); spread over it (no two within 2 mm), the normals unit vectors pointing
    out of the part the point lies on."""
    points, normals = spec.surface()
    assert points.shape == normals.shape == (SURFACE_POINTS, 3)
    dist = np.stack([part_distance(points, part) for part in spec.parts()])  # (parts, P)
    on = np.abs(dist) < 1e-9
    assert on.any(axis=0).all()
    assert (dist > -1e-9).all()
    np.testing.assert_allclose(spec.signed_distance(points), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    part = np.argmax(on, axis=0)
    for i, (p, n) in enumerate(zip(points, normals, strict=True)):  # a step along the normal leaves the part
        assert part_distance((p + 1e-4 * n)[None], spec.parts()[part[i]])[0] == pytest.approx(1e-4, abs=2e-5)
    gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(len(points))
    assert gaps.min() > 0.002
    # every side is covered: the points reach the bounding box's faces
    np.testing.assert_allclose(np.abs(points).max(axis=0), spec.half_extents, atol=0.01)
    again, _ = spec.surface()
    np.testing.assert_array_equal(points, again)


def test_shape_facts_by_hand():
    """A tee of a 10 x 2 cm bar along x and a 2 x 6 cm bar from its middle, 4 cm tall: its bounding box 10 x 8 cm
    centred, its far corners sqrt(5^2 + 4^2) cm out, its volume the two bars'; a dumbbell's footprint reaches a ball
    radius past the balls' centres; a capsule's bounding box its radius plus its straight half along x."""
    tee = ObjectSpec("t", "tee", (0.05, 0.03, 0.01, 0.02), GRAY, 0.1, (0, 0))
    np.testing.assert_allclose(tee.half_extents, [0.05, 0.04, 0.02])
    assert tee.footprint_radius == pytest.approx(np.hypot(0.05, 0.04))
    assert tee.volume == pytest.approx(8 * 0.05 * 0.01 * 0.02 + 8 * 0.01 * 0.03 * 0.02)
    assert tee.yaw_symmetry == pytest.approx(2 * np.pi) and tee.half_height == pytest.approx(0.02)
    dumbbell = ObjectSpec("d", "dumbbell", (0.025, 0.01, 0.05), GRAY, 0.1, (0, 0))
    assert dumbbell.footprint_radius == pytest.approx(0.075) and dumbbell.yaw_symmetry == pytest.approx(np.pi)
    np.testing.assert_allclose(dumbbell.half_extents, [0.075, 0.025, 0.025])
    capsule = ObjectSpec("c", "capsule", (0.02, 0.03), GRAY, 0.1, (0, 0))
    np.testing.assert_allclose(capsule.half_extents, [0.05, 0.02, 0.02])
    assert ObjectSpec("b", "box", (0.04, 0.04, 0.01), GRAY, 0.1, (0, 0)).yaw_symmetry == pytest.approx(np.pi / 2)
    assert ObjectSpec("s", "sphere", (0.04,), GRAY, 0.1, (0, 0)).yaw_symmetry == 0.0


def test_farthest_points_chooses_as_the_plain_loop_does():
    """`farthest_points` (coordinate rows, about 3x faster) picks exactly what the plain loop over
    ``np.linalg.norm`` picks, so surfaces, and models trained on them, are what they were; and its picks cover the
    cloud: every point lies within the smallest gap between picks of one of them."""
    from babblegen.shapes import farthest_points

    def plain(points: np.ndarray, n: int) -> np.ndarray:
        chosen = [int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
        nearest = np.linalg.norm(points - points[chosen[0]], axis=1)
        for _ in range(min(n, len(points)) - 1):
            chosen.append(int(np.argmax(nearest)))
            nearest = np.minimum(nearest, np.linalg.norm(points - points[chosen[-1]], axis=1))
        return np.array(chosen)

    rng = np.random.default_rng(3)
    for m in (5, 64, 700, 3072):
        points = rng.standard_normal((m, 3)) * rng.random(3) * 0.2 + rng.random(3)
        picks = farthest_points(points, 64)
        assert np.array_equal(picks, plain(points, 64))
        assert len(set(picks.tolist())) == min(m, 64)
        chosen = points[picks]
        gaps = np.linalg.norm(chosen[:, None] - chosen[None], axis=-1) + np.eye(len(chosen)) * 1e9
        cover = np.linalg.norm(points[:, None] - chosen[None], axis=-1).min(axis=1)
        assert cover.max() <= gaps.min() + 1e-12
