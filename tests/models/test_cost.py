"""Cost predictor: shapes, pairwise costs, Hungarian set cost, invariances, masks, training on Chamfer."""

from __future__ import annotations

import itertools
from dataclasses import replace

import pytest
import torch

from pasta.geometry.distances import chamfer_distance
from pasta.models import CostPredictor, hungarian_assignment, matched_cost
from tests.models.synthetic import box_clouds, tiny_model_config, train


def test_default_architecture_and_shapes():
    torch.manual_seed(0)
    model = CostPredictor()
    assert [(m.in_features, m.out_features) for m in model.net[::2]] == [
        (10, 1024),
        (1024, 1024),
        (1024, 1024),
        (1024, 1),
    ]
    gen = torch.Generator().manual_seed(0)
    a, b = torch.randn(4, 3, 5, generator=gen), torch.randn(4, 2, 5, generator=gen)
    assert model(a[:, 0], b[:, 0]).shape == (4,)
    pair = model.pairwise(a, b)
    assert pair.shape == (4, 3, 2)
    torch.testing.assert_close(pair[:, 2, 1], model(a[:, 2], b[:, 1]))
    assert model.set_cost(a, b).shape == (4,)
    with pytest.raises(ValueError):
        model(a[:, 0], b[:, 0, :4])


def test_centring_uses_only_the_relative_position():
    config = tiny_model_config().cost
    gen = torch.Generator().manual_seed(1)
    a, b = torch.randn(6, 5, generator=gen), torch.randn(6, 5, generator=gen)
    shift = torch.tensor([0.0, 0.0, 0.2, -0.4, 0.1])
    model = CostPredictor(config)
    torch.testing.assert_close(model(a + shift, b + shift), model(a, b), atol=1e-5, rtol=0)
    absolute = CostPredictor(replace(config, centre_positions=False))
    assert not torch.allclose(absolute(a + shift, b + shift), absolute(a, b))


def test_hungarian_matches_brute_force_and_respects_masks():
    gen = torch.Generator().manual_seed(2)
    costs = torch.rand(20, 3, 3, generator=gen)
    assignment = hungarian_assignment(costs)
    for b in range(20):
        best = min(sum(float(costs[b, i, p[i]]) for i in range(3)) for p in itertools.permutations(range(3)))
        assert float(matched_cost(costs[b : b + 1], assignment[b : b + 1])) == pytest.approx(best, rel=1e-6)
    obs_mask = torch.tensor([[True, False, True]])
    goal_mask = torch.tensor([[False, True, True]])
    partial = hungarian_assignment(costs[:1], obs_mask, goal_mask)
    assert partial[0, 1] == -1 and set(partial[0, [0, 2]].tolist()) == {1, 2}
    rectangular = hungarian_assignment(torch.rand(2, 1, 3, generator=gen))
    assert rectangular.shape == (2, 1) and bool((rectangular >= 0).all())


def test_set_cost_is_invariant_to_entity_order_and_padding():
    torch.manual_seed(0)
    model = CostPredictor().eval()
    gen = torch.Generator().manual_seed(3)
    obs, goal = torch.randn(5, 3, 5, generator=gen), torch.randn(5, 3, 5, generator=gen)
    with torch.no_grad():
        ref = model.set_cost(obs, goal)
        torch.testing.assert_close(model.set_cost(obs[:, [2, 0, 1]], goal[:, [1, 2, 0]]), ref, atol=1e-5, rtol=0)
        padded_obs = torch.cat([obs, torch.full((5, 2, 5), -3.0)], dim=1)
        padded_goal = torch.cat([torch.full((5, 1, 5), 7.0), goal], dim=1)
        obs_mask = torch.tensor([True, True, True, False, False]).expand(5, 5)
        goal_mask = torch.tensor([False, True, True, True]).expand(5, 4)
        torch.testing.assert_close(model.set_cost(padded_obs, padded_goal, obs_mask, goal_mask), ref, atol=1e-6, rtol=0)


def test_set_cost_gradient_flows_to_latents():
    model = CostPredictor(tiny_model_config().cost)
    obs = torch.randn(2, 2, 5, requires_grad=True)
    model.set_cost(obs, torch.randn(2, 2, 5)).sum().backward()
    assert obs.grad is not None and bool((obs.grad.abs().sum(-1) > 0).all())


def test_training_regresses_chamfer_between_synthetic_clouds():
    torch.manual_seed(0)
    model = CostPredictor(tiny_model_config().cost)
    gen = torch.Generator().manual_seed(4)
    clouds_a, clouds_b = box_clouds(64, 64, gen), box_clouds(64, 64, gen)
    target = chamfer_distance(clouds_a, clouds_b)

    def latent(clouds):  # a stand-in encoder: shape code = log half-extent of x and y, t = mean
        extent = clouds.amax(1) - clouds.amin(1)
        return torch.cat([extent[:, :2].log(), clouds.mean(1)], dim=-1)

    u_a, u_b = latent(clouds_a), latent(clouds_b)
    first, last = train(lambda: (model(u_a, u_b) - target).square().mean(), model.parameters(), lr=1e-3)
    assert last < 0.5 * first
