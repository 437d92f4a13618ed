"""Set feasibility predictor: shapes, invariances, masks, training on synthetic latents."""

from __future__ import annotations

import pytest
import torch

from pasta.models import FeasibilityConfig, LatentPrior, SetFeasibilityPredictor, feasibility_batch, weighted_mse
from tests.models.synthetic import tiny_model_config, train


def make_sets(gen, batch=6, k_obs=2, k_goal=3):
    return torch.randn(batch, k_obs, 5, generator=gen), torch.randn(batch, k_goal, 5, generator=gen)


def test_default_architecture_and_output_range():
    torch.manual_seed(0)
    model = SetFeasibilityPredictor()
    assert [m.out_features for m in model.obs_encoder.net[::2]] == [256, 256]
    assert [(m.in_features, m.out_features) for m in model.head[::2]] == [(512, 256), (256, 256), (256, 1)]
    obs, goal = make_sets(torch.Generator().manual_seed(0))
    out = model(obs, goal)
    assert out.shape == (6,) and bool(((out > 0) & (out < 1)).all())


@pytest.mark.parametrize("centre", [True, False])
def test_invariant_to_entity_order(centre):
    torch.manual_seed(0)
    model = SetFeasibilityPredictor(FeasibilityConfig(centre_positions=centre)).eval()
    obs, goal = make_sets(torch.Generator().manual_seed(1))
    with torch.no_grad():
        ref = model(obs, goal)
        out = model(obs[:, [1, 0]], goal[:, [2, 0, 1]])
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=0)
    assert not torch.allclose(model(obs, goal[:, :1]), ref)  # the goal entities do matter


def test_padded_entities_do_not_change_the_output():
    torch.manual_seed(0)
    model = SetFeasibilityPredictor().eval()
    gen = torch.Generator().manual_seed(2)
    obs, goal = make_sets(gen)
    junk_obs = torch.cat([obs[:, :1], 100 * torch.randn(6, 2, 5, generator=gen), obs[:, 1:]], dim=1)
    junk_goal = torch.cat([goal, -50 * torch.randn(6, 1, 5, generator=gen)], dim=1)
    obs_mask = torch.tensor([True, False, False, True]).expand(6, 4)
    goal_mask = torch.tensor([True, True, True, False]).expand(6, 4)
    with torch.no_grad():
        torch.testing.assert_close(model(junk_obs, junk_goal, obs_mask, goal_mask), model(obs, goal), atol=1e-6, rtol=0)
    with pytest.raises(ValueError):
        model(obs, goal, torch.zeros(6, 2, dtype=torch.bool))


def test_centring_makes_it_translation_invariant():
    torch.manual_seed(0)
    model = SetFeasibilityPredictor()
    obs, goal = make_sets(torch.Generator().manual_seed(3))
    shift = torch.tensor([0.0, 0.0, 0.3, -0.1, 0.2])  # positions only
    torch.testing.assert_close(model(obs + shift, goal + shift), model(obs, goal), atol=1e-5, rtol=0)


def test_training_separates_positives_from_negatives():
    torch.manual_seed(0)
    model = SetFeasibilityPredictor(tiny_model_config().feasibility)
    gen = torch.Generator().manual_seed(4)
    # synthetic skill: the goal entity sits 0.1 to the +x of the observation entity, with the same shape code
    obs = torch.cat([0.3 * torch.randn(32, 1, 2, generator=gen), 0.2 + 0.6 * torch.rand(32, 1, 3, generator=gen)], -1)
    goal = obs + torch.tensor([0.0, 0.0, 0.1, 0.0, 0.0])
    prior = LatentPrior(2, (0.2, 0.2, 0.2), (0.9, 0.8, 0.8))
    batch = feasibility_batch(
        obs, goal, None, None, prior, sigma_z=0.02, sigma_t=0.01, hard_copies=4, n_random=64, generator=gen
    )

    def loss():
        return weighted_mse(model(batch.obs, batch.goal, batch.obs_mask, batch.goal_mask), batch.labels, batch.weights)

    first, last = train(loss, model.parameters(), lr=3e-3)
    assert last < 0.7 * first
