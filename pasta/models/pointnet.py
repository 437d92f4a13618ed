"""PointNet++ in plain torch: farthest-point sampling, ball query, set abstraction, the policy encoder.

A dense re-implementation of the PyTorch Geometric modules the official policy used (model_spec §4.2,
appendix §1.4): ``fps`` + ``radius`` + ``PointNetConv`` with max aggregation, and a global stage. Clouds
are dense ``(B, N, 3)`` batches (every cloud has N points) instead of PyG's ragged ``batch`` vector.

Differences from PyG, both deliberate:

* FPS starts at index 0 (or a given index) instead of a random point, so encodings are deterministic.
* Ball query returns a fixed ``K`` neighbours per centre, padded with the first neighbour found; under
  max aggregation this equals PyG's variable-size neighbourhoods. Neighbours are the first
  ``max_neighbours`` points within the radius in index order, as PyG's CUDA ``radius`` takes them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

from pasta.models.layers import mlp

__all__ = [
    "GlobalSetAbstraction",
    "PointNetPlusPlusConfig",
    "PointNetPlusPlusEncoder",
    "SetAbstraction",
    "SetAbstractionStage",
    "ball_query",
    "farthest_point_sample",
    "gather_points",
]


def _check_points(points: torch.Tensor, name: str = "points") -> None:
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (B, N, 3), got {tuple(points.shape)}")


def gather_points(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Per-batch gather: ``x (B, N, C)`` at ``idx (B, *S)`` -> ``(B, *S, C)``."""
    batch = torch.arange(x.shape[0], device=x.device).view(-1, *([1] * (idx.ndim - 1)))
    return x[batch, idx]


def farthest_point_sample(
    points: torch.Tensor, n_samples: int, start: int | torch.Tensor | None = None
) -> torch.Tensor:
    """Farthest-point sampling: each new sample is the point farthest from those already chosen.

    Args:
        points: ``(B, N, 3)``.
        n_samples: ``S``, with ``1 <= S <= N``.
        start: index of the first sample: ``None`` (index 0), an int for every cloud, or a ``(B,)``
            long tensor. Ties in the farthest distance go to the lowest index.

    Returns:
        ``(B, S)`` long indices into the N points, in the order chosen. Not differentiable.
    """
    _check_points(points)
    batch_size, n_points, _ = points.shape
    if not 1 <= n_samples <= n_points:
        raise ValueError(f"n_samples must be in [1, {n_points}], got {n_samples}")
    if start is None:
        start = 0
    if isinstance(start, int):
        farthest = torch.full((batch_size,), start, dtype=torch.long, device=points.device)
    else:
        farthest = start.to(device=points.device, dtype=torch.long)
        if farthest.shape != (batch_size,):
            raise ValueError(f"start must be an int or a ({batch_size},) tensor, got shape {tuple(farthest.shape)}")
    if bool(((farthest < 0) | (farthest >= n_points)).any()):
        raise ValueError(f"start indices must be in [0, {n_points}), got {farthest.tolist()}")
    batch = torch.arange(batch_size, device=points.device)
    idx = torch.empty(batch_size, n_samples, dtype=torch.long, device=points.device)
    with torch.no_grad():
        pts = points.detach()
        min_sq = torch.full((batch_size, n_points), float("inf"), dtype=pts.dtype, device=pts.device)
        for i in range(n_samples):
            idx[:, i] = farthest
            sq = (pts - pts[batch, farthest].unsqueeze(1)).square().sum(-1)  # (B, N)
            min_sq = torch.minimum(min_sq, sq)
            farthest = min_sq.argmax(dim=1)  # first maximal index on ties
    return idx


def ball_query(points: torch.Tensor, centres: torch.Tensor, radius: float, max_neighbours: int) -> torch.Tensor:
    """Neighbours of each centre within ``radius``, as PyG's ``radius(x=points, y=centres)``.

    A point is a neighbour when its squared distance is strictly below ``radius**2``. The first
    ``K = min(max_neighbours, N)`` neighbours in index order are kept; a centre with fewer repeats its
    first neighbour in the remaining slots, and a centre with none (possible only when centres are not
    points of the cloud) gets its nearest point.

    Args:
        points: ``(B, N, 3)``.
        centres: ``(B, S, 3)``.
        radius: ball radius, > 0.
        max_neighbours: cap on neighbours per centre (PyG ``max_num_neighbors``; the official 64).

    Returns:
        ``(B, S, K)`` long indices into the N points. Memory is ``O(B * S * N)``.
    """
    _check_points(points)
    _check_points(centres, "centres")
    if radius <= 0 or max_neighbours < 1:
        raise ValueError(f"radius must be > 0 and max_neighbours >= 1, got {radius}, {max_neighbours}")
    n_points = points.shape[1]
    k = min(max_neighbours, n_points)
    with torch.no_grad():
        sq = torch.cdist(centres.detach(), points.detach(), compute_mode="donot_use_mm_for_euclid_dist").square()
        within = sq < radius**2  # (B, S, N)
        order = torch.arange(n_points, dtype=torch.int32, device=points.device)
        keys = torch.where(within, order, torch.full_like(order, n_points))  # index, or N when outside
        first = keys.topk(k, dim=-1, largest=False, sorted=True).values.long()  # (B, S, K) lowest indices
        fallback = torch.where(within.any(dim=-1), first[..., 0], sq.argmin(dim=-1))  # (B, S)
        return torch.where(first < n_points, first, fallback.unsqueeze(-1))


class SetAbstraction(nn.Module):
    """PointNet++ set abstraction: FPS centres, ball grouping, a shared MLP, max-pool per group.

    For every centre ``i`` and neighbour ``j`` the MLP sees ``[x_j, pos_j - pos_i]`` (PyG ``PointNetConv``
    without added self-loops); the centre itself is among its neighbours at distance 0.

    Args:
        ratio: fraction of points kept as centres, ``S = ceil(ratio * N)`` (torch_cluster's rule).
        radius: ball radius.
        mlp_channels: ``[C_in + 3, ..., C_out]``; ReLU after every layer, as the official MLP.
        max_neighbours: neighbours per ball.
    """

    def __init__(self, ratio: float, radius: float, mlp_channels: Sequence[int], max_neighbours: int = 64) -> None:
        super().__init__()
        if not 0 < ratio <= 1:
            raise ValueError(f"ratio must be in (0, 1], got {ratio}")
        self.ratio = ratio
        self.radius = radius
        self.max_neighbours = max_neighbours
        self.net = mlp(mlp_channels, final_activation=True)

    def forward(
        self, features: torch.Tensor, pos: torch.Tensor, start: int | torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``features (B, N, C_in)``, ``pos (B, N, 3)`` -> ``(features (B, S, C_out), pos (B, S, 3))``.

        ``start`` is the FPS start index (see ``farthest_point_sample``).
        """
        n_centres = math.ceil(self.ratio * pos.shape[1])
        centres = gather_points(pos, farthest_point_sample(pos, n_centres, start))  # (B, S, 3)
        neighbours = ball_query(pos, centres, self.radius, self.max_neighbours)  # (B, S, K)
        relative = gather_points(pos, neighbours) - centres.unsqueeze(2)  # (B, S, K, 3)
        grouped = torch.cat([gather_points(features, neighbours), relative], dim=-1)  # (B, S, K, C_in + 3)
        return self.net(grouped).max(dim=2).values, centres


class GlobalSetAbstraction(nn.Module):
    """The last PointNet++ stage: a shared MLP on ``[x, pos]`` (absolute positions), global max-pool.

    ``features (B, N, C_in)``, ``pos (B, N, 3)`` -> ``(B, C_out)``; ``mlp_channels = [C_in + 3, ..., C_out]``.
    """

    def __init__(self, mlp_channels: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp(mlp_channels, final_activation=True)

    def forward(self, features: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([features, pos], dim=-1)).max(dim=1).values


@dataclass(frozen=True)
class SetAbstractionStage:
    """One local stage: centre ratio, ball radius, MLP widths after the input (``[64, 64, 128]``)."""

    ratio: float
    radius: float
    channels: tuple[int, ...]


@dataclass(frozen=True)
class PointNetPlusPlusConfig:
    """Hyper-parameters of the encoder; defaults are the appendix §1.4 encoder.

    ``SA(0.5, 0.05, [3+3, 64, 64, 128])``, ``SA(0.25, 0.1, [128+3, 128, 128, 256])``,
    ``GlobalSA([256+3, 256, 128, 512, 1024])`` with ``in_features = 3`` (the one-hot point roles).
    """

    in_features: int = 3
    stages: tuple[SetAbstractionStage, ...] = (
        SetAbstractionStage(0.5, 0.05, (64, 64, 128)),
        SetAbstractionStage(0.25, 0.1, (128, 128, 256)),
    )
    global_channels: tuple[int, ...] = (256, 128, 512, 1024)
    max_neighbours: int = 64

    @property
    def out_dim(self) -> int:
        return self.global_channels[-1]


class PointNetPlusPlusEncoder(nn.Module):
    """PointNet++ encoder: local set-abstraction stages then a global stage, ``(B, N, 3)`` -> ``(B, out_dim)``."""

    def __init__(self, config: PointNetPlusPlusConfig = PointNetPlusPlusConfig()) -> None:
        super().__init__()
        self.config = config
        stages = []
        c_in = config.in_features
        for stage in config.stages:
            stages.append(SetAbstraction(stage.ratio, stage.radius, (c_in + 3, *stage.channels), config.max_neighbours))
            c_in = stage.channels[-1]
        self.stages = nn.ModuleList(stages)
        self.global_stage = GlobalSetAbstraction((c_in + 3, *config.global_channels))

    def forward(
        self, points: torch.Tensor, features: torch.Tensor, start: int | torch.Tensor | None = None
    ) -> torch.Tensor:
        """Encode a batch of clouds.

        Args:
            points: ``(B, N, 3)`` positions.
            features: ``(B, N, in_features)`` per-point features (the one-hot roles).
            start: FPS start index of the first stage (default 0); later stages start at their first
                centre, which is the first stage's start point, so the output does not depend on the
                order of the points when ``start`` follows the same point.

        Returns:
            ``(B, out_dim)`` global features.
        """
        _check_points(points)
        if features.shape != (*points.shape[:2], self.config.in_features):
            raise ValueError(
                f"features must have shape {(*points.shape[:2], self.config.in_features)}, got {tuple(features.shape)}"
            )
        x, pos = features, points
        for i, stage in enumerate(self.stages):
            x, pos = stage(x, pos, start if i == 0 else None)
        return self.global_stage(x, pos)
