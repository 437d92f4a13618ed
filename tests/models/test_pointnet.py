"""Farthest-point sampling, ball query and PointNet++ against slow references and invariances.

The encoder evaluates its MLPs factored and reordered (``pasta.models.pointnet._mlp_max``); the plain
references below apply the same weights the obvious way, and outputs and gradients must agree.
"""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from pasta.models import (
    GlobalSetAbstraction,
    PointNetPlusPlusConfig,
    PointNetPlusPlusEncoder,
    SetAbstraction,
    ball_query,
    farthest_point_sample,
)
from pasta.models.pointnet import gather_points
from tests.models.synthetic import tiny_encoder


def fps_reference(points: list[list[float]], n_samples: int, start: int) -> list[int]:
    chosen = [start]
    min_sq = [math.inf] * len(points)
    for _ in range(n_samples - 1):
        last = points[chosen[-1]]
        for j, p in enumerate(points):
            min_sq[j] = min(min_sq[j], sum((a - b) ** 2 for a, b in zip(p, last, strict=True)))
        best = max(range(len(points)), key=lambda j: (min_sq[j], -j))  # farthest, lowest index on ties
        chosen.append(best)
    return chosen


def ball_reference(points, centres, radius: float, k: int) -> list[list[int]]:
    out = []
    for c in centres:
        sq = [sum((a - b) ** 2 for a, b in zip(p, c, strict=True)) for p in points]
        found = [j for j, d in enumerate(sq) if d < radius**2][:k]
        if not found:
            found = [min(range(len(points)), key=lambda j: sq[j])]
        out.append(found + [found[0]] * (min(k, len(points)) - len(found)))
    return out


def test_fps_matches_reference_and_start():
    gen = torch.Generator().manual_seed(0)
    points = torch.rand(3, 40, 3, generator=gen)
    idx = farthest_point_sample(points, 12)
    assert idx.shape == (3, 12) and idx.dtype == torch.long
    for b in range(3):
        assert idx[b].tolist() == fps_reference(points[b].tolist(), 12, 0)
    start = torch.tensor([5, 0, 39])
    idx = farthest_point_sample(points, 12, start)
    for b in range(3):
        assert idx[b].tolist() == fps_reference(points[b].tolist(), 12, int(start[b]))
    assert len(set(idx[0].tolist())) == 12  # distinct while points are distinct


def test_fps_rejects_bad_arguments():
    points = torch.rand(2, 10, 3)
    with pytest.raises(ValueError):
        farthest_point_sample(points, 11)
    with pytest.raises(ValueError):
        farthest_point_sample(points, 3, torch.tensor([0, 10]))


def test_ball_query_matches_reference_with_padding_and_cap():
    gen = torch.Generator().manual_seed(1)
    points = torch.rand(2, 60, 3, generator=gen)
    centres = torch.cat([points[:, :7], torch.full((2, 1, 3), 5.0)], dim=1)  # the last centre has no neighbour
    for radius, k in [(0.2, 8), (0.35, 5), (0.05, 4), (2.0, 100)]:
        idx = ball_query(points, centres, radius, k)
        assert idx.shape == (2, 8, min(k, 60))
        for b in range(2):
            assert idx[b].tolist() == ball_reference(points[b].tolist(), centres[b].tolist(), radius, k)


def test_set_abstraction_shapes_and_group_max():
    gen = torch.Generator().manual_seed(2)
    pos = torch.rand(2, 30, 3, generator=gen)
    x = torch.rand(2, 30, 4, generator=gen)
    sa = SetAbstraction(0.25, 0.3, (4 + 3, 8, 16), max_neighbours=6)
    out, centres = sa(x, pos)
    assert out.shape == (2, math.ceil(0.25 * 30), 16) and centres.shape == (2, 8, 3)
    # group 0 by hand: centre = point 0 (FPS start), its neighbours from the ball query, max over the MLP
    nbr = ball_query(pos, centres, 0.3, 6)[0, 0]
    manual = sa.net(torch.cat([x[0, nbr], pos[0, nbr] - pos[0, 0]], dim=-1)).max(dim=0).values
    torch.testing.assert_close(out[0, 0], manual)
    glob = GlobalSetAbstraction((16 + 3, 32))
    assert glob(out, centres).shape == (2, 32)


def test_encoder_default_shape_matches_appendix():
    enc = PointNetPlusPlusEncoder()
    first, second = enc.stages
    assert first.net[0].in_features == 6 and first.net[-2].out_features == 128 and first.ratio == 0.5
    assert second.net[0].in_features == 131 and second.net[-2].out_features == 256 and second.radius == 0.1
    assert enc.global_stage.net[0].in_features == 259 and [m.out_features for m in enc.global_stage.net[::2]] == [
        256,
        128,
        512,
        1024,
    ]
    gen = torch.Generator().manual_seed(3)
    points = 0.3 * torch.rand(2, 64, 3, generator=gen)
    roles = torch.eye(3)[torch.randint(3, (2, 64), generator=gen)]
    assert enc(points, roles).shape == (2, 1024)


def test_encoder_is_invariant_to_point_order():
    torch.manual_seed(0)
    config = PointNetPlusPlusConfig(max_neighbours=128)  # no neighbour cap, so the order cannot matter
    enc = PointNetPlusPlusEncoder(config).eval()
    gen = torch.Generator().manual_seed(4)
    points = 0.2 * torch.rand(2, 128, 3, generator=gen)
    roles = torch.eye(3)[torch.randint(3, (2, 128), generator=gen)]
    perm = torch.randperm(128, generator=gen)
    start_in_permuted = torch.argsort(perm)[0].repeat(2)  # where point 0 went
    with torch.no_grad():
        ref = enc(points, roles)
        out = enc(points[:, perm], roles[:, perm], start_in_permuted)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=0)


def test_encoder_rejects_wrong_features():
    enc = PointNetPlusPlusEncoder(tiny_encoder(3))
    with pytest.raises(ValueError):
        enc(torch.rand(1, 20, 3), torch.rand(1, 20, 2))


def plain_mlp(net: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """ReLU after every linear layer of ``net``, on the last axis of ``x``."""
    for layer in net:
        if isinstance(layer, nn.Linear):
            x = torch.relu(x @ layer.weight.T + layer.bias)
    return x


def plain_set_abstraction(sa: SetAbstraction, x: torch.Tensor, pos: torch.Tensor, start=None):
    """Group each centre's neighbours, concatenate ``[x_j, pos_j - pos_i]``, MLP, max over the group."""
    centres = gather_points(pos, farthest_point_sample(pos, math.ceil(sa.ratio * pos.shape[1]), start))
    neighbours = ball_query(pos, centres, sa.radius, sa.max_neighbours)  # (B, S, K)
    grouped = []
    for b in range(pos.shape[0]):
        relative = pos[b][neighbours[b]] - centres[b].unsqueeze(1)  # (S, K, 3)
        grouped.append(torch.cat([x[b][neighbours[b]], relative], dim=-1))
    return plain_mlp(sa.net, torch.stack(grouped)).max(dim=2).values, centres


def plain_encoder(enc: PointNetPlusPlusEncoder, points: torch.Tensor, roles: torch.Tensor) -> torch.Tensor:
    x, pos = roles, points
    for stage in enc.stages:
        x, pos = plain_set_abstraction(stage, x, pos)
    return plain_mlp(enc.global_stage.net, torch.cat([x, pos], dim=-1)).max(dim=1).values


def randomise_(module: nn.Module, seed: int) -> nn.Module:
    """Every parameter drawn from N(0, 0.5^2), so biases weigh as much as weights (torch's start small)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for param in module.parameters():
            param.copy_(0.5 * torch.randn(param.shape, generator=gen))
    return module


def outputs_and_gradients(module: nn.Module, forward, seed: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``forward()``'s output and the gradients of a fixed random linear function of it."""
    module.zero_grad()
    out = forward()
    weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=out.dtype)
    (out * weights).sum().backward()
    return out.detach(), {name: p.grad.clone() for name, p in module.named_parameters()}


def clouds(batch: int, n: int, seed: int, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    """Points in ``[0.3, 0.7]^3`` and one-hot roles; at these sizes some balls are full and some padded."""
    gen = torch.Generator().manual_seed(seed)
    points = 0.3 + 0.4 * torch.rand(batch, n, 3, generator=gen, dtype=dtype)
    return points, torch.eye(3, dtype=dtype)[torch.randint(3, (batch, n), generator=gen)]


@pytest.mark.parametrize("channels", [(16,), (16, 32), (8, 16, 32)])
def test_set_abstraction_matches_plain_reference(channels):
    # float64: the gradient of a max jumps where two group members tie, and float32 rounding can pick
    # the other member of a near tie; in float64 the gaps dwarf the rounding, so agreement is tight.
    pos, x = clouds(2, 120, seed=5)
    x = torch.cat([x, torch.rand(2, 120, 1, generator=torch.Generator().manual_seed(6), dtype=x.dtype)], -1)
    sa = randomise_(SetAbstraction(0.25, 0.15, (4 + 3, *channels), max_neighbours=12).double(), seed=7)
    start = torch.tensor([3, 0])
    neighbours = ball_query(pos, sa(x, pos, start)[1], sa.radius, sa.max_neighbours)
    padded = neighbours[..., -1] == neighbours[..., 0]  # fewer than K neighbours: the first one repeats
    assert bool(padded.any()) and not bool(padded.all())
    out, grads = outputs_and_gradients(sa, lambda: sa(x, pos, start)[0], seed=8)
    ref, ref_grads = outputs_and_gradients(sa, lambda: plain_set_abstraction(sa, x, pos, start)[0], seed=8)
    torch.testing.assert_close(out, ref, rtol=1e-10, atol=1e-12)
    assert grads.keys() == ref_grads.keys()
    for name in grads:
        torch.testing.assert_close(grads[name], ref_grads[name], rtol=1e-10, atol=1e-12, msg=name)


@pytest.mark.parametrize("train_mode", [True, False])
def test_encoder_matches_plain_reference(train_mode):
    points, roles = clouds(2, 200, seed=9)
    enc = randomise_(PointNetPlusPlusEncoder(tiny_encoder(3)).double(), seed=10).train(train_mode)
    out, grads = outputs_and_gradients(enc, lambda: enc(points, roles), seed=11)
    ref, ref_grads = outputs_and_gradients(enc, lambda: plain_encoder(enc, points, roles), seed=11)
    torch.testing.assert_close(out, ref, rtol=1e-10, atol=1e-12)
    for name in grads:
        torch.testing.assert_close(grads[name], ref_grads[name], rtol=1e-10, atol=1e-12, msg=name)


@pytest.mark.parametrize("train_mode", [True, False])
def test_default_encoder_matches_plain_reference_in_float32(train_mode):
    torch.manual_seed(12)
    points, roles = clouds(2, 400, seed=13, dtype=torch.float32)
    enc = PointNetPlusPlusEncoder().train(train_mode)
    with torch.no_grad():
        out, ref = enc(points, roles), plain_encoder(enc, points, roles)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5 * float(ref.abs().max()))


def test_encoder_parameters_keep_their_checkpoint_names():
    shapes = {name: tuple(p.shape) for name, p in PointNetPlusPlusEncoder().state_dict().items()}
    expected = {}
    for prefix, widths in [
        ("stages.0", (6, 64, 64, 128)),
        ("stages.1", (131, 128, 128, 256)),
        ("global_stage", (259, 256, 128, 512, 1024)),
    ]:
        for i, (c_in, c_out) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
            expected[f"{prefix}.net.{2 * i}.weight"] = (c_out, c_in)
            expected[f"{prefix}.net.{2 * i}.bias"] = (c_out,)
    assert shapes == expected


def test_fps_restores_the_thread_count():
    torch.set_num_threads(2)  # the folder's fixture restores its own count afterwards
    farthest_point_sample(torch.rand(1, 30, 3), 5)
    assert torch.get_num_threads() == 2
