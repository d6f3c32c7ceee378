"""The graph network of the learned simulator, as an ensemble: ``members`` networks of one architecture whose
weights are stacked, so that one batched matrix product runs them all on the same inputs.

Per scene (see babblegen/worldmodel/contact_graph.py for the inputs), two rounds of message passing, GNS / FIGNet
style, with plain torch (a sum over a fixed number of masked edges per node needs no scatter):

1. each object's node is encoded; messages from its arm edges and its table edges (an MLP of each edge's features)
   are summed and update it;
2. messages along its object edges (an MLP of the edge's features and the other object's latent from round 1) are
   summed and update it again;

then a decoder reads each object's latent: a "moves" logit and its motion (translation, rotation vector) in its
push frame. Inputs are standardised with the training rows' means and spreads (`Standardiser`).

torch_geometric would bring scatter operations and a batching scheme; with every node holding a fixed number of
edges (masked where absent), dense tensors carry the same graph with no dependency and no index bookkeeping.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from babblegen.worldmodel.contact_graph import (
    ARM_FEATURES,
    NODE_FEATURES,
    OBJECT_FEATURES,
    TABLE_FEATURES,
    Graph,
    others,
)

OUTPUTS = 7  # a "moves" logit, then translation (3) and rotation vector (3)


class Linear(nn.Module):
    """``members`` linear maps at once: (N, in) or (members, N, in) -> (members, N, out)."""

    def __init__(self, members: int, n_in: int, n_out: int, bias: bool = True):
        super().__init__()
        bound = 1 / np.sqrt(n_in)
        self.weight = nn.Parameter(torch.empty(members, n_in, n_out).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(members, 1, n_out).uniform_(-bound, bound)) if bias else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = torch.matmul(x, self.weight)
        return out if self.bias is None else out + self.bias


class MLP(nn.Module):
    """Linear, SiLU, ..., Linear, for every member."""

    def __init__(self, members: int, sizes: list[int]):
        super().__init__()
        self.layers = nn.ModuleList(Linear(members, a, b) for a, b in zip(sizes[:-1], sizes[1:], strict=True))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = nn.functional.silu(x)
        return x


class Standardiser(nn.Module):
    """Per input kind, the training rows' mean and spread (an input that never varied reads 0)."""

    def __init__(self) -> None:
        super().__init__()
        for name, size in (("node", NODE_FEATURES), ("arm", ARM_FEATURES), ("table", TABLE_FEATURES)):
            self.register_buffer(f"{name}_mean", torch.zeros(size))
            self.register_buffer(f"{name}_std", torch.ones(size))
        self.register_buffer("obj_mean", torch.zeros(OBJECT_FEATURES))
        self.register_buffer("obj_std", torch.ones(OBJECT_FEATURES))

    def fit(self, graph: Graph) -> None:
        """Means and spreads over ``graph``'s rows (edges: the unmasked ones)."""
        pairs = (
            ("node", graph.node.reshape(-1, NODE_FEATURES)),
            ("arm", graph.arm[graph.arm_mask]),
            ("table", graph.table.reshape(-1, TABLE_FEATURES)),
            ("obj", graph.obj[graph.obj_mask]),
        )
        for name, rows in pairs:
            if len(rows) < 2:
                continue
            mean, std = rows.mean(axis=0), rows.std(axis=0)
            std = np.where(std < 1e-6, np.inf, std + 1e-3)
            getattr(self, f"{name}_mean").copy_(torch.from_numpy(mean.astype(np.float32)))
            getattr(self, f"{name}_std").copy_(torch.from_numpy(std.astype(np.float32)))

    def __call__(self, name: str, x: torch.Tensor) -> torch.Tensor:
        return (x - getattr(self, f"{name}_mean")) / getattr(self, f"{name}_std")


class GraphNet(nn.Module):
    """The ensemble's networks: `forward` maps a batch of graphs to (members, N, K, OUTPUTS)."""

    def __init__(self, members: int, objects: int, hidden: int = 64):
        super().__init__()
        h, m = hidden, members
        self.members, self.hidden = members, hidden
        self.register_buffer("other", torch.from_numpy(others(objects)))
        self.scale = Standardiser()
        self.node = MLP(m, [NODE_FEATURES, h, h])
        self.arm = MLP(m, [ARM_FEATURES, h, h])
        self.table = MLP(m, [TABLE_FEATURES, h, h])
        self.update1 = MLP(m, [3 * h, h, h])
        self.obj_in = Linear(m, OBJECT_FEATURES, h)
        self.obj_from = Linear(m, h, h, bias=False)
        self.obj_out = Linear(m, h, h)
        self.update2 = MLP(m, [2 * h, h, h])
        self.decode = MLP(m, [h, h, OUTPUTS])

    def forward(self, g: dict[str, torch.Tensor]) -> torch.Tensor:
        n, k = g["node"].shape[:2]
        m, h = self.members, self.hidden

        def edges(mlp: MLP, name: str, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
            """(M, N, K, H): the sum of the messages of (N, K, E, F) edges."""
            e = x.shape[2]
            out = mlp(self.scale(name, x).reshape(-1, x.shape[-1])).reshape(m, n, k, e, h)
            if mask is not None:
                out = out * mask.reshape(1, n, k, e, 1)
            return out.sum(dim=3)

        node = self.node(self.scale("node", g["node"]).reshape(n * k, -1)).reshape(m, n, k, h)
        arm = edges(self.arm, "arm", g["arm"], g["arm_mask"])
        table = edges(self.table, "table", g["table"], None)
        h1 = node + self.update1(torch.cat([node, arm, table], dim=-1).reshape(m, n * k, -1)).reshape(m, n, k, h)
        if k > 1:
            obj = g["obj"]  # (N, K, K-1, EO, F)
            eo = obj.shape[3]
            own = self.obj_in(self.scale("obj", obj).reshape(-1, obj.shape[-1])).reshape(m, n, k, k - 1, eo, h)
            theirs = self.obj_from(h1.reshape(m, n * k, h)).reshape(m, n, k, h)[:, :, self.other]  # (M,N,K,K-1,H)
            msg = self.obj_out(nn.functional.silu(own + theirs[:, :, :, :, None]).reshape(m, -1, h))
            msg = msg.reshape(m, n, k, k - 1, eo, h) * g["obj_mask"].reshape(1, n, k, k - 1, eo, 1)
            objects = msg.sum(dim=(3, 4))
        else:
            objects = torch.zeros_like(h1)
        h2 = h1 + self.update2(torch.cat([h1, objects], dim=-1).reshape(m, n * k, -1)).reshape(m, n, k, h)
        return self.decode(h2.reshape(m, n * k, h)).reshape(m, n, k, OUTPUTS)


def tensors(graph: Graph) -> dict[str, torch.Tensor]:
    """A `Graph`'s arrays as the network's inputs."""
    return {
        "node": torch.from_numpy(graph.node),
        "arm": torch.from_numpy(graph.arm),
        "arm_mask": torch.from_numpy(graph.arm_mask.astype(np.float32)),
        "table": torch.from_numpy(graph.table),
        "obj": torch.from_numpy(graph.obj),
        "obj_mask": torch.from_numpy(graph.obj_mask.astype(np.float32)),
    }
