"""Collision checking for planning: the arm as spheres, the static world (table, floor, torso) as boxes.

The planner's hot path is "is this configuration (or this straight motion) free?". Approximating each link's
primitives by spheres makes that a handful of vectorised numpy operations over a whole batch of
configurations, which is simpler and faster here than driving a general collision library one pose at a
time. Objects on the table are deliberately not obstacles: touching them is the point of babbling.
"""

from __future__ import annotations

import functools

import numpy as np

from babblegen.shapes import Box
from babblegen.world.exact import matvec, row_norm
from babblegen.world.kinematics import ArmKinematics, Shape

CHUNK = 256  # configurations per batch of `SphereCollisionModel.in_collision` and `sphere_centres`


def _in_chunks(method):
    """``method(self, q)`` over ``CHUNK`` configurations of ``q`` at a time, the results joined along the batch.
    Each configuration's answer is computed alone (elementwise), so chunks change nothing but the speed: the
    temporaries stay in cache (a batch of 20,000 ran 6x slower whole)."""

    @functools.wraps(method)
    def chunked(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if len(q) <= CHUNK:
            return method(self, q)
        return np.concatenate([method(self, q[at : at + CHUNK]) for at in range(0, len(q), CHUNK)])

    return chunked


def shape_spheres(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres in the link frame, radii) covering a primitive.

    Cylinders become capsules inscribed in their length (spheres of the cylinder's radius spaced at most half
    a radius apart); boxes become a grid of spheres circumscribing equal cells no larger than the box's
    smallest side.
    """
    if shape.kind == "sphere":
        local, radii = np.zeros((1, 3)), np.array([shape.size[0]])
    elif shape.kind == "cylinder":
        r, length = shape.size
        half = max(length / 2 - r, 0.0)
        n = max(int(np.ceil(2 * half / (0.5 * r))) + 1, 1)
        local = np.zeros((n, 3))
        local[:, 2] = np.linspace(-half, half, n)
        radii = np.full(n, r)
    elif shape.kind == "box":
        size = np.asarray(shape.size)
        counts = np.maximum(np.ceil(size / size.min()), 1).astype(int)
        cell = size / counts
        axes = [(np.arange(c) + 0.5) * s - d / 2 for c, s, d in zip(counts, cell, size, strict=True)]
        local = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        radii = np.full(len(local), row_norm(cell) / 2)
    else:
        raise ValueError(shape.kind)
    centres = matvec(shape.origin[:3, :3], local) + shape.origin[:3, 3]
    return centres, radii


def box_distance(points: np.ndarray, box: Box) -> np.ndarray:
    """Distance from points (..., 3) to a box (0 inside)."""
    rot = np.asarray(box.rotation)
    local = matvec(rot.T, points - np.asarray(box.center))  # (points - centre) @ rot, summed in order
    outside = np.maximum(np.abs(local) - np.asarray(box.half_extents), 0.0)
    return row_norm(outside)


class SphereCollisionModel:
    """Batched validity checks for the arm against static boxes and itself."""

    def __init__(
        self,
        kin: ArmKinematics,
        obstacles: list[Box],
        margin: float = 0.01,
        self_margin: float = 0.005,
        body_exempt_links: tuple[str, ...] = (),
        self_exempt_pairs: tuple[tuple[str, str], ...] = (),
    ):
        self.kin = kin
        self.obstacles = list(obstacles)
        self.margin = margin
        centres, radii, link_idx = [], [], []
        for li, name in enumerate(kin.link_names):
            if li == 0:
                continue  # the fixed base is modelled by the obstacle boxes
            for shape in kin.urdf.links.get(name, []):
                c, r = shape_spheres(shape)
                centres.append(c)
                radii.append(r)
                link_idx.append(np.full(len(r), li))
        self.local = np.concatenate(centres)
        self.radii = np.concatenate(radii)
        self.link_of_sphere = np.concatenate(link_idx)
        exempt_idx = [kin.link_names.index(n) for n in body_exempt_links]
        self.world_mask = ~np.isin(self.link_of_sphere, exempt_idx)
        exempt = {frozenset(p) for p in self_exempt_pairs}
        ia, ib = np.triu_indices(len(self.radii), k=1)
        la, lb = self.link_of_sphere[ia], self.link_of_sphere[ib]
        names = kin.link_names
        keep = np.abs(la - lb) >= 2
        keep &= np.array([frozenset((names[a], names[b])) not in exempt for a, b in zip(la, lb, strict=True)])
        self.pair_a, self.pair_b = ia[keep], ib[keep]
        self.pair_reach = self.radii[self.pair_a] + self.radii[self.pair_b] + self_margin

    @_in_chunks
    def sphere_centres(self, q: np.ndarray) -> np.ndarray:
        """World centres of all spheres, shape (B, n_spheres, 3)."""
        tf = self.kin.link_transforms(q)[:, self.link_of_sphere]
        return matvec(tf[..., :3, :3], self.local) + tf[..., :3, 3]

    def collisions(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Per obstacle (and 'self'), whether each configuration of the batch collides with it."""
        pts = self.sphere_centres(q)
        out = {}
        for box in self.obstacles:
            d = box_distance(pts[:, self.world_mask], box)
            out[box.name] = (d < self.radii[self.world_mask] + self.margin).any(axis=1)
        dist = row_norm(pts[:, self.pair_a] - pts[:, self.pair_b])
        out["self"] = (dist < self.pair_reach).any(axis=1)
        return out

    @_in_chunks
    def in_collision(self, q: np.ndarray) -> np.ndarray:
        """(B,) True where a configuration touches an obstacle or itself."""
        return np.logical_or.reduce(list(self.collisions(q).values()))

    def motion_free(self, q0: np.ndarray, q1: np.ndarray, resolution: float = 0.03) -> bool:
        """Whether the straight joint-space motion q0 -> q1 is free, checked every `resolution` radians."""
        n = max(int(np.ceil(np.abs(q1 - q0).max() / resolution)), 1) + 1
        t = np.linspace(0.0, 1.0, n)[:, None]
        return not self.in_collision(q0 + t * (q1 - q0)).any()
