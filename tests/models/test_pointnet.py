"""Farthest-point sampling, ball query and PointNet++ against slow references and invariances."""

from __future__ import annotations

import math

import pytest
import torch

from pasta.models import (
    GlobalSetAbstraction,
    PointNetPlusPlusConfig,
    PointNetPlusPlusEncoder,
    SetAbstraction,
    ball_query,
    farthest_point_sample,
)
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
