"""Tool-concat and latent-set policies: shapes, tool-state use, entity-order and padding invariance."""

from __future__ import annotations

import pytest
import torch

from pasta.models import LatentSetPolicy, ToolConcatPolicy, ToolConcatPolicyConfig
from tests.models.synthetic import box_clouds, tiny_encoder


def test_tool_concat_policy_shapes_and_tool_state():
    torch.manual_seed(0)
    default = ToolConcatPolicy(15)
    assert default.encoder.config.in_features == 2 and default.head[0].in_features == 1024 + 16
    policy = ToolConcatPolicy(15, ToolConcatPolicyConfig(encoder=tiny_encoder(2), head_channels=(32,)))
    gen = torch.Generator().manual_seed(0)
    obs, goal = box_clouds(3, 40, gen), box_clouds(3, 40, gen)
    state = torch.rand(3, 8, generator=gen)
    out = policy(obs, goal, state)
    assert out.shape == (3, 15)
    assert not torch.allclose(policy(obs, goal, state + 1.0), out)
    with pytest.raises(ValueError):
        policy(obs, goal, state[:, :7])


def test_latent_set_policy_invariances():
    torch.manual_seed(0)
    policy = LatentSetPolicy(10).eval()
    gen = torch.Generator().manual_seed(1)
    obs, goal = torch.randn(4, 2, 5, generator=gen), torch.randn(4, 3, 5, generator=gen)
    with torch.no_grad():
        ref = policy(obs, goal)
        assert ref.shape == (4, 10)
        torch.testing.assert_close(policy(obs[:, [1, 0]], goal[:, [2, 1, 0]]), ref, atol=1e-5, rtol=0)
        padded = torch.cat([obs, 9 * torch.ones(4, 1, 5)], dim=1)
        mask = torch.tensor([True, True, False]).expand(4, 3)
        torch.testing.assert_close(policy(padded, goal, mask), ref, atol=1e-6, rtol=0)
