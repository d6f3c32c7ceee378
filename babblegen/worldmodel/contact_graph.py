"""The graph a learned simulator reads at one frame: the objects as points on their collision surfaces
(`babblegen.shapes.ObjectSpec.surface`), the arm as its collision spheres sweeping through the frame, and the
table top; edges where they come near each other.

Per scene and object (a node), everything is read in the object's **push frame**: centred on the object, its x
axis pointing from where the arm's surface passes nearest this frame to the object's centre, seen from above (along
the sphere's motion when it passes right over it). One frame for every shape and every side: a push learned from
one side holds for all, and turning the whole scene about the vertical turns nothing the object sees but the table's
edges.

- **node**: the object's last motion (translation, rotation vector), its up axis, its height above the table, its
  mass, frictions, restitution and volume, and the spread of its surface points (second moments);
- **arm edges**: the ``ARM_EDGES`` nearest pairs of an arm sphere (of the ``ARM_SPHERES`` passing nearest the
  object) and a surface point, over the segment the sphere sweeps this frame: the point and its normal, where the
  sphere passes nearest relative to the point, the sphere's motion, radius and gap; and where the sphere goes the
  frame after (its motion then, and how near it passes the point, up to ``NEXT_NEAR``): a strike lasts less than
  a frame, and whether the arm goes on into the object or leaves it decides whether it starts; and where it came
  from the frame before (its motion then, how near it passed the point where the object was then, and when in that
  frame): when in its frame a strike came sets how fast the struck object goes on; masked beyond ``ARM_REACH``;
- **table edges**: the object's ``TABLE_EDGES`` lowest surface points: where they are, their normals, their height
  above the table and how far inside its edges (up to ``EDGE_NEAR``: an edge farther away reads the same);
- **object edges**: per other object, the ``OBJECT_EDGES`` nearest pairs of points (among each one's
  ``OBJECT_NEAR`` points nearest the other's centre): both points and normals, the other's motion relative to this
  one's, its mass and friction; masked beyond ``OBJECT_REACH``.

The targets are each object's rigid motion over the frame (translation of its origin and rotation vector, in its
push frame); `apply_motion` turns predicted motions back into poses. A scene where the arm passes nowhere near an
object and nothing moves is not a row at all (`active`): nothing in it moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from babblegen.worldmodel.poses import quat_conjugate, quat_from_rotvec, quat_multiply, rotate, rotvec_of, turn_z

ARM_SPHERES = 6  # arm spheres per object whose sweep is searched for edges: those passing nearest its centre
ARM_EDGES = 8  # sphere-point edges per object
ARM_REACH = 0.04  # metres between a sphere's surface and a surface point: an edge
TABLE_EDGES = 4  # an object's lowest surface points
OBJECT_NEAR = 8  # points of each object (nearest the other's centre) among which object-object pairs are found
OBJECT_EDGES = 4  # point pairs per pair of objects
OBJECT_REACH = 0.03  # metres between two objects' surface points: an edge
EDGE_NEAR = 0.1  # metres inside the table's edges: beyond this the edges are not an input (they read this)
NEXT_NEAR = 0.1  # metres between a sphere's surface and a point the frame after: farther reads the same
MOVING = (0.0005, 0.005)  # metres, radians in one frame: an object moving
POS, VEL, ROT = 10.0, 100.0, 10.0  # positions in dm, motions per frame in cm, rotations in rad / 10: near unit scale

NODE_FEATURES, ARM_FEATURES, TABLE_FEATURES, OBJECT_FEATURES = 19, 24, 8, 18


@dataclass
class Surfaces:
    """Per scene and object: its surface points and normals in its own frame (N, K, P, 3), its bounding radius about
    its origin (N, K), and its physical properties (N, K, 5): log10 mass (kg), static and dynamic friction,
    restitution, log10 volume (litres)."""

    points: np.ndarray
    normals: np.ndarray
    radius: np.ndarray
    physics: np.ndarray

    def take(self, idx: np.ndarray) -> Surfaces:
        return Surfaces(self.points[idx], self.normals[idx], self.radius[idx], self.physics[idx])


@dataclass
class Graph:
    """The inputs of N scenes of K objects at one frame (see the module docstring), float32; ``frame`` (N, K) each
    object's push frame's yaw."""

    node: np.ndarray  # (N, K, NODE_FEATURES)
    arm: np.ndarray  # (N, K, ARM_EDGES, ARM_FEATURES)
    arm_mask: np.ndarray  # (N, K, ARM_EDGES)
    table: np.ndarray  # (N, K, TABLE_EDGES, TABLE_FEATURES)
    obj: np.ndarray  # (N, K, K - 1, OBJECT_EDGES, OBJECT_FEATURES)
    obj_mask: np.ndarray  # (N, K, K - 1, OBJECT_EDGES)
    frame: np.ndarray  # (N, K)

    def take(self, idx: np.ndarray) -> Graph:
        return Graph(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    @staticmethod
    def concat(parts: list[Graph]) -> Graph:
        return Graph(*(np.concatenate([getattr(p, f) for p in parts]) for f in Graph.__dataclass_fields__))


def others(k: int) -> np.ndarray:
    """(K, K - 1) the other objects of each object, in the scene's order."""
    return np.array([[j for j in range(k) if j != i] for i in range(k)], dtype=np.int64).reshape(k, k - 1)


def motion_of(before: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) twice: the world-frame translation of each object's origin and its rotation vector between (..., 7)
    poses ``before`` and ``after``."""
    turn = quat_multiply(after[..., 3:], quat_conjugate(before[..., 3:]))
    return after[..., :3] - before[..., :3], rotvec_of(turn)


def moving(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(...) whether each object moves between (..., 7) poses (over `MOVING`)."""
    shift, turn = motion_of(before, after)
    return (np.linalg.norm(shift, axis=-1) > MOVING[0]) | (np.linalg.norm(turn, axis=-1) > MOVING[1])


def _segment_gap(points: np.ndarray, a0: np.ndarray, a1: np.ndarray, radii: np.ndarray):
    """How near spheres (centres ``a0`` -> ``a1``, ``radii``) pass points: broadcast shapes; returns (the fraction
    of the way where each passes nearest, where its centre is then, the gap between its surface and the point)."""
    seg = a1 - a0
    along = np.clip(((points - a0) * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-12), 0.0, 1.0)
    at = a0 + along[..., None] * seg
    return along, at, np.linalg.norm(points - at, axis=-1) - radii


def _smallest(values: np.ndarray, count: int) -> np.ndarray:
    """Indices of the ``count`` smallest values along the last axis (all of them when there are no more), in no
    particular order: each node sums over its edges, whose order does not matter."""
    if values.shape[-1] <= count:
        return np.broadcast_to(np.arange(values.shape[-1]), values.shape).copy()
    return np.argpartition(values, count - 1, axis=-1)[..., :count]


def _arm_edges(world, world_prev, rel_f, normal_f, sp, s0, s1, s2, r, yaw) -> tuple[np.ndarray, np.ndarray]:
    """Arm edges of B objects: their surface points (B, P, 3) in the world now and a frame before (``world_prev``),
    and relative to their centres and their normals in their push frames (``yaw`` (B,)); the M candidate spheres'
    sweeps ``s0`` -> ``s1``, on to ``s2`` the frame after and from ``sp`` the frame before (B, M, 3), and radii
    (B, M). Returns the `ARM_EDGES` nearest pairs' features (B, EA, ARM_FEATURES) and gaps (B, EA)."""
    b, p = world.shape[:2]
    t, c, gap = _segment_gap(world[:, None], s0[:, :, None], s1[:, :, None], r[..., None])  # (B, M, P)
    flat = gap.reshape(b, -1)
    pick = _smallest(flat, ARM_EDGES)  # (B, EA)
    m_of, p_of = np.divmod(pick, p)
    rows = np.arange(b)[:, None]
    edge_gap = flat[rows, pick]
    centre = c.reshape(b, -1, 3)[rows, pick]  # the sphere's centre where it passes nearest
    to_frame = -yaw[:, None]
    _, _, next_gap = _segment_gap(world[rows, p_of], s1[rows, m_of], s2[rows, m_of], r[rows, m_of])
    # the frame before: how near and when the sphere passed the point where the object was then (a strike's time
    # within its frame, which sets how fast an object struck then goes now)
    prev_along, _, prev_gap = _segment_gap(world_prev[rows, p_of], sp[rows, m_of], s0[rows, m_of], r[rows, m_of])
    feats = np.concatenate(
        [
            rel_f[rows, p_of] * POS,
            normal_f[rows, p_of],
            turn_z(centre - world[rows, p_of], to_frame) * POS,
            turn_z((s1 - s0)[rows, m_of], to_frame) * POS,
            r[rows, m_of][..., None] * POS,
            edge_gap[..., None] * VEL,
            t.reshape(b, -1)[rows, pick][..., None],
            turn_z((s2 - s1)[rows, m_of], to_frame) * POS,
            np.minimum(next_gap, NEXT_NEAR)[..., None] * VEL,
            turn_z((s0 - sp)[rows, m_of], to_frame) * POS,
            np.minimum(prev_gap, NEXT_NEAR)[..., None] * VEL,
            prev_along[..., None],
        ],
        axis=-1,
    )
    return feats, edge_gap


def _object_edges(mine, theirs, rel_f, normal_f, their_normals, rel_shift, physics, yaw):
    """Object edges of B (object, other object) pairs: both objects' surface points in the world (B, P, 3), this
    one's relative to its centre and its normals in its push frame (``yaw`` (B,)), the other's normals (world), the
    other's last motion relative to this one's (B, 3) and its physics (B, 5). Returns the `OBJECT_EDGES` nearest
    point pairs' features (B, EO, OBJECT_FEATURES) and distances (B, EO)."""
    b = len(mine)
    rows = np.arange(b)[:, None]
    centre_a, centre_b = mine.mean(axis=1, keepdims=True), theirs.mean(axis=1, keepdims=True)
    pa = _smallest(((mine - centre_b) ** 2).sum(-1), OBJECT_NEAR)  # (B, Q): this one's points facing the other
    pb = _smallest(((theirs - centre_a) ** 2).sum(-1), OBJECT_NEAR)
    a_w, b_w = mine[rows, pa], theirs[rows, pb]  # (B, Q, 3)
    dist2 = ((a_w[:, :, None] - b_w[:, None]) ** 2).sum(-1).reshape(b, -1)  # (B, Q * Q)
    pick = _smallest(dist2, OBJECT_EDGES)  # (B, EO)
    ia, ib = np.divmod(pick, OBJECT_NEAR)
    ea, eb = pa[rows, ia], pb[rows, ib]  # point indices
    d = np.sqrt(dist2[rows, pick])
    to_frame = -yaw[:, None]
    feats = np.concatenate(
        [
            rel_f[rows, ea] * POS,
            normal_f[rows, ea],
            turn_z(theirs[rows, eb] - mine[rows, ea], to_frame) * VEL,
            turn_z(their_normals[rows, eb], to_frame),
            np.broadcast_to(turn_z(rel_shift[:, None], to_frame), (b, OBJECT_EDGES, 3)) * VEL,
            d[..., None] * VEL,
            np.broadcast_to(physics[:, None, :2], (b, OBJECT_EDGES, 2)),
        ],
        axis=-1,
    )
    return feats, d


def active(
    poses: np.ndarray, before: np.ndarray, arm0: np.ndarray, arm1: np.ndarray, radii: np.ndarray, bound: np.ndarray
) -> np.ndarray:
    """(N,) whether anything can happen in each scene this frame: the arm sweeps within `ARM_REACH` of an object's
    bounding sphere, or an object moves."""
    _, _, gap = _segment_gap(poses[:, :, None, :3], arm0[:, None], arm1[:, None], radii)  # (N, K, S)
    near = (gap.min(axis=-1) - bound < ARM_REACH).any(axis=1)
    return near | moving(before, poses).any(axis=1)


def build(
    poses: np.ndarray,
    before: np.ndarray,
    arm0: np.ndarray,
    arm1: np.ndarray,
    arm2: np.ndarray,
    radii: np.ndarray,
    surfaces: Surfaces,
    table: tuple[float, float, float, float],
    top: float,
    arm_prev: np.ndarray | None = None,
) -> Graph:
    """The graph of N scenes at one frame: ``poses`` and ``before`` (N, K, 7) the objects' poses now and a frame
    before, ``arm0``, ``arm1`` and ``arm2`` (N, S, 3) the arm's spheres now, a frame later and two frames later (the
    last frame's again at an episode's end), ``arm_prev`` a frame before (None: as now, the first frame's),
    ``table`` its top's x0, x1, y0, y1 and ``top`` its height."""
    n, k = poses.shape[:2]
    f32 = np.float32
    arm_prev = arm0 if arm_prev is None else arm_prev
    poses, before, arm_prev, arm0, arm1, arm2, radii = (
        np.asarray(v, dtype=f32) for v in (poses, before, arm_prev, arm0, arm1, arm2, radii)
    )
    surfaces = Surfaces(*(np.asarray(v, dtype=f32) for v in (surfaces.points, surfaces.normals, surfaces.radius,
                                                            surfaces.physics)))  # fmt: skip
    pos, quat = poses[..., :3], poses[..., 3:]
    world = rotate(quat[:, :, None], surfaces.points) + pos[:, :, None]  # (N, K, P, 3)
    normal = rotate(quat[:, :, None], surfaces.normals)

    # the push frame: from where the sphere passing nearest the centre does so, to the centre
    along, at, gap_c = _segment_gap(pos[:, :, None], arm0[:, None], arm1[:, None], radii)  # (N, K, S)
    near = _smallest(gap_c, ARM_SPHERES)  # (N, K, M), in no particular order
    first = np.argmin(gap_c, axis=-1)
    closest = np.take_along_axis(at, first[..., None, None], axis=2)[:, :, 0]  # (N, K, 3)
    away = (pos - closest)[..., :2]
    sweep = (arm1 - arm0)[np.arange(n)[:, None], first][..., :2]
    use = np.where((np.linalg.norm(away, axis=-1) > 1e-3)[..., None], away, sweep)
    yaw = np.arctan2(use[..., 1], use[..., 0])

    def framed(v: np.ndarray) -> np.ndarray:
        """World vectors (N, K, ..., 3) in each object's push frame."""
        return turn_z(v, -yaw.reshape(n, k, *([1] * (v.ndim - 3))))

    rel = world - pos[:, :, None]  # (N, K, P, 3)
    rel_f, normal_f = framed(rel), framed(normal)

    # arm edges: the nearest (sphere, point) pairs over the spheres' sweeps, for the objects the arm comes near
    take = (np.arange(n)[:, None, None], np.arange(k)[None, :, None])
    arm = np.zeros((n, k, ARM_EDGES, ARM_FEATURES), dtype=f32)
    arm_mask = np.zeros((n, k, ARM_EDGES), dtype=bool)
    rows, objs = np.nonzero(gap_c.min(axis=-1) - surfaces.radius < ARM_REACH)
    if len(rows):
        m = near[rows, objs]  # (B, M)
        sp, s0 = arm_prev[rows[:, None], m], arm0[rows[:, None], m]
        s1, s2 = arm1[rows[:, None], m], arm2[rows[:, None], m]  # (B, M, 3)
        then = before[rows, objs]
        world_prev = rotate(then[:, None, 3:], surfaces.points[rows, objs]) + then[:, None, :3]
        feats, gaps = _arm_edges(world[rows, objs], world_prev, rel_f[rows, objs], normal_f[rows, objs], sp, s0, s1,
                                 s2, radii[m], yaw[rows, objs])  # fmt: skip
        arm[rows, objs], arm_mask[rows, objs] = feats, gaps < ARM_REACH

    # table edges: the lowest points
    low = _smallest(world[..., 2], TABLE_EDGES)  # (N, K, ET)
    x0, x1, y0, y1 = table
    wl = world[take + (low,)]
    inside = np.minimum.reduce([wl[..., 0] - x0, x1 - wl[..., 0], wl[..., 1] - y0, y1 - wl[..., 1]])
    inside = np.minimum(inside, EDGE_NEAR)  # farther in than this, an edge is nowhere near: read the same
    table_edges = np.concatenate(
        [rel_f[take + (low,)] * POS, normal_f[take + (low,)], (wl[..., 2:] - top) * VEL, inside[..., None] * POS],
        axis=-1,
    )

    # the node: its last motion, up axis, height, physics, spread
    shift, turn = motion_of(before, poses)
    up = framed(rotate(quat, np.array([0.0, 0.0, 1.0]))[:, :, None])[:, :, 0]
    spread = np.stack(
        [
            (rel_f[..., 0] ** 2).mean(-1),
            (rel_f[..., 1] ** 2).mean(-1),
            (rel_f[..., 0] * rel_f[..., 1]).mean(-1),
            (rel_f[..., 2] ** 2).mean(-1),
        ],
        axis=-1,
    )
    node = np.concatenate(
        [
            framed(shift[:, :, None])[:, :, 0] * VEL,
            framed(turn[:, :, None])[:, :, 0] * ROT,
            up,
            (pos[..., 2:] - top) * POS,
            surfaces.physics,
            spread * POS * POS,
        ],
        axis=-1,
    )

    # object edges: per other object within reach, the nearest point pairs among each one's points nearest the
    # other's centre
    other = others(k)
    obj = np.zeros((n, k, k - 1, OBJECT_EDGES, OBJECT_FEATURES), dtype=f32)
    obj_mask = np.zeros((n, k, k - 1, OBJECT_EDGES), dtype=bool)
    if k > 1:
        apart = np.linalg.norm(pos[:, other] - pos[:, :, None], axis=-1)  # (N, K, K-1)
        reach = surfaces.radius[:, :, None] + surfaces.radius[:, other] + OBJECT_REACH
        rows, objs, slots = np.nonzero(apart < reach)
        if len(rows):
            js = other[objs, slots]
            feats, d = _object_edges(
                world[rows, objs], world[rows, js], rel_f[rows, objs], normal_f[rows, objs], normal[rows, js],
                shift[rows, js] - shift[rows, objs], surfaces.physics[rows, js], yaw[rows, objs],
            )  # fmt: skip
            obj[rows, objs, slots], obj_mask[rows, objs, slots] = feats, d < OBJECT_REACH
    return Graph(node.astype(f32), arm, arm_mask, table_edges.astype(f32), obj.astype(f32), obj_mask, yaw)


def targets(before: np.ndarray, after: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What a learned simulator predicts of (N, K, 7) poses one frame apart: each object's motion in its push frame
    ``frame`` (N, K), (N, K, 6) translation in cm and rotation vector in rad / 10; and whether it moves."""
    shift, turn = motion_of(before, after)
    out = np.concatenate([turn_z(shift, -frame) * VEL, turn_z(turn, -frame) * ROT], axis=-1)
    return out.astype(np.float32), moving(before, after)


def apply_motion(poses: np.ndarray, motion: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(N, K, 7) poses after (N, K, 6) motions (`targets`' units), each in its object's push frame ``frame``."""
    shift = turn_z(motion[..., :3] / VEL, frame)
    turn = turn_z(motion[..., 3:] / ROT, frame)
    out = poses.copy()
    out[..., :3] += shift
    q = quat_multiply(quat_from_rotvec(turn), poses[..., 3:])
    out[..., 3:] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out
