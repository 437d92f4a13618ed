"""PointNet++ in plain torch: farthest-point sampling, ball query, set abstraction, the policy encoder.

A dense re-implementation of the PyTorch Geometric modules the official policy used (model_spec §4.2,
appendix §1.4): ``fps`` + ``radius`` + ``PointNetConv`` with max aggregation, and a global stage. Clouds
are dense ``(B, N, 3)`` batches (every cloud has N points) instead of PyG's ragged ``batch`` vector.

Differences from PyG, both deliberate:

* FPS starts at index 0 (or a given index) instead of a random point, so encodings are deterministic.
* Ball query returns a fixed ``K`` neighbours per centre, padded with the first neighbour found; under
  max aggregation this equals PyG's variable-size neighbourhoods. Neighbours are the first
  ``max_neighbours`` points within the radius in index order, as PyG's CUDA ``radius`` takes them.

The MLPs are not applied to the grouped ``(B, S, K, C)`` tensor as is: the first layer is split into a
per-point part and a relative-position part, biases and ReLUs that commute with the max move after it,
and everything runs on 2-D contiguous rows (``SetAbstraction``, ``_mlp_max``). The results are those of
the plain per-neighbour MLP, up to float rounding (``tests/models/test_pointnet.py`` compares them).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from pasta.models.group_max import linear_group_max
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


@contextmanager
def _one_torch_thread() -> Iterator[None]:
    """Run the body on one intra-op thread, then restore the count.

    FPS is a long chain of tiny ops on ``(B, N)`` tensors; splitting each over threads costs more in
    synchronisation than it saves, and stalls whenever another process holds a core.
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _start_indices(
    start: int | torch.Tensor | None, batch_size: int, n_points: int, device: torch.device
) -> torch.Tensor:
    """FPS start indices as a checked ``(B,)`` long tensor (``None`` means index 0 everywhere)."""
    if start is None or isinstance(start, int):
        first = torch.full((batch_size,), 0 if start is None else start, dtype=torch.long, device=device)
    else:
        first = start.to(device=device, dtype=torch.long)
        if first.shape != (batch_size,):
            raise ValueError(f"start must be an int or a ({batch_size},) tensor, got shape {tuple(first.shape)}")
    if bool(((first < 0) | (first >= n_points)).any()):
        raise ValueError(f"start indices must be in [0, {n_points}), got {first.tolist()}")
    return first


def farthest_point_sample(
    points: torch.Tensor, n_samples: int, start: int | torch.Tensor | None = None
) -> torch.Tensor:
    """Farthest-point sampling: each new sample is the point farthest from those already chosen.

    The coordinates are held as three contiguous ``(B, N)`` planes, so each step's squared distances
    are three element-wise passes, and the loop runs on one thread (``_one_torch_thread``).

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
    farthest = _start_indices(start, batch_size, n_points, points.device)
    with torch.no_grad(), _one_torch_thread():
        planes = points.detach().permute(2, 0, 1).contiguous()  # (3, B, N)
        chosen = [farthest]
        min_sq = torch.full((batch_size, n_points), float("inf"), dtype=points.dtype, device=points.device)
        offsets, sq = torch.empty_like(planes), torch.empty_like(min_sq)  # reused: no allocation per sample
        for _ in range(n_samples - 1):
            last = planes.gather(2, farthest.view(1, -1, 1).expand(3, -1, 1))  # (3, B, 1)
            torch.sum(torch.sub(planes, last, out=offsets).square_(), dim=0, out=sq)
            torch.minimum(min_sq, sq, out=min_sq)
            farthest = min_sq.argmax(dim=1)  # first maximal index on ties
            chosen.append(farthest)
    return torch.stack(chosen, dim=1)


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
        sq = torch.cdist(centres.detach(), points.detach(), compute_mode="donot_use_mm_for_euclid_dist").square_()
        # The narrowest integer that holds N: selecting and sorting the keys is memory-bound.
        key_dtype = torch.int16 if n_points < torch.iinfo(torch.int16).max else torch.int32
        order = torch.arange(n_points, dtype=key_dtype, device=points.device)
        outside = torch.tensor(n_points, dtype=key_dtype, device=points.device)
        keys = torch.where(sq < radius**2, order, outside)  # (B, S, N): index when within, else N
        first = keys.topk(k, dim=-1, largest=False, sorted=True).values.long()  # (B, S, K) lowest indices
        lonely = first[..., 0] == n_points  # (B, S): no point within the radius
        if bool(lonely.any()):
            first[..., 0] = torch.where(lonely, sq.argmin(dim=-1), first[..., 0])
        return torch.where(first < n_points, first, first[..., :1])


def _linear_layers(net: nn.Sequential) -> list[nn.Linear]:
    """The ``nn.Linear`` layers of an ``mlp(..., final_activation=True)``, in order."""
    return [layer for layer in net if isinstance(layer, nn.Linear)]


def _group_max(rows: torch.Tensor, n_members: int) -> torch.Tensor:
    """``(G * M, C)`` member-major rows -> ``(M, C)``: per group, the max over its ``G`` members."""
    return rows.view(n_members, -1, rows.shape[-1]).max(dim=0).values


def _mlp_max(pre: torch.Tensor, layers: Sequence[nn.Linear], n_members: int) -> torch.Tensor:
    """Finish a ReLU MLP from its first layer's pre-activations and max-pool groups of rows.

    Rows are member-major: row ``g * M + m`` is member ``g`` of group ``m``. Every layer works on 2-D
    contiguous rows, and the hidden ReLUs run in place (no layer's backward needs its own output).
    Two exact reorderings move work from ``G * M`` rows to ``M``: the last layer's bias is added after
    the max (``max_g(W a_g) + b``), and so is the last ReLU, which commutes with the max. The last layer
    and the max are one ``linear_group_max``, whose backward pass touches only each group's winners.

    Args:
        pre: ``(G * M, C_1)`` pre-activations of the MLP's first layer, bias included.
        layers: the MLP's remaining linear layers (possibly none); ReLU before each of them.
        n_members: ``G``.

    Returns:
        ``(M, C_out)``: per group, the max over its members of the MLP with a ReLU after every layer.
    """
    if not layers:
        return _group_max(pre, n_members).relu()
    *hidden, last = layers
    out = pre
    for layer in hidden:
        out = F.linear(out.relu_(), layer.weight, layer.bias)
    return (linear_group_max(out.relu_(), last.weight, n_members) + last.bias).relu()


def _member_major_rows(neighbours: torch.Tensor, n_points: int) -> torch.Tensor:
    """``neighbours (B, S, K)`` indices into each cloud's N points -> ``(K * B * S,)`` rows of the
    flattened ``(B * N, C)`` points, member-major (``_mlp_max``'s order)."""
    offsets = n_points * torch.arange(neighbours.shape[0], device=neighbours.device).view(-1, 1, 1)
    return (neighbours + offsets).permute(2, 0, 1).reshape(-1)


def _grouped_first_layer(
    first: nn.Linear, features: torch.Tensor, pos: torch.Tensor, centres: torch.Tensor, rows: torch.Tensor
) -> torch.Tensor:
    """``first([x_j, pos_j - pos_i])`` for every (neighbour ``j``, centre ``i``) pair, ``(K * B * S, C_1)``.

    ``W_x x_j + b`` is computed once per point and gathered; ``W_pos (pos_j - pos_i)`` is added on the
    grouped relative positions (3 inputs, so cheap).

    Args:
        first: the MLP's first layer, ``C_in + 3 -> C_1``.
        features: ``(B, N, C_in)``.
        pos: ``(B, N, 3)``.
        centres: ``(B, S, 3)``.
        rows: ``(K * B * S,)`` member-major rows of the flattened ``(B * N)`` points.
    """
    w_x, w_pos = first.weight.split([features.shape[-1], 3], dim=1)
    per_point = F.linear(features.flatten(0, 1), w_x, first.bias)  # (B * N, C_1)
    neighbour_pos = pos.flatten(0, 1).index_select(0, rows).view(-1, *centres.shape[:2], 3)  # (K, B, S, 3)
    relative = (neighbour_pos - centres).view(-1, 3)  # (K * B * S, 3)
    dtype = per_point.dtype  # bfloat16 under a caller's autocast, which in-place products do not follow
    return per_point.index_select(0, rows).addmm_(relative.to(dtype), w_pos.t().to(dtype))


class SetAbstraction(nn.Module):
    """PointNet++ set abstraction: FPS centres, ball grouping, a shared MLP, max-pool per group.

    For every centre ``i`` and neighbour ``j`` the MLP ``net`` sees ``[x_j, pos_j - pos_i]`` (PyG
    ``PointNetConv`` without added self-loops); the centre itself is among its neighbours at distance 0.

    ``forward`` evaluates exactly that, factored: the first layer ``W [x_j, pos_j - pos_i] + b`` splits
    into ``(W_x x_j + b)``, computed once per point and gathered, plus ``W_pos (pos_j - pos_i)`` on the
    grouped relative positions (``_grouped_first_layer``). The relative part stays grouped: splitting it
    too, ``W_pos pos_j - W_pos pos_i``, would subtract large nearly equal numbers and lose float32
    precision in ``W_pos``'s gradient. The rest of the MLP and the max run as ``_mlp_max``.

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
        batch_size, n_points, _ = pos.shape
        n_centres = math.ceil(self.ratio * n_points)
        centres = gather_points(pos, farthest_point_sample(pos, n_centres, start))  # (B, S, 3)
        neighbours = ball_query(pos, centres, self.radius, self.max_neighbours)  # (B, S, K)
        rows = _member_major_rows(neighbours, n_points)  # (K * B * S,)
        first, *rest = _linear_layers(self.net)
        pre = _grouped_first_layer(first, features, pos, centres, rows)  # (K * B * S, C_1)
        pooled = _mlp_max(pre, rest, neighbours.shape[-1])  # (B * S, C_out)
        return pooled.view(batch_size, n_centres, -1), centres


class GlobalSetAbstraction(nn.Module):
    """The last PointNet++ stage: a shared MLP on ``[x, pos]`` (absolute positions), global max-pool.

    ``features (B, N, C_in)``, ``pos (B, N, 3)`` -> ``(B, C_out)``; ``mlp_channels = [C_in + 3, ..., C_out]``.
    Evaluated as ``_mlp_max`` over the points laid out member-major, ``(N * B, C_in + 3)``.
    """

    def __init__(self, mlp_channels: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp(mlp_channels, final_activation=True)

    def forward(self, features: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        first, *rest = _linear_layers(self.net)
        inputs = torch.cat([features, pos], dim=-1).transpose(0, 1).flatten(0, 1)  # (N * B, C_in + 3)
        return _mlp_max(F.linear(inputs, first.weight, first.bias), rest, pos.shape[1])


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

    @property
    def out_dim(self) -> int:
        return self.config.out_dim

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
