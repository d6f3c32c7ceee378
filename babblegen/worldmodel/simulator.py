"""The learned simulator `babblegen evaluate` trains by default: an ensemble of graph networks over the objects'
collision surfaces, the arm's collision spheres and the table (babblegen/worldmodel/contact_graph.py,
babblegen/worldmodel/gnn.py), rolled out frame by frame on its own predictions.

- The arm's joints come from the commands alone (`ArmFilter`), and its collision spheres from the joints.
- Each frame, every scene where the arm comes near an object or something moves is a graph; the ensemble's
  members each predict, per object, whether it moves and its rigid motion; the rollout applies the members' mean
  (mean "moves" logit over the gate, mean motion) and keeps how far the members disagree.
- Trained on every recorded frame with the true poses and joints (teacher forcing), with early stopping on a tenth
  of the training episodes held back, which also choose the "moves" gate that tells moved objects best.

`LearnedSimulator.save` writes a model a user can keep; `load` reads it back (see babblegen/worldmodel/api.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from babblegen.shapes import ObjectSpec
from babblegen.worldmodel import contact_graph as cg
from babblegen.worldmodel.arm import ArmFilter, ArmSpheres
from babblegen.worldmodel.episodes import PROPERTIES, PROPERTY, SUMMARY, EpisodeSet, EvaluationError, Scene
from babblegen.worldmodel.gated import GatedModel
from babblegen.worldmodel.gnn import GraphNet, tensors
from babblegen.worldmodel.poses import as_poses, object_state, quat_conjugate, quat_multiply

GATES = (-1.5, -1.0, -0.5, 0.0, 0.5, 1.0)  # the "moves" thresholds (logits) a model chooses among
FORMAT = 3  # the saved model's layout (2: arm edges read the frame after; 3: and the frame before)


@dataclass
class GraphSettings:
    """How the ensemble trains: Adam steps on batches of ``batch`` scene frames, at most ``steps``, every
    ``check`` steps the one-step loss on the ``validation`` share of the training episodes (held back), the best
    weights kept, stopped after ``patience`` checks without a better one."""

    members: int = 5
    hidden: int = 48
    steps: int = 8000
    check: int = 400
    patience: int = 3
    validation: float = 0.1
    batch: int = 128
    lr: float = 2e-3
    seed: int = 0
    threads: int = 0  # torch threads while training (0: torch's choice)
    motion_noise: float = 0.8  # std of Gaussian noise on the objects' last motion inputs in training (cm, rad / 10)


def surfaces(objects: np.ndarray) -> cg.Surfaces:
    """The `contact_graph.Surfaces` of (..., K, P) object vectors (`episodes.object_vector`)."""
    n_points = (len(PROPERTIES) - SUMMARY) // 6
    points = objects[..., SUMMARY : SUMMARY + 3 * n_points].reshape(*objects.shape[:-1], n_points, 3)
    normals = objects[..., SUMMARY + 3 * n_points :].reshape(*objects.shape[:-1], n_points, 3)
    physics = np.stack(
        [
            np.log10(np.maximum(objects[..., PROPERTY["mass"]], 1e-6)),
            objects[..., PROPERTY["static_friction"]],
            objects[..., PROPERTY["dynamic_friction"]],
            objects[..., PROPERTY["restitution"]],
            np.log10(np.maximum(objects[..., PROPERTY["volume"]] * 1e3, 1e-9)),
        ],
        axis=-1,
    )
    return cg.Surfaces(points, normals, np.linalg.norm(points, axis=-1).max(axis=-1), physics)


def episode_rows(
    episodes: EpisodeSet, spheres: ArmSpheres, arm: ArmFilter
) -> tuple[cg.Graph, np.ndarray, np.ndarray] | None:
    """Every active frame of every episode, with the true poses and the arm where ``arm`` puts it from the commands
    (as a rollout sees it): its graph, and per object its motion to the next frame and whether it moves; None when
    no frame is active."""
    scene = episodes.scene
    graphs, motions, moves = [], [], []
    for a, q, poses, objects in zip(episodes.actions, episodes.states, episodes.poses, episodes.objects, strict=True):
        balls = spheres(arm.run(a, q[0]))
        now, after = poses[:-1], poses[1:]
        before = np.concatenate([poses[:1], poses[:-2]])
        surf = surfaces(np.broadcast_to(objects, (len(now), *objects.shape)))
        live = np.flatnonzero(cg.active(now, before, balls[:-1], balls[1:], spheres.radii, surf.radius))
        if not len(live):
            continue
        g = cg.build(
            now[live], before[live], balls[:-1][live], balls[1:][live], np.concatenate([balls[2:], balls[-1:]])[live],
            spheres.radii, surf.take(live), scene.table, scene.top, np.concatenate([balls[:1], balls[:-2]])[live],
        )  # fmt: skip
        y, m = cg.targets(now[live], after[live], g.frame)
        graphs.append(g)
        motions.append(y)
        moves.append(m)
    if not graphs:
        return None
    return cg.Graph.concat(graphs), np.concatenate(motions), np.concatenate(moves)


def loss_of(out: torch.Tensor, motion: torch.Tensor, moves: torch.Tensor) -> torch.Tensor:
    """Per member: the "moves" cross-entropy plus the motion's smooth L1 error on the objects that move; summed
    over members."""
    logit, pred = out[..., 0], out[..., 1:]
    target = moves.expand_as(logit)
    loss = nn.functional.binary_cross_entropy_with_logits(logit, target, reduction="none").mean(dim=(1, 2))
    if moves.any():
        err = nn.functional.smooth_l1_loss(pred, motion.expand_as(pred), reduction="none").sum(-1)
        loss = loss + (err * moves).sum(dim=(1, 2)) / moves.sum()
    return loss.sum()


class LearnedSimulator(GatedModel):
    """The ensemble and the arm filter; `fit` on episodes, `predict` where objects end up, `rollout` any movement."""

    kind = "graph"

    def __init__(self, scene: Scene, arm: ArmFilter, net: GraphNet, settings: GraphSettings):
        self.scene, self.arm, self.net, self.settings = scene, arm, net, settings
        self.spheres = ArmSpheres(scene.robot)
        self.gate = 0.0
        self.trained_steps = 0
        self.train_seconds = 0.0

    @classmethod
    def fit(
        cls, episodes: EpisodeSet, settings: GraphSettings | None = None, progress: Callable[[int], None] | None = None
    ) -> LearnedSimulator:
        """Train on ``episodes``; ``progress``, if given, is told the steps taken every ``check`` steps."""
        s = settings or GraphSettings()
        started = time.perf_counter()
        if s.threads:
            torch.set_num_threads(s.threads)
        torch.manual_seed(s.seed)
        rng = np.random.default_rng(s.seed)
        order = rng.permutation(len(episodes))
        n_val = int(len(episodes) * s.validation) if len(episodes) >= 10 else 0
        train, val = episodes.take(np.sort(order[n_val:])), episodes.take(np.sort(order[:n_val]))
        spheres = ArmSpheres(episodes.scene.robot)
        net = GraphNet(s.members, len(episodes.scene.objects), s.hidden)
        arm = ArmFilter.fit(train.actions, train.states)
        rows = episode_rows(train, spheres, arm)
        if rows is None:  # the arm came near no object: nothing moves, as far as this model knows
            model = cls(episodes.scene, arm, net.eval(), s)
            model.gate, model.train_seconds = np.inf, time.perf_counter() - started
            return model
        graph, motion, moves = rows
        net.scale.fit(graph)
        x, y, mv = tensors(graph), torch.from_numpy(motion), torch.from_numpy(moves.astype(np.float32))
        checks = episode_rows(val, spheres, arm) if n_val else None
        if checks is not None:
            vg, vy, vm = checks
            checks = (tensors(vg), torch.from_numpy(vy), torch.from_numpy(vm.astype(np.float32)))
        opt = torch.optim.AdamW(net.parameters(), lr=s.lr, weight_decay=1e-4)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=s.lr, total_steps=s.steps)
        best, best_state, since, best_step = np.inf, None, 0, 0
        rows = len(motion)
        batches = torch.zeros(0, dtype=torch.int64)
        per_epoch = max(rows - rows % s.batch, s.batch)
        step = 0
        for step in range(1, s.steps + 1):
            at = ((step - 1) * s.batch) % per_epoch
            if at == 0:
                batches = torch.from_numpy(rng.permutation(rows))
            idx = batches[at : at + s.batch]
            batch = {k: v[idx] for k, v in x.items()}
            if s.motion_noise:  # a rollout feeds on its own motion: learn from motions a little off
                batch["node"] = batch["node"].clone()
                batch["node"][..., :6] += s.motion_noise * torch.randn(batch["node"][..., :6].shape)
            loss = loss_of(net(batch), y[idx], mv[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            if progress is not None and step % s.check == 0:
                progress(step)
            if checks is not None and step % s.check == 0:
                with torch.no_grad():
                    value = float(_batched_loss(net, *checks))
                if value < best:
                    best, since, best_step = value, 0, step
                    best_state = {k: v.clone() for k, v in net.state_dict().items()}
                else:
                    since += 1
                    if since >= s.patience:
                        break
        if best_state is not None:
            net.load_state_dict(best_state)
        net.eval()
        model = cls(episodes.scene, arm, net, s)
        model.trained_steps = best_step if best_state is not None else step
        if n_val:
            model.choose_gate(val, GATES)
        model.train_seconds = time.perf_counter() - started
        return model

    def rollout(
        self,
        first: list[np.ndarray],
        actions: list[np.ndarray],
        joints0: list[np.ndarray],
        objects: np.ndarray | list[np.ndarray] | None = None,
        spread: bool = False,
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Final (E, K, 4) states of episodes given their first poses (K, 7) (or upright (K, 4) states), commands
        (T, 7), first joints, and objects: per episode (K, P) object vectors (``EpisodeSet.objects``; one (K, P) for
        all; None: the task's). With ``spread``, also (E, K) how far the members disagree: per object the sum over
        frames of the spread (std) of their predicted translations, cm."""
        final, disagree = self.rollout_poses(first, actions, joints0, objects)
        final = object_state(final)
        return (final, disagree) if spread else final

    def rollout_poses(
        self, first, actions, joints0, objects=None, replay: tuple[list, list] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """`rollout`'s final (E, K, 7) poses and the members' spread (E, K). ``replay`` (a diagnosis: how much of
        the error a frame holds): per episode its recorded (T, K, 7) poses and (T - 1, K) which objects' motion over
        which frames is the recorded one, applied to where the rollout has the object, in place of the model's."""
        lengths = np.array([len(a) for a in actions])
        horizon = int(lengths.max())
        e, k = len(actions), len(first[0])
        if k != len(self.scene.objects):
            raise EvaluationError(f"the model knows scenes of {len(self.scene.objects)} objects, not {k}")
        props = self.scene.properties if objects is None else np.asarray(objects, dtype=np.float64)
        props = np.broadcast_to(props, (e, *props.shape[-2:]))
        if props.shape[-1] != len(PROPERTIES):
            raise EvaluationError(f"objects need {len(PROPERTIES)} properties each, got {props.shape[-1]}")
        surf = surfaces(props)
        balls = self.spheres.paths(self.arm, actions, joints0, horizon)
        now = np.stack([as_poses(f) for f in first])
        before = now.copy()
        final = now.copy()
        disagree = np.zeros((e, k))
        radii = self.spheres.radii
        with torch.no_grad():
            for t in range(horizon - 1):
                live = lengths - 1 > t
                if not live.any():
                    break
                idx = np.flatnonzero(live)
                act = cg.active(now[idx], before[idx], balls[idx, t], balls[idx, t + 1], radii, surf.radius[idx])
                rows = idx[act]
                previous = before[rows]
                before[idx] = now[idx]
                if len(rows):
                    g = cg.build(
                        now[rows], previous, balls[rows, t], balls[rows, t + 1], balls[rows, min(t + 2, horizon - 1)],
                        radii, surf.take(rows),
                        self.scene.table, self.scene.top, balls[rows, max(t - 1, 0)],
                    )  # fmt: skip
                    out = self.net(tensors(g)).numpy()  # (M, R, K, 7)
                    motion = out[..., 1:].mean(axis=0)
                    motion = motion * (out[..., 0].mean(axis=0) > self.gate)[..., None]
                    disagree[rows] += np.linalg.norm(out[..., 1:4].std(axis=0), axis=-1)
                    now[rows] = cg.apply_motion(now[rows], motion, g.frame)
                if replay is not None:
                    _replay(now, before, idx, t, *replay)
                ended = idx[lengths[idx] - 2 == t]
                final[ended] = now[ended]
        final[lengths == 1] = now[lengths == 1]
        return final, disagree

    # --- keeping a model -------------------------------------------------------------------------------------
    def save(self, path: Path) -> Path:
        """Write the model to ``path`` (a torch file): weights, arm filter, gate, scene and settings."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(
            {
                "format": FORMAT,
                "kind": self.kind,
                "state": self.net.state_dict(),
                "objects": len(self.scene.objects),
                "arm": self.arm.coef,
                "gate": self.gate,
                "trained_steps": self.trained_steps,
                "settings": asdict(self.settings),
                "scene": {
                    "task": self.scene.task,
                    "objects": [{**o.factors(), "xy": list(o.xy)} for o in self.scene.specs],
                    "table": list(self.scene.table),
                    "top": self.scene.top,
                    "robot": self.scene.robot,
                },
            },
            path,
        )
        return path

    @classmethod
    def load(cls, path: Path) -> LearnedSimulator:
        data = torch.load(Path(path), map_location="cpu", weights_only=False)
        if not isinstance(data, dict) or data.get("kind") != cls.kind:
            raise EvaluationError(f"{path} is not a babblegen learned simulator")
        if data.get("format") != FORMAT:
            raise EvaluationError(
                f"{path} is a learned simulator of format {data.get('format')}; this babblegen reads format {FORMAT}: "
                "train it again (babblegen evaluate --save-models DIR)"
            )
        sc = data["scene"]
        scene = Scene(
            sc["task"], tuple(ObjectSpec.from_record(o) for o in sc["objects"]), tuple(sc["table"]), sc["top"],
            sc["robot"],
        )  # fmt: skip
        stored = data["settings"]
        if stored.get("residual"):  # measured and not kept: 2026-12-06-learned-simulator-dev-settings.md, run E
            raise EvaluationError(f"{path} predicts changes of motion, which this babblegen does not read: train again")
        settings = GraphSettings(**{k: v for k, v in stored.items() if k in GraphSettings.__dataclass_fields__})
        net = GraphNet(settings.members, data["objects"], settings.hidden)
        net.load_state_dict(data["state"])
        net.eval()
        model = cls(scene, ArmFilter(data["arm"]), net, settings)
        model.gate, model.trained_steps = float(data["gate"]), int(data["trained_steps"])
        return model


def first_moving_frames(poses: np.ndarray, count: int) -> np.ndarray:
    """(T - 1, K) each object's first ``count`` frames of motion in (T, K, 7) recorded poses: from the first frame it
    moves over (`contact_graph.moving`), moving or not after it."""
    moves = cg.moving(poses[:-1], poses[1:])
    out = np.zeros_like(moves)
    for k in range(moves.shape[1]):
        start = np.flatnonzero(moves[:, k])
        if len(start):
            out[start[0] : start[0] + count, k] = True
    return out


def _replay(now, before, idx, t, recorded: list[np.ndarray], frames: list[np.ndarray]) -> None:
    """Where ``frames`` marks frame ``t`` of an object of the live episodes ``idx``, its pose ``now`` becomes its
    pose ``before`` moved as the recording moves it over that frame (`rollout_poses`' ``replay``)."""
    for e in idx:
        if t >= len(frames[e]):
            continue
        for k in np.flatnonzero(frames[e][t]):
            a, b = recorded[e][t, k], recorded[e][t + 1, k]
            now[e, k, :3] = before[e, k, :3] + (b[:3] - a[:3])
            q = quat_multiply(quat_multiply(b[3:], quat_conjugate(a[3:])), before[e, k, 3:])
            now[e, k, 3:] = q / np.linalg.norm(q)


def _batched_loss(net: GraphNet, x: dict, y: torch.Tensor, mv: torch.Tensor, chunk: int = 2048) -> float:
    """The loss over every row, in chunks (weighted by their sizes)."""
    total, n = 0.0, len(y)
    for at in range(0, n, chunk):
        sl = slice(at, at + chunk)
        part = {k: v[sl] for k, v in x.items()}
        total += float(loss_of(net(part), y[sl], mv[sl])) * min(chunk, n - at)
    return total / max(n, 1)
