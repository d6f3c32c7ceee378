"""The world-model example's networks: a flat MLP, a convolutional one over the start's maps, and the networks
shared by every object (over its map and the arm's path, or over the arm's points relative to its pose). Used by
examples/train_world_model.py."""

from __future__ import annotations

import torch
from torch import nn
from world_model_data import ARM_LINKS


class WorldModel(nn.Module):
    """MLP: flattened trajectory (and start) -> per-object displacement (dx, dy) and a "moves" logit."""

    def __init__(self, n_in: int, n_objects: int, hidden: int = 128):
        super().__init__()
        self.n_objects = n_objects
        self.net = nn.Sequential(
            nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3 * n_objects)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.net(x.flatten(1)).view(-1, self.n_objects, 3)
        return out[..., :2], out[..., 2]


def image_features(channels: int) -> nn.Module:
    """The small convolutional network both image models use: ``channels`` maps in, 32 x 4 x 4 features out."""
    return nn.Sequential(
        nn.Conv2d(channels, 16, 3, padding=1), nn.ReLU(),
        nn.Conv2d(16, 32, 3, padding=1, stride=2), nn.ReLU(),
        nn.Conv2d(32, 32, 3, padding=1, stride=2), nn.ReLU(),
        nn.AdaptiveAvgPool2d(4), nn.Flatten(),
    )  # fmt: skip


class ConvWorldModel(nn.Module):
    """The start's object maps and the tool path's two maps (``channels`` images of ``grid`` x ``grid``, the head
    camera's view) through a small convolutional network, beside the trajectory through a linear layer; one head
    predicts each object's (dx, dy) and "moves" logit. Convolutions see the same geometry wherever the objects
    stand, which a flat MLP over the maps has to learn for every place anew."""

    def __init__(self, n_trajectory: int, channels: int, grid: int, n_objects: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.channels, self.grid, self.n_objects = n_trajectory, channels, grid, n_objects
        self.conv = image_features(channels)
        self.trajectory = nn.Linear(n_trajectory, hidden)
        self.head = nn.Sequential(
            nn.ReLU(), nn.Linear(32 * 16 + hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3 * n_objects)
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        images = x[:, self.n_trajectory :].reshape(-1, self.channels, self.grid, self.grid)
        features = torch.cat([self.conv(images), self.trajectory(x[:, : self.n_trajectory])], dim=1)
        out = self.head(features).view(-1, self.n_objects, 3)
        return out[..., :2], out[..., 2]


class ObjectMapsModel(nn.Module):
    """One network for every object, shared: object k's occupancy map, the other objects' maps summed and the arm's
    path maps (all of it, its low part) through a convolutional network, with which object it is, predict k's
    (dx, dy) and "moves" logit. Whatever holds for one object at one place is learned for all objects and places:
    what a model must find for a new start is where the arm's path meets an object's map."""

    def __init__(self, n_trajectory: int, n_objects: int, grid: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.n_objects, self.grid = n_trajectory, n_objects, grid
        self.conv = image_features(4)
        self.head = nn.Sequential(
            nn.Linear(32 * 16 + n_objects, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, 3),
        )

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, k, g = len(x), self.n_objects, self.grid
        maps = x[:, self.n_trajectory :].reshape(b, k + 2, g, g)
        objects, path = maps[:, :k], maps[:, k:]
        others = objects.sum(dim=1, keepdim=True) - objects
        channels = torch.cat(
            [objects.unsqueeze(2), others.unsqueeze(2), path.unsqueeze(1).expand(b, k, 2, g, g)], dim=2
        ).reshape(b * k, 4, g, g)
        which = torch.eye(k).expand(b, k, k).reshape(b * k, k)
        out = self.head(torch.cat([self.conv(channels), which], dim=1)).view(b, k, 3)
        return out[..., :2], out[..., 2]


class ObjectPosesModel(nn.Module):
    """One network for every object, shared: each point of the arm's path (``ARM_LINKS`` link origins at each time
    step) relative to object k's start position, its height above the table and which link it is, through a small
    network and pooled over the points (the nearest pass counts wherever in time it happens); with k's own position
    and yaw, where the other objects stand relative to it and which object it is, predict k's (dx, dy) and "moves"
    logit."""

    def __init__(self, n_trajectory: int, n_objects: int, steps: int, hidden: int = 128):
        super().__init__()
        self.n_trajectory, self.n_objects, self.steps = n_trajectory, n_objects, steps
        self.point = nn.Sequential(nn.Linear(3 + ARM_LINKS, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.head = nn.Sequential(
            nn.Linear(hidden + 4 + 3 * n_objects, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, 3),
        )  # fmt: skip

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, k, n = len(x), self.n_objects, self.steps * ARM_LINKS
        start = x[:, self.n_trajectory : self.n_trajectory + 4 * k].reshape(b, k, 4)
        arm = x[:, self.n_trajectory + 4 * k :].reshape(b, 1, n, 3)
        relative = arm[..., :2] - start[:, :, None, :2]  # (b, k, points, 2)
        height = arm[..., 2:].expand(b, k, n, 1)
        link = torch.eye(ARM_LINKS).repeat(self.steps, 1).expand(b, k, n, ARM_LINKS)
        pooled = self.point(torch.cat([10 * relative, 10 * height, link], dim=3)).amax(dim=2)
        others = start[:, None, :, :2] - start[:, :, None, :2]  # (b, k, k, 2)
        which = torch.eye(k).expand(b, k, k)
        out = self.head(torch.cat([pooled, start, 10 * others.flatten(2), which], dim=2)).view(b, k, 3)
        return out[..., :2], out[..., 2]


def build(net: dict | None, n_in: int, n_objects: int, hidden: int) -> nn.Module:
    """The network ``net`` names (``{"kind": "conv" | "object_maps" | "object_poses", ...its arguments}``), or the
    MLP for None."""
    if net is None:
        return WorldModel(n_in, n_objects, hidden)
    kinds = {"conv": ConvWorldModel, "object_maps": ObjectMapsModel, "object_poses": ObjectPosesModel}
    args = {k: v for k, v in net.items() if k != "kind"}
    return kinds[net["kind"]](**args, n_objects=n_objects, hidden=hidden)
