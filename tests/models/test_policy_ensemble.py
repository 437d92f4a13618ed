"""``PolicyEnsemble`` and ``ModelConfig.policy_members``: the mean of the members, built per skill by
``build_models``, stored with the model config."""

from __future__ import annotations

import pytest
import torch

from pasta.models import ModelConfig, build_models
from pasta.models.policy import SetPolicy
from pasta.models.policy_ablations import LatentSetPolicy, ToolConcatPolicy
from pasta.models.policy_ensemble import PolicyEnsemble, policy_members
from tests.models.synthetic import tiny_model_config


class Scale(torch.nn.Module):
    def __init__(self, factor: float) -> None:
        super().__init__()
        self.factor = factor

    def forward(self, x: torch.Tensor, y: torch.Tensor | None = None) -> torch.Tensor:
        return x * self.factor if y is None else x * self.factor + y


def test_the_ensemble_acts_the_mean_of_its_members_on_the_same_inputs():
    ensemble = PolicyEnsemble([Scale(1.0), Scale(2.0), Scale(6.0)])
    x = torch.arange(6.0).reshape(2, 3)
    torch.testing.assert_close(ensemble(x), x * 3.0)
    torch.testing.assert_close(ensemble(x, None), x * 3.0)
    torch.testing.assert_close(ensemble(x, torch.ones(2, 3)), x * 3.0 + 1.0)
    assert policy_members(ensemble) == tuple(ensemble.members)
    single = Scale(1.0)
    assert policy_members(single) == (single,)


def test_an_ensemble_of_one_is_refused():
    with pytest.raises(ValueError, match="at least 2 members, got 1"):
        PolicyEnsemble([Scale(1.0)])


def test_build_models_makes_one_ensemble_per_skill_with_members_drawn_apart():
    tiny_config = tiny_model_config()
    config = tiny_config.with_policy_members(3)
    policies = build_models("pasta", 6, config, n_skills=2)["policy"]
    assert all(isinstance(p, PolicyEnsemble) and len(p.members) == 3 for p in policies)
    weights = [next(member.parameters()).detach() for member in policies[0].members]
    assert not torch.equal(weights[0], weights[1]) and not torch.equal(weights[1], weights[2])
    single = build_models("pasta", 6, tiny_config, n_skills=2)["policy"]
    assert all(isinstance(p, SetPolicy) for p in single)


def test_the_ablation_policies_become_ensembles_of_their_own_kind():
    config = tiny_model_config().with_policy_members(2)
    for variant, kind in (("shared_encoder_policy", LatentSetPolicy), ("tool_concat_policy", ToolConcatPolicy)):
        policies = build_models(variant, 6, config)["policy"]
        assert all(isinstance(p, PolicyEnsemble) and all(isinstance(m, kind) for m in p.members) for p in policies)


def test_members_round_trip_through_the_dict_and_default_to_one_for_older_checkpoints():
    config = ModelConfig().with_policy_members(4)
    assert ModelConfig.from_dict(config.to_dict()).policy_members == 4
    older = config.to_dict()
    del older["policy_members"]
    assert ModelConfig.from_dict(older).policy_members == 1
    assert config.with_latent_dim(3).policy_members == 4
    with pytest.raises(ValueError, match="policy_members must be at least 1, got 0"):
        ModelConfig(policy_members=0)
