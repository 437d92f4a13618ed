"""A skill policy's action does not depend on the device the bundle sits on."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from pasta.evaluate.policy_action import PolicyInput, policy_action
from pasta.models.latent_prior import LatentPrior
from pasta.train.bundle import untrained


def _seen(rng: np.random.Generator) -> PolicyInput:
    return PolicyInput(obs_points=rng.uniform(0.4, 0.6, (1000, 3)), tool_points=rng.uniform(0.4, 0.6, (100, 3)),
                       tool_state=np.array([0.5, 0.2, 0.5, 1, 0, 0, 0, 0.1]),
                       goal_points=rng.uniform(0.4, 0.6, (2000, 3)),
                       goal_latents=LatentPrior(2, (0.4,) * 3, (0.6,) * 3).sample((2,), torch.Generator()))


@pytest.mark.gpu
@pytest.mark.parametrize("variant", ["pasta", "tool_concat_policy", "shared_encoder_policy"])
def test_policy_action_on_cuda_matches_the_cpu(cfg, variant):
    bundle = untrained(cfg, variant, LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8))).eval()
    seen = _seen(np.random.default_rng(0))
    on_cpu = policy_action(bundle, "cut", seen)
    on_gpu = policy_action(copy.deepcopy(bundle).to("cuda"), "cut", seen)
    np.testing.assert_allclose(on_gpu, on_cpu, rtol=1e-3, atol=1e-4)


def test_policy_action_is_a_finite_vector_of_the_action_size(cfg, bundle):
    seen = _seen(np.random.default_rng(1))
    action = policy_action(bundle, "cut", seen)
    assert action.shape == (10,) and action.dtype == np.float64 and np.isfinite(action).all()

    def batch(points: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(points.astype(np.float32)).unsqueeze(0)

    with torch.no_grad():
        direct = bundle.policy("cut")(batch(seen.obs_points), batch(seen.tool_points), batch(seen.goal_points))
    np.testing.assert_array_equal(action, direct.reshape(-1).double().numpy())
    with torch.no_grad():
        rearrange = bundle.policy("rearrange")(batch(seen.obs_points), batch(seen.tool_points),
                                               batch(seen.goal_points))
    assert not np.array_equal(action, rearrange.reshape(-1).double().numpy()), "the cut skill's own policy"


@pytest.mark.parametrize("variant", ["pasta", "tool_concat_policy", "shared_encoder_policy"])
def test_an_ensemble_acts_the_mean_of_its_members_actions_for_every_policy_kind(cfg, variant):
    """``policy.members: 2``: the executor reads each member with the inputs of its kind (clouds, the tool state
    or latents) and acts their mean."""
    cfg = cfg.model_copy(update={"policy": cfg.policy.model_copy(update={"members": 2})})
    bundle = untrained(cfg, variant, LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8))).eval()
    seen = _seen(np.random.default_rng(2))
    together = policy_action(bundle, "cut", seen)
    ensemble = bundle.models["policy"][0]
    alone = []
    for member in ensemble.members:
        bundle.models["policy"][0] = member
        alone.append(policy_action(bundle, "cut", seen))
    bundle.models["policy"][0] = ensemble
    assert not np.allclose(alone[0], alone[1])
    np.testing.assert_allclose(together, (alone[0] + alone[1]) / 2, rtol=1e-5, atol=1e-7)
