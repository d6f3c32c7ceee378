"""Where a learned simulator's displacements fall short: one frame at a time against rolled out, and its "moves" gate.

For a saved model (`babblegen evaluate --save-models`) and test datasets it prints, per test set:

- **one frame** (teacher forced: the true poses in, the next frame's motion out), over the frames in which an
  object truly moves, split by whether an arm sphere is near it (an arm edge in its graph) or not: the median ratio
  of the predicted to the true translation, the ratio of their sums, the median cosine between them, and the share
  of those frames in which the "moves" gate lets the motion through;
- **rolled out** (as `babblegen evaluate` predicts), for each gate variant: F1 of "moves", the error as a multiple
  of "nothing moves", and the median ratio of the predicted to the true displacement of the moved objects.

A gate variant ``MOVING/NEAR`` lowers the gate by ``MOVING`` (a logit) for an object that moved in the frame before
and by ``NEAR`` for one with an arm sphere near; ``0/0`` is the model as it is.

    python benchmarks/rollout_lengths.py --model evaluation/models/noveb_4000attempts_equal-attempts_repeat1.pt \\
        --test varied=dev/var_noveb,dev/var_random_waypoints --test heldout=dev/ho_noveb,dev/ho_random_waypoints \\
        --gates 0/0,1/0,100/0,0/2,100/2
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from babblegen.worldmodel.cli import _named_dirs
from babblegen.worldmodel.episodes import MOVED, EpisodeSet, read_dataset
from babblegen.worldmodel.gnn import tensors
from babblegen.worldmodel.metrics import score
from babblegen.worldmodel.poses import object_state
from babblegen.worldmodel.simulator import LearnedSimulator, episode_rows


class ShiftedGate(nn.Module):
    """The model's network with its "moves" logit raised by ``moving`` for objects that moved in the frame before
    and by ``near`` for those with an arm sphere near: the same as lowering the gate for them."""

    def __init__(self, net: nn.Module, moving: float, near: float):
        super().__init__()
        self.net, self.moving, self.near = net, moving, near

    def forward(self, x: dict) -> torch.Tensor:
        out = self.net(x).clone()
        moved = (x["node"][..., :3].norm(dim=-1) > 1e-5).float()  # its last translation (cm) over 0.1 micrometre
        near = x["arm_mask"].any(-1).float()
        out[..., 0] += self.moving * moved + self.near * near
        return out


def one_frame(model: LearnedSimulator, episodes: EpisodeSet) -> dict:
    graph, motion, moves = episode_rows(episodes, model.spheres, model.arm)
    x = tensors(graph)
    with torch.no_grad():
        out = np.concatenate(
            [model.net({k: v[a : a + 2048] for k, v in x.items()}).numpy() for a in range(0, len(motion), 2048)],
            axis=1,
        )
    logit, pred, true = out[..., 0].mean(0), out[..., 1:4].mean(0), motion[..., :3]
    near = graph.arm_mask.any(-1)
    p_len, t_len = np.linalg.norm(pred, axis=-1), np.linalg.norm(true, axis=-1)
    found = {}
    for label, pick in (("arm near", moves & near), ("free", moves & ~near)):
        cosine = (pred[pick] * true[pick]).sum(-1) / np.maximum(p_len[pick] * t_len[pick], 1e-9)
        found[label] = {
            "frames": int(pick.sum()),
            "true cm per frame": round(float(np.median(t_len[pick])), 2),
            "length ratio": round(float(np.median(p_len[pick] / np.maximum(t_len[pick], 1e-9))), 3),
            "sum ratio": round(float(p_len[pick].sum() / max(t_len[pick].sum(), 1e-9)), 3),
            "cosine": round(float(np.median(cosine)), 3),
            "gate lets through": round(float((logit[pick] > model.gate).mean()), 3),
        }
    found["still frames the gate lets through"] = round(float((logit[~moves] > model.gate).mean()), 4)
    return found


def rolled_out(model: LearnedSimulator, episodes: EpisodeSet) -> dict:
    pred = model.predict(episodes)
    s = score(pred, episodes, np.zeros((len(episodes.scene.objects), 2)))["all"]
    first, final = object_state(episodes.first), object_state(episodes.final)
    moved = np.linalg.norm(final[..., :3] - first[..., :3], axis=-1) > MOVED
    p_len = np.linalg.norm(pred[..., :2] - first[..., :2], axis=-1)[moved]
    t_len = np.linalg.norm(final[..., :2] - first[..., :2], axis=-1)[moved]
    return {
        "f1": round(s["f1"], 3),
        "error": round(s["ratio"], 3),
        "length ratio": round(float(np.median(p_len / np.maximum(t_len, 1e-9))), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--test", action="append", required=True, type=_named_dirs, help="NAME=DIR[,DIR...]")
    parser.add_argument("--gates", default="0/0", help="comma-separated MOVING/NEAR gate variants")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = LearnedSimulator.load(args.model)
    net = model.net
    tests = {name: EpisodeSet.union([read_dataset(d).episodes for d in dirs]) for name, dirs in args.test}
    print(f"gate {model.gate}", flush=True)
    for name, episodes in tests.items():
        print(json.dumps({"test": name, "one frame": one_frame(model, episodes)}), flush=True)
    for variant in args.gates.split(","):
        moving, near = (float(v) for v in variant.split("/"))
        model.net = ShiftedGate(net, moving, near)
        row = {"gate lowered (moving/near)": variant}
        row.update({name: rolled_out(model, episodes) for name, episodes in tests.items()})
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
