"""The baseline world model (`babblegen evaluate --model mlp`): per object and frame, one network over hand-made
features of its push frame.

- The arm's response to its commands: `ArmFilter` (babblegen/worldmodel/arm.py).
- `StepNet`, the objects' response to the arm and to each other, one frame at a time, one network shared by every
  object (`features`): in the object's push frame (`push_frame`: x from where the arm passes nearest to its centre),
  the arm's nearest collision spheres where they start and end the frame, its own last motion, height, turn in the
  frame and the table's edges, its own properties (shape one-hot, bounding box, mass, friction...:
  `property_inputs`), and the other objects' places, last motions, sizes and masses. It predicts whether the object
  moves this frame and, if so, by how much (x, y, yaw, z in its frame). Trained on every recorded frame with the
  true poses (teacher forcing); `rollout` runs it from the first frame on its own predictions.

It reads an object as a bounding box and a property vector, so it cannot tell an ell from a block of the same
extent; the graph network (babblegen/worldmodel/simulator.py), the default, reads the objects' surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from babblegen.worldmodel.arm import ArmFilter, ArmSpheres
from babblegen.worldmodel.episodes import PROPERTIES, PROPERTY, SUMMARY, EpisodeSet, EvaluationError, Scene
from babblegen.worldmodel.gated import GatedModel
from babblegen.worldmodel.poses import as_poses, object_state, wrap

NEAREST = 8  # arm spheres per object and frame the network sees (the nearest to it over the frame's motion)
POS, VEL = 10.0, 100.0  # positions in decimetres, motions per frame in centimetres: inputs near unit scale
BUSY_GAP = 0.1  # metres: the arm passes nearer than this to an object, a row worth learning from
QUIET = 8  # training keeps one in this many rows where nothing is near or moving, weighted by this
GATES = (
    -2.0,
    -1.5,
    -1.0,
    -0.5,
    0.0,
    0.5,
)  # the "moves" thresholds (logits) a model chooses among on its validation episodes
MOVING = 0.001  # metres (or radians / 10) in one frame: the object moves in that frame
# what an object sees of each other object's properties, beside its place and motion
OTHER = ("footprint_radius", "half_height", "mass", "static_friction", "dynamic_friction")
LENGTHS = ("footprint_radius", "half_height", "half_extent_x", "half_extent_y", "half_extent_z")
LOGS = {"volume": 1e-3, "mass": 1.0, "density": 1e3}  # inputs as log10 of the value in these units (litres, ...)


def property_inputs(objects: np.ndarray) -> np.ndarray:
    """(..., P) `object_vector`s as the step network reads them, near unit scale: the shape one-hot as is, lengths
    in decimetres, volume, mass and density as log10 (of litres, kg, tonnes / m^3), frictions and restitution as
    they are, the yaw symmetry in half turns."""
    out = np.array(objects, dtype=np.float64, copy=True)
    for name in LENGTHS:
        out[..., PROPERTY[name]] *= POS
    for name, unit in LOGS.items():
        out[..., PROPERTY[name]] = np.log10(np.maximum(out[..., PROPERTY[name]], 1e-12) / unit)
    out[..., PROPERTY["yaw_symmetry"]] /= np.pi
    return out


def scene_objects(scene: Scene, objects: np.ndarray | None, n: int) -> np.ndarray:
    """(N, K, P) the objects of N scenes: ``objects`` as given ((N, K, P), or one (K, P) for all), or the task's."""
    props = scene.properties if objects is None else np.asarray(objects, dtype=np.float64)
    return np.broadcast_to(props, (n, *props.shape[-2:]))


def sweep(
    now: np.ndarray, arm0: np.ndarray, arm1: np.ndarray, radii: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The arm's spheres relative to each object's centre over a frame: where they start and end (N, K, S, 3), the
    fraction of the way at which each passes nearest (N, K, S), and how near its surface passes then (N, K, S)."""
    rel0 = arm0[:, None] - now[:, :, None, :3]
    rel1 = arm1[:, None] - now[:, :, None, :3]
    seg = rel1 - rel0
    along = np.clip(-(rel0 * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-12), 0.0, 1.0)
    gap = np.linalg.norm(rel0 + along[..., None] * seg, axis=-1) - radii
    return rel0, rel1, along, gap


def push_frame(now: np.ndarray, arm0: np.ndarray, arm1: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(N, K) each object's push frame for a frame: x points from where the arm passes nearest (the sphere whose
    surface comes nearest) to the object's centre, seen from above; along the sphere's motion where it passes
    right over the centre. One frame for every shape: what is learned of a push from one side holds for all."""
    rel0, rel1, along, gap = sweep(now, arm0, arm1, radii)
    first = np.argmin(gap, axis=-1)[..., None]  # (N, K, 1)
    r0 = np.take_along_axis(rel0, first[..., None], axis=2)[:, :, 0]
    r1 = np.take_along_axis(rel1, first[..., None], axis=2)[:, :, 0]
    t = np.take_along_axis(along, first, axis=2)[..., 0, None]
    away = -(r0 + t * (r1 - r0))[..., :2]  # (N, K, 2): from the arm to the centre
    motion = (r1 - r0)[..., :2]
    use = np.where((np.linalg.norm(away, axis=-1) > 1e-3)[..., None], away, motion)
    return np.arctan2(use[..., 1], use[..., 0])


def features(
    scene: Scene,
    radii: np.ndarray,
    now: np.ndarray,
    before: np.ndarray,
    arm0: np.ndarray,
    arm1: np.ndarray,
    objects: np.ndarray | None,
    frame_yaw: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Inputs of the step network for N scenes at one frame: ``now`` and ``before`` (N, K, 4) the objects' states
    in this frame and the one before, ``arm0`` and ``arm1`` (N, S, 3) the arm's spheres in this frame and the next,
    ``objects`` the objects' `object_vector`s ((N, K, P); None: the task's), ``frame_yaw`` (N, K) each object's
    push frame (`push_frame`). Returns (N, K, F), one row per object, in its own push frame (see the module
    docstring), and (N, K) how near the arm's surface passes the object's centre this frame, metres."""
    n, k = now.shape[:2]
    objects = scene_objects(scene, objects, n)
    sym = objects[..., PROPERTY["yaw_symmetry"]]  # (N, K)
    cos, sin = np.cos(frame_yaw), np.sin(frame_yaw)

    def to_frame(v: np.ndarray) -> np.ndarray:
        """(N, K, ..., 2) world xy offsets, each in object k's frame."""
        shape = (n, k) + (1,) * (v.ndim - 3)
        cc, ss = cos.reshape(shape), sin.reshape(shape)
        return np.stack([cc * v[..., 0] + ss * v[..., 1], cc * v[..., 1] - ss * v[..., 0]], axis=-1)

    # the arm: its spheres relative to the object's centre, the nearest first over the segment each sweeps
    rel0, rel1, along, gap = sweep(now, arm0, arm1, radii)
    near = np.argsort(gap, axis=-1, kind="stable")[..., :NEAREST]  # (N, K, M)
    r0 = np.take_along_axis(rel0, near[..., None], axis=2)
    r1 = np.take_along_axis(rel1, near[..., None], axis=2)
    closest = r0 + np.take_along_axis(along, near, axis=2)[..., None] * (r1 - r0)  # where it passes nearest
    parts = [to_frame(r0[..., :2]), r0[..., 2:], to_frame(r1[..., :2]), r1[..., 2:], radii[near][..., None]]
    parts += [to_frame(closest[..., :2]), closest[..., 2:], np.take_along_axis(gap, near, axis=2)[..., None]]
    arm = np.concatenate(parts, axis=-1).reshape(n, k, -1) * POS
    # the object itself: its last motion, its height over resting, its turn in the frame, the table's edges, its
    # properties
    rest = scene.top + objects[..., PROPERTY["half_height"]]  # (N, K)
    motion = now - before
    period = np.where(sym > 0, sym, 2 * np.pi)
    order = np.where(sym > 0, 2 * np.pi / np.where(sym > 0, sym, 1.0), 0.0)
    turn = order * (now[..., 3] - frame_yaw)  # its own turn in the push's frame, modulo its symmetry
    own = np.concatenate(
        [
            to_frame(motion[:, :, None, :2])[:, :, 0] * VEL,
            wrap(motion[..., 3:4], period[..., None]) * VEL / 10,
            motion[..., 2:3] * VEL,
            (now[..., 2:3] - rest[..., None]) * POS,
            np.stack([np.cos(turn), np.sin(turn)], axis=-1) * (sym > 0)[..., None],
        ],
        axis=-1,
    )
    x0, x1, y0, y1 = scene.table
    edges = np.stack([now[..., 0] - x0, x1 - now[..., 0], now[..., 1] - y0, y1 - now[..., 1]], axis=-1) * POS
    props = property_inputs(objects[..., :SUMMARY])
    # the others, in the scene's order: where each stands, its last motion and height, its size and mass, in this
    # object's frame
    rel = now[:, None, :, :2] - now[:, :, None, :2]  # (N, K, K, 2): object j relative to object i
    vel = np.broadcast_to(motion[:, None, :, :2], rel.shape)
    high = np.broadcast_to((now[..., 2] - rest)[:, None, :, None], (n, k, k, 1))
    theirs = np.broadcast_to(props[:, None][..., [PROPERTY[p] for p in OTHER]], (n, k, k, len(OTHER)))
    pair = np.concatenate([to_frame(rel) * POS, to_frame(vel) * VEL, high * POS, theirs], axis=-1)
    pair = pair[:, ~np.eye(k, dtype=bool)].reshape(n, k, (k - 1) * (5 + len(OTHER)))
    which = np.broadcast_to(np.eye(k), (n, k, k))
    nearest = np.take_along_axis(gap, near[..., :1], axis=2)[..., 0]
    return np.concatenate([which, own, edges, props, pair, arm], axis=-1).astype(np.float32), nearest


def targets(
    scene: Scene, now: np.ndarray, after: np.ndarray, objects: np.ndarray | None, frame_yaw: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """What the step network learns for (N, K, 4) states in a frame and the next: the motion in the object's push
    frame ``frame_yaw`` (dx, dy in cm, dyaw in rad / 10, dz in cm), and whether it moves at all."""
    sym = scene_objects(scene, objects, len(now))[..., PROPERTY["yaw_symmetry"]]
    cos, sin = np.cos(frame_yaw), np.sin(frame_yaw)
    d = after - now
    dyaw = np.where(sym > 0, wrap(d[..., 3], np.where(sym > 0, sym, 2 * np.pi)), 0.0)
    out = np.stack(
        [
            (cos * d[..., 0] + sin * d[..., 1]) * VEL,
            (cos * d[..., 1] - sin * d[..., 0]) * VEL,
            dyaw * VEL / 10,
            d[..., 2] * VEL,
        ],
        axis=-1,
    )
    moving = (np.abs(out) > MOVING * VEL).any(axis=-1)
    return out.astype(np.float32), moving


def apply(now: np.ndarray, motion: np.ndarray, frame_yaw: np.ndarray) -> np.ndarray:
    """(N, K, 4) states after the step network's (N, K, 4) motions, each in its object's push frame ``frame_yaw``."""
    cos, sin = np.cos(frame_yaw), np.sin(frame_yaw)
    dx, dy = motion[..., 0] / VEL, motion[..., 1] / VEL
    out = now.copy()
    out[..., 0] += cos * dx - sin * dy
    out[..., 1] += sin * dx + cos * dy
    out[..., 3] += motion[..., 2] * 10 / VEL
    out[..., 2] += motion[..., 3] / VEL
    return out


class StepNet(nn.Module):
    """Per object and frame: a "moves" logit and the motion if it does (4 numbers, `targets`' units)."""

    def __init__(self, n_in: int, hidden: int = 256):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(n_in, hidden), nn.SiLU(), nn.Linear(hidden, hidden), nn.SiLU(), nn.Linear(hidden, 5)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(x)
        return out[..., 0], out[..., 1:]


@dataclass
class TrainSettings:
    """How a model trains: Adam steps on batches of rows, at most ``steps``, with early stopping: every ``check``
    steps the one-step loss on ``validation`` of the training episodes (held back from training) is measured, and
    the best weights are kept; training stops after ``patience`` checks without a better one. Every source's model
    thus trains as long as its own data supports."""

    steps: int = 12000
    check: int = 500
    patience: int = 4
    validation: float = 0.1
    batch: int = 512
    hidden: int = 256
    lr: float = 2e-3
    seed: int = 0


def training_rows(episodes: EpisodeSet, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """The step network's rows (inputs, targets, moving, weight) of every frame of every episode, with the true arm
    and object states."""
    scene = episodes.scene
    spheres = ArmSpheres(scene.robot)
    xs, ys, ms, ws = [], [], [], []
    for q, poses, objects in zip(episodes.states, episodes.poses, episodes.objects, strict=True):
        state = object_state(poses)
        before = np.concatenate([state[:1], state[:-2]])
        balls = spheres(q)
        yaw = push_frame(state[:-1], balls[:-1], balls[1:], spheres.radii)
        x, gap = features(scene, spheres.radii, state[:-1], before, balls[:-1], balls[1:], objects, yaw)
        y, m = targets(scene, state[:-1], state[1:], objects, yaw)
        _, was = targets(scene, before, state[:-1], objects, yaw)
        # quiet rows (nothing near or moving, before or now) teach little but "stays": keep one in QUIET
        busy = (gap < BUSY_GAP) | m | was | (m | was).any(axis=1, keepdims=True)
        keep = busy | (rng.random(busy.shape) < 1 / QUIET)
        xs.append(x[keep])
        ys.append(y[keep])
        ms.append(m[keep])
        ws.append(np.where(busy[keep], 1.0, QUIET))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ms).astype(np.float32), np.concatenate(ws)


def step_loss(net: StepNet, x: torch.Tensor, y: torch.Tensor, m: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Weighted "moves" cross-entropy, plus the motion's smooth L1 error on the rows that move."""
    logit, motion = net(x)
    loss = nn.functional.binary_cross_entropy_with_logits(logit, m, weight=w / w.mean())
    moving = m > 0
    if moving.any():
        loss = loss + nn.functional.smooth_l1_loss(motion[moving], y[moving])
    return loss


class WorldModel(GatedModel):
    """`ArmFilter` and `StepNet` together; `fit` on episodes, `predict` where objects end up."""

    kind = "mlp"

    def __init__(self, scene: Scene, arm: ArmFilter, net: StepNet, mean: np.ndarray, std: np.ndarray):
        self.scene, self.arm, self.net, self.mean, self.std = scene, arm, net, mean, std
        self.spheres = ArmSpheres(scene.robot)
        self.trained_steps = 0
        self.gate = 0.0  # a frame's motion is applied where the "moves" logit exceeds this

    @classmethod
    def fit(cls, episodes: EpisodeSet, settings: TrainSettings | None = None) -> WorldModel:
        s = settings or TrainSettings()
        torch.manual_seed(s.seed)
        rng = np.random.default_rng(s.seed)
        order = rng.permutation(len(episodes))
        n_val = int(len(episodes) * s.validation) if len(episodes) >= 10 else 0
        train, val = episodes.take(np.sort(order[n_val:])), episodes.take(np.sort(order[:n_val]))
        arm = ArmFilter.fit(train.actions, train.states)
        x, y, m, w = training_rows(train, rng)
        # an input that never varies in training (a shape no training object has) teaches nothing: read as 0
        mean, std = x.mean(axis=0), x.std(axis=0)
        std = np.where(std < 1e-6, np.inf, std + 1e-3).astype(np.float32)

        def tensors(rows: tuple[np.ndarray, ...]) -> list[torch.Tensor]:
            xr, *rest = rows
            return [torch.from_numpy(((xr - mean) / std).astype(np.float32))] + [torch.from_numpy(r) for r in rest]

        xt, yt, mt, wt = tensors((x, y, m, w.astype(np.float32)))
        val_rows = training_rows(val, rng) if n_val else None
        checks = tensors(tuple(r.astype(np.float32) for r in val_rows)) if val_rows is not None else None
        net = StepNet(x.shape[1], s.hidden)
        opt = torch.optim.AdamW(net.parameters(), lr=s.lr, weight_decay=1e-4)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=s.lr, total_steps=s.steps)
        best, best_state, since, batches = np.inf, None, 0, torch.zeros(0, dtype=torch.int64)
        per_epoch = max(len(x) - len(x) % s.batch, s.batch)
        step = best_step = 0
        for step in range(1, s.steps + 1):
            at = ((step - 1) * s.batch) % per_epoch
            if at == 0:
                batches = torch.from_numpy(rng.permutation(len(x)))
            idx = batches[at : at + s.batch]
            loss = step_loss(net, xt[idx], yt[idx], mt[idx], wt[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            if checks is not None and step % s.check == 0:
                with torch.no_grad():
                    value = float(step_loss(net, *checks))
                if value < best:
                    best, since, best_step = value, 0, step
                    best_state = {k: v.clone() for k, v in net.state_dict().items()}
                else:
                    since += 1
                    if since >= s.patience:
                        break
        model = cls(episodes.scene, arm, net, mean, std)
        if best_state is not None:
            net.load_state_dict(best_state)
            model.trained_steps = best_step
        else:
            model.trained_steps = step
        net.eval()
        if n_val:
            model.choose_gate(val, GATES)
        return model

    def rollout(
        self,
        first: list[np.ndarray],
        actions: list[np.ndarray],
        joints0: list[np.ndarray],
        objects: np.ndarray | list[np.ndarray] | None = None,
    ) -> np.ndarray:
        """Final (E, K, 4) states of episodes given their first poses (K, 7) (or (K, 4) states), commands (T, 7),
        first joints, and objects: per episode (K, P) `object_vector`s (``EpisodeSet.objects``; one (K, P) for
        all), None for the task's objects (the training scene's)."""
        lengths = np.array([len(a) for a in actions])
        horizon = int(lengths.max())
        e, k = len(actions), len(first[0])
        if k != len(self.scene.objects):
            raise EvaluationError(f"the model knows scenes of {len(self.scene.objects)} objects, not {k}")
        props = scene_objects(self.scene, None if objects is None else np.asarray(objects, dtype=np.float64), e)
        if props.shape[-1] != len(PROPERTIES):
            raise EvaluationError(f"objects need {len(PROPERTIES)} properties each, got {props.shape[-1]}")
        balls = self.spheres.paths(self.arm, actions, joints0, horizon)
        now = object_state(np.stack([as_poses(f) for f in first]))
        before = now.copy()
        final = now.copy()
        with torch.no_grad():
            for t in range(horizon - 1):
                live = np.flatnonzero(lengths - 1 > t)
                if not len(live):
                    break
                arm0, arm1 = balls[live, t], balls[live, t + 1]
                yaw = push_frame(now[live], arm0, arm1, self.spheres.radii)
                x, _ = features(self.scene, self.spheres.radii, now[live], before[live], arm0, arm1, props[live], yaw)
                z = (x.reshape(-1, x.shape[-1]) - self.mean) / self.std
                logit, motion = self.net(torch.from_numpy(z))
                motion = motion.numpy().reshape(len(live), k, 4) * (logit.numpy() > self.gate).reshape(len(live), k, 1)
                before[live] = now[live]
                now[live] = apply(now[live], motion, yaw)
                ended = live[lengths[live] - 2 == t]
                final[ended] = now[ended]
        final[lengths == 1] = now[lengths == 1]
        return final
