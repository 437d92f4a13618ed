"""Variant table, model building, and a few training steps of every model of every variant."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from pasta.models import (
    VARIANT_SPECS,
    VARIANTS,
    CostPredictor,
    LatentPrior,
    LatentSetPolicy,
    PointCloudVAE,
    SetFeasibilityPredictor,
    SetPolicy,
    ToolConcatPolicy,
    VariantSpec,
    build_models,
    feasibility_batch,
    variant_spec,
    weighted_mse,
)
from tests.models.synthetic import box_clouds, tiny_model_config, train

POLICY_CLASS = {
    "pasta": SetPolicy,
    "no_smoothing_feasibility": SetPolicy,
    "shared_encoder_policy": LatentSetPolicy,
    "tool_concat_policy": ToolConcatPolicy,
    "set_without_filtering": SetPolicy,
    "flat3d": SetPolicy,
}


def test_table_covers_every_variant_and_differs_from_pasta_in_its_switch():
    assert tuple(VARIANT_SPECS) == VARIANTS
    pasta = variant_spec("pasta")
    assert pasta == VariantSpec(True, False, False, True, False)
    changed = {
        name: {f.name for f in dataclasses.fields(VariantSpec) if getattr(spec, f.name) != getattr(pasta, f.name)}
        for name, spec in VARIANT_SPECS.items()
    }
    assert changed == {
        "pasta": set(),
        "no_smoothing_feasibility": {"latent_noise"},
        "shared_encoder_policy": {"policy_on_latents"},
        "tool_concat_policy": {"tool_state_after_encoder"},
        "set_without_filtering": {"filter_entities"},
        "flat3d": {"filter_entities", "whole_scene_latent"},
    }
    with pytest.raises(ValueError, match="known"):
        variant_spec("pasta2")
    with pytest.raises(ValueError):
        VariantSpec(True, True, True, True, False)


def test_build_models_is_seeded_and_leaves_global_rng_alone():
    state = torch.random.get_rng_state()
    first = build_models("pasta", 4, tiny_model_config(), n_skills=2, seed=3)
    second = build_models("pasta", 4, tiny_model_config(), n_skills=2, seed=3)
    assert torch.equal(torch.random.get_rng_state(), state)
    assert set(first) == {"vae", "feasibility", "cost", "policy"}
    assert len(first["feasibility"]) == len(first["policy"]) == 2
    for name in first:
        for (key, a), b in zip(first[name].state_dict().items(), second[name].state_dict().values(), strict=True):
            assert torch.equal(a, b), key
    other = build_models("pasta", 4, tiny_model_config(), seed=4)
    assert not torch.equal(other["cost"].net[0].weight, first["cost"].net[0].weight)


def policy_loss(policy, gen):
    """A behaviour-cloning loss on a fixed synthetic batch: the action points from the observation to the goal."""
    obs, tool = box_clouds(6, 32, gen), box_clouds(6, 8, gen)
    goal = obs + 0.3 * (2 * torch.rand(6, 1, 3, generator=gen) - 1)
    action = torch.cat([(goal.mean(1) - obs.mean(1)) / 0.3, torch.zeros(6, 1)], dim=-1)
    if isinstance(policy, LatentSetPolicy):
        u_obs = torch.cat([torch.zeros(6, 2), obs.mean(1)], -1)[:, None]
        u_goal = torch.cat([torch.zeros(6, 2), goal.mean(1)], -1)[:, None]
        inputs = (u_obs, u_goal)
    elif isinstance(policy, ToolConcatPolicy):
        inputs = (obs, goal, torch.rand(6, 8, generator=gen))
    else:
        inputs = (obs, tool, goal)
    return lambda: (policy(*inputs) - action).square().sum(-1).mean()


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_model_of_every_variant_trains(variant):
    models = build_models(variant, 4, tiny_model_config(), seed=0)
    vae, feasibility, cost, policy = models["vae"], models["feasibility"][0], models["cost"], models["policy"][0]
    assert isinstance(vae, PointCloudVAE) and isinstance(feasibility, SetFeasibilityPredictor)
    assert isinstance(cost, CostPredictor) and isinstance(policy, POLICY_CLASS[variant])
    spec = variant_spec(variant)
    gen = torch.Generator().manual_seed(0)

    clouds = box_clouds(8, 64, gen)
    vae.fit_scale(clouds)
    first, last = train(lambda: vae.elbo_loss(clouds, torch.Generator().manual_seed(0))[0], vae.parameters(), lr=3e-3)
    assert last < 0.5 * first, "vae"  # measured 0.26 of the first loss

    k = 1 if spec.whole_scene_latent else 2
    obs = torch.cat([torch.randn(16, k, 2, generator=gen), 0.3 + 0.4 * torch.rand(16, k, 3, generator=gen)], -1)
    goal = obs + torch.tensor([0.0, 0.0, 0.1, 0.0, 0.0])
    sigma = 0.01 if spec.latent_noise else 0.0
    batch = feasibility_batch(obs, goal, None, None, LatentPrior(2, (0.2,) * 3, (0.8,) * 3), sigma_z=sigma,
                              sigma_t=sigma, hard_copies=2, n_random=32, generator=gen)
    first, last = train(
        lambda: weighted_mse(feasibility(batch.obs, batch.goal, batch.obs_mask, batch.goal_mask), batch.labels,
                             batch.weights),
        feasibility.parameters(),
        steps=50,
        lr=3e-3,
    )
    assert last < 0.5 * first, "feasibility"  # measured 0.31 to 0.33

    u_a, u_b = torch.randn(32, 5, generator=gen), torch.randn(32, 5, generator=gen)
    target = (u_a - u_b).square().sum(-1) / 10
    first, last = train(lambda: (cost(u_a, u_b) - target).square().mean(), cost.parameters())
    assert last < 0.5 * first, "cost"  # measured 0.15 to 0.19

    first, last = train(policy_loss(policy, gen), policy.parameters(), steps=70, lr=3e-3)
    assert last < 0.5 * first, "policy"  # measured 0.03 to 0.37
