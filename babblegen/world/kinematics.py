"""The arm's kinematic model, read from its URDF: batched forward kinematics, Jacobian, position IK.

Everything is vectorised over a batch of joint configurations so that the planner can check a whole
straight-line motion in one call and IK can run several seeds at once. The URDF is the single source of
truth: the simulator loads the same file.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from babblegen.world.exact import inv3, matmul, matvec, row_norm


def _vec(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    return np.array([float(v) for v in text.split()] if text else default, dtype=np.float64)


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a rotation matrix (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def transform(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rpy_matrix(rpy)
    t[:3, 3] = xyz
    return t


def axis_rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations about a unit axis by a batch of angles (Rodrigues), shape (B, 3, 3)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * matmul(k, k)


@dataclass
class Shape:
    """A collision primitive in its link's frame: kind is box, sphere or cylinder (axis = local z)."""

    kind: str
    size: np.ndarray  # box: (x, y, z) full extents; sphere: (r,); cylinder: (r, length)
    origin: np.ndarray  # 4x4 pose in the link frame


@dataclass
class Joint:
    name: str
    parent: str
    child: str
    kind: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float


@dataclass
class UrdfModel:
    """Links (with collision shapes) and joints of a URDF, enough for kinematics and collision checking."""

    links: dict[str, list[Shape]] = field(default_factory=dict)
    joints: dict[str, Joint] = field(default_factory=dict)

    @classmethod
    def load(cls, path: str | Path) -> UrdfModel:
        root = ET.parse(path).getroot()
        model = cls()
        for link in root.findall("link"):
            shapes = []
            for col in link.findall("collision"):
                org = col.find("origin")
                pose = transform(
                    _vec(org.get("xyz") if org is not None else None, (0, 0, 0)),
                    _vec(org.get("rpy") if org is not None else None, (0, 0, 0)),
                )
                geo = col.find("geometry")[0]
                if geo.tag == "box":
                    shapes.append(Shape("box", _vec(geo.get("size"), ()), pose))
                elif geo.tag == "sphere":
                    shapes.append(Shape("sphere", np.array([float(geo.get("radius"))]), pose))
                elif geo.tag == "cylinder":
                    size = np.array([float(geo.get("radius")), float(geo.get("length"))])
                    shapes.append(Shape("cylinder", size, pose))
                else:
                    raise ValueError(f"unsupported collision geometry {geo.tag!r} in link {link.get('name')}")
            model.links[link.get("name")] = shapes
        for j in root.findall("joint"):
            org, lim = j.find("origin"), j.find("limit")
            axis_el = j.find("axis")
            axis = _vec(axis_el.get("xyz") if axis_el is not None else None, (1, 0, 0))
            model.joints[j.get("name")] = Joint(
                name=j.get("name"),
                parent=j.find("parent").get("link"),
                child=j.find("child").get("link"),
                kind=j.get("type"),
                origin=transform(
                    _vec(org.get("xyz") if org is not None else None, (0, 0, 0)),
                    _vec(org.get("rpy") if org is not None else None, (0, 0, 0)),
                ),
                axis=axis / row_norm(axis),
                lower=float(lim.get("lower", -np.pi)) if lim is not None else 0.0,
                upper=float(lim.get("upper", np.pi)) if lim is not None else 0.0,
            )
        return model

    def chain(self, base: str, tip: str) -> list[Joint]:
        """Joints from base to tip, in order."""
        by_child = {j.child: j for j in self.joints.values()}
        out, link = [], tip
        while link != base:
            if link not in by_child:
                raise ValueError(f"{tip!r} is not below {base!r} in the URDF")
            out.append(by_child[link])
            link = by_child[link].parent
        return out[::-1]


@dataclass(frozen=True)
class ReachShell:
    """Where the tool can be at all: within ``reach`` of the circle the shoulder-lift axis sweeps around the pan
    axis (world frame, metres). Beyond it no configuration gets the tool there; inside it IK may still fail."""

    pan_xy: tuple[float, float]
    lift_radius: float
    shoulder_z: float
    reach: float

    @classmethod
    def of(cls, kin: ArmKinematics) -> ReachShell:
        """The shell of an arm: its joint frames at zero, and the tool's distance from the shoulder-lift axis with
        the arm stretched out."""
        pos = kin.link_frames(np.zeros(kin.dof))[1][0]
        _, stretched = kin.link_frames(np.clip(np.zeros(kin.dof), kin.lower, kin.upper))
        return cls(
            (float(pos[1, 0]), float(pos[1, 1])),
            float(row_norm(pos[2, :2] - pos[1, :2])),
            float(pos[2, 2]),
            float(row_norm(stretched[0, -1] - stretched[0, 2])),
        )

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance from points (..., 3) to the nearest place the shoulder-lift joint can be."""
        points = np.asarray(points, dtype=np.float64)
        horizontal = row_norm(points[..., :2] - np.asarray(self.pan_xy))
        return np.hypot(horizontal - self.lift_radius, points[..., 2] - self.shoulder_z)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether each point (..., 3) is within reach."""
        return self.distance(points) <= self.reach


class ArmKinematics:
    """Serial chain from `base` to `tip` with batched FK, tool Jacobian and damped least-squares IK.

    The base frame is the world frame (the torso is fixed at the origin).
    """

    def __init__(self, urdf: UrdfModel, base: str, tip: str):
        self.urdf = urdf
        self.chain = urdf.chain(base, tip)
        self.active = [j for j in self.chain if j.kind in ("revolute", "continuous")]
        self.joint_names = [j.name for j in self.active]
        self.link_names = [base] + [j.child for j in self.chain]
        self.lower = np.array([j.lower for j in self.active])
        self.upper = np.array([j.upper for j in self.active])
        self.dof = len(self.active)
        self._active_link_index = np.array(
            [li for li, j in enumerate(self.chain, start=1) if j.kind in ("revolute", "continuous")]
        )
        self._active_axes = np.stack([j.axis for j in self.active])
        self._steps = [self._step(j) for j in self.chain]

    @staticmethod
    def _step(joint: Joint) -> tuple[np.ndarray | None, np.ndarray | None, object]:
        """Precomputed work of one joint: origin offset, origin rotation, and how its motion rotates."""
        o_rot, o_pos = joint.origin[:3, :3], joint.origin[:3, 3]
        axis: object = None
        if joint.kind in ("revolute", "continuous"):
            principal = np.flatnonzero(np.abs(joint.axis) > 1 - 1e-12)
            if len(principal) == 1:
                a = int(principal[0])
                axis = ((a + 1) % 3, (a + 2) % 3, float(np.sign(joint.axis[a])))
            else:
                axis = joint.axis
        return (
            o_pos.copy() if o_pos.any() else None,
            None if np.allclose(o_rot, np.eye(3)) else o_rot.copy(),
            axis,
        )

    @property
    def limits(self) -> np.ndarray:
        """(dof, 2) lower and upper joint limits in radians."""
        return np.stack([self.lower, self.upper], axis=1)

    def link_transforms(self, q: np.ndarray) -> np.ndarray:
        """World poses of every link on the chain, shape (B, n_links, 4, 4), for q of shape (B, dof)."""
        rot, pos = self.link_frames(q)
        b, n = rot.shape[:2]
        out = np.zeros((b, n, 4, 4))
        out[:, :, :3, :3] = rot
        out[:, :, :3, 3] = pos
        out[:, :, 3, 3] = 1.0
        return out

    def link_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (B, n_links, 3, 3) and origins (B, n_links, 3) of every link on the chain.

        Joints about a principal axis (all of this arm's) rotate by mixing two columns, which keeps a
        single-configuration call at a few dozen small numpy operations: the planner calls it per state.
        """
        q = np.atleast_2d(q)
        b = q.shape[0]
        rots = np.empty((b, len(self.link_names), 3, 3))
        poss = np.empty((b, len(self.link_names), 3))
        rot = np.broadcast_to(np.eye(3), (b, 3, 3)).copy()
        pos = np.zeros((b, 3))
        rots[:, 0], poss[:, 0] = rot, pos
        qi = 0
        for li, (o_pos, o_rot, axis) in enumerate(self._steps, start=1):
            if o_pos is not None:
                pos = pos + matvec(rot, o_pos)
            if o_rot is not None:
                rot = matmul(rot, o_rot)
            if axis is not None:
                angle = q[:, qi]
                qi += 1
                if isinstance(axis, tuple):
                    i, j, sign = axis
                    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None] * sign
                    ci, cj = rot[:, :, i], rot[:, :, j]
                    rot = rot.copy()
                    rot[:, :, i] = c * ci + s * cj
                    rot[:, :, j] = c * cj - s * ci
                else:
                    rot = matmul(rot, axis_rotations(axis, angle))
            rots[:, li], poss[:, li] = rot, pos
        return rots, poss

    def tool_position(self, q: np.ndarray) -> np.ndarray:
        """Tool point (origin of the tip link) in the world frame, shape (B, 3)."""
        return self.link_frames(q)[1][:, -1]

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positional Jacobian of the tool point, (B, 3, dof), and the tool positions (B, 3)."""
        rot, pos = self.link_frames(q)
        tool = pos[:, -1]
        idx = self._active_link_index
        axes_w = matvec(rot[:, idx], self._active_axes)
        cols = np.cross(axes_w, tool[:, None, :] - pos[:, idx])
        return cols.transpose(0, 2, 1), tool

    def inverse_position(
        self,
        target: np.ndarray,
        seeds: np.ndarray,
        tol: float = 2e-3,
        max_iters: int = 100,
        damping: float = 0.05,
        bias_gain: float = 0.05,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Position-only IK from several seeds at once (damped least squares, limits enforced by clipping).

        Iterates until at least one seed has converged (callers pick among the converged ones).

        The 4 redundant degrees of freedom are pulled gently towards each seed in the Jacobian's null space, so
        solutions stay close to where the arm is. Returns the joint solutions (M, dof) and their remaining
        position errors (M,) in metres: `inverse_positions` for one target.
        """
        q, err = self.inverse_positions(np.asarray(target, dtype=np.float64)[None], np.asarray(seeds)[None], tol,
                                        max_iters, damping, bias_gain)  # fmt: skip
        return q[0], err[0]

    def inverse_positions(
        self,
        targets: np.ndarray,
        seeds: np.ndarray,
        tol: float = 2e-3,
        max_iters: int = 100,
        damping: float = 0.05,
        bias_gain: float = 0.05,
    ) -> tuple[np.ndarray, np.ndarray]:
        """`inverse_position` for B targets (B, 3) at once, each from its own M seeds ``seeds`` (B, M, dof): each
        target's seeds iterate until one of them converges, as if it were alone (every product is row by row, so a
        target's answer does not depend on the others). Returns (B, M, dof) solutions and (B, M) errors."""
        b, m = seeds.shape[:2]
        q = np.clip(np.array(seeds, dtype=np.float64).reshape(b * m, -1), self.lower, self.upper)
        bias = q.copy()
        goal = np.repeat(np.asarray(targets, dtype=np.float64), m, axis=0)
        err = np.full(b * m, np.inf)
        live = np.ones(b, dtype=bool)
        eye3, eye_n = np.eye(3), np.eye(self.dof)
        for _ in range(max_iters):
            rows = np.flatnonzero(np.repeat(live, m))
            if not len(rows):
                break
            jac, tool = self.jacobian(q[rows])
            e = goal[rows] - tool
            err[rows] = row_norm(e)
            going = (err[rows] > tol).reshape(-1, m).all(axis=1)
            live[np.flatnonzero(live)[~going]] = False  # one of its seeds converged: that target stops here
            keep = np.repeat(going, m)
            rows, jac, e = rows[keep], jac[keep], e[keep]
            if not len(rows):
                break
            # BLAS-free products (babblegen.world.exact): the same solution on any CPU
            jac_t = jac.transpose(0, 2, 1)
            jpinv = matmul(jac_t, inv3(matmul(jac, jac_t) + damping**2 * eye3))
            step = matvec(jpinv, e)
            null = eye_n - matmul(jpinv, jac)
            step += bias_gain * matvec(null, bias[rows] - q[rows])
            # cap the step to keep the linearisation honest
            norm = row_norm(step)[:, None]
            step *= np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))
            q[rows] = np.clip(q[rows] + step, self.lower, self.upper)
        rows = np.flatnonzero(np.repeat(live, m))
        if len(rows):  # ran out of iterations: the error where they ended
            err[rows] = row_norm(goal[rows] - self.tool_position(q[rows]))
        return q.reshape(b, m, -1), err.reshape(b, m)
