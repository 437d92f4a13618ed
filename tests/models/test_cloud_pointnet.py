"""The compact policy encoder (one PointNet per cloud): sizes, point-order invariance, input normalisation,
checkpoint round trip and a few training steps."""

from __future__ import annotations

import pytest
import torch

from pasta.models import (
    CloudPointNet,
    ModelConfig,
    PolicyConfig,
    SetPolicy,
    build_models,
    load_checkpoint,
    restore_models,
    save_checkpoint,
)
from pasta.models.cloud_pointnet import CloudPointNetConfig
from tests.models.synthetic import box_clouds, goal_offset_problem, tiny_model_config, train

COMPACT = PolicyConfig(point_encoder="pointnet")


def clouds(batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    return box_clouds(batch, 48, gen), box_clouds(batch, 8, gen), box_clouds(batch, 48, gen)


def test_default_compact_policy_is_the_probed_design():
    torch.manual_seed(0)
    policy = SetPolicy(10, COMPACT)
    assert isinstance(policy.encoder, CloudPointNet) and policy.encoder.out_dim == 768
    assert [(m.in_features, m.out_features) for m in policy.encoder.nets[0][::2]] == [(3, 64), (64, 128), (128, 256)]
    assert [(m.in_features, m.out_features) for m in policy.head[::2]] == [(768, 256), (256, 256), (256, 10)]
    assert sum(p.numel() for p in policy.parameters()) == 390_026  # "390 k parameters per skill"
    assert policy(*clouds(2, 0)).shape == (2, 10)


def test_first_training_batch_fixes_the_normalisation_and_evaluation_keeps_it():
    torch.manual_seed(0)
    encoder = CloudPointNet(3)
    first, second = clouds(4, 1), clouds(4, 2)
    encoder.eval()
    encoder(*first)
    assert not bool(encoder.fitted) and torch.equal(encoder.centre, torch.zeros(3))  # eval mode fits nothing
    encoder.train()
    encoder(*first)
    points = torch.cat([c.reshape(-1, 3) for c in first])
    torch.testing.assert_close(encoder.centre, points.mean(0))
    torch.testing.assert_close(encoder.scale, (points - points.mean(0)).square().mean().sqrt())
    fitted = encoder.centre.clone(), encoder.scale.clone()
    encoder(*second)
    assert bool(encoder.fitted) and torch.equal(encoder.centre, fitted[0]) and torch.equal(encoder.scale, fitted[1])


def test_output_is_invariant_to_point_order_within_each_cloud_not_to_swapping_clouds():
    torch.manual_seed(0)
    policy = SetPolicy(10, COMPACT)
    obs, tool, goal = clouds(3, 3)
    policy(obs, tool, goal)  # fits the normalisation
    policy.eval()
    gen = torch.Generator().manual_seed(4)
    shuffled = [c[:, torch.randperm(c.shape[1], generator=gen)] for c in (obs, tool, goal)]
    with torch.no_grad():
        reference = policy(obs, tool, goal)
        torch.testing.assert_close(policy(*shuffled), reference, rtol=0, atol=1e-6)
        assert not torch.allclose(policy(goal, tool, obs), reference, atol=1e-3)


def test_normalisation_travels_with_a_checkpoint(tmp_path):
    config = ModelConfig().with_policy_encoder("pointnet")
    models = build_models("pasta", 10, config, seed=0)
    policy = models["policy"][0]
    policy(*clouds(4, 5))  # training mode: fits centre and scale
    assert bool(policy.encoder.fitted) and float(policy.encoder.scale) < 0.5
    path = save_checkpoint(tmp_path / "models.pt", models, None, 1, config.to_dict())
    checkpoint = load_checkpoint(path)
    restored_config = ModelConfig.from_dict(checkpoint.config)
    assert restored_config.policy.point_encoder == "pointnet"
    fresh = build_models("pasta", 10, restored_config, seed=1)
    restore_models(fresh, checkpoint)
    restored = fresh["policy"][0].eval()
    for name in ("centre", "scale", "fitted"):
        assert torch.equal(getattr(restored.encoder, name), getattr(policy.encoder, name)), name
    inputs = clouds(2, 6)
    with torch.no_grad():
        assert torch.equal(restored(*inputs), policy.eval()(*inputs))


def test_unknown_encoder_is_refused_with_its_name():
    with pytest.raises(ValueError, match=r"unknown policy encoder 'pointnet3'.*pointnet2, pointnet"):
        PolicyConfig(point_encoder="pointnet3")
    with pytest.raises(ValueError, match="'pn'"):
        ModelConfig.from_dict({"tool_concat_policy": {"point_encoder": "pn"}})


def test_compact_policy_learns_a_goal_offset():
    torch.manual_seed(0)
    policy = SetPolicy(3, PolicyConfig(point_encoder="pointnet"))
    noisy, action = goal_offset_problem(torch.Generator().manual_seed(3))

    def loss():
        return (policy(*noisy) - action).square().sum(-1).mean()

    first, last = train(loss, policy.parameters(), steps=40, lr=1e-3)
    assert last < 0.5 * first


@pytest.mark.parametrize("variant, n_clouds", [("pasta", 3), ("tool_concat_policy", 2)])
def test_the_option_switches_both_point_cloud_policies_and_they_train(variant, n_clouds):
    config = tiny_model_config().with_policy_encoder("pointnet")
    assert config.with_latent_dim(3).tool_concat_policy.point_encoder == "pointnet"
    policy = build_models(variant, 4, config, seed=0)["policy"][0]
    assert isinstance(policy.encoder, CloudPointNet) and len(policy.encoder.nets) == n_clouds
    gen = torch.Generator().manual_seed(7)
    obs, tool = box_clouds(6, 32, gen), box_clouds(6, 8, gen)
    goal = obs + 0.3 * (2 * torch.rand(6, 1, 3, generator=gen) - 1)
    action = torch.cat([(goal.mean(1) - obs.mean(1)) / 0.3, torch.zeros(6, 1)], dim=-1)
    inputs = (obs, goal, torch.rand(6, 8, generator=gen)) if n_clouds == 2 else (obs, tool, goal)
    first, last = train(lambda: (policy(*inputs) - action).square().sum(-1).mean(), policy.parameters(), steps=40,
                        lr=1e-3)
    assert last < 0.5 * first


def test_pooling_matches_the_plain_mlp_and_max_with_gradients():
    gen = torch.Generator().manual_seed(21)
    encoder = CloudPointNet(2, CloudPointNetConfig(channels=(8, 16, 12))).double()
    clouds = [torch.randn(3, n, 3, generator=gen, dtype=torch.float64) for n in (30, 7)]
    encoder.fit_normalisation(*clouds)
    probe = torch.randn(3, encoder.out_dim, generator=gen, dtype=torch.float64)

    def output_and_gradients(encode):
        encoder.zero_grad()
        out = encode()
        (out * probe).sum().backward()
        return out.detach(), {name: p.grad.clone() for name, p in encoder.named_parameters()}

    def plain():
        pooled = [net((cloud - encoder.centre) / encoder.scale).max(dim=1).values
                  for net, cloud in zip(encoder.nets, clouds, strict=True)]
        return torch.cat(pooled, dim=-1)

    fast, fast_grads = output_and_gradients(lambda: encoder(*clouds))
    ref, ref_grads = output_and_gradients(plain)
    torch.testing.assert_close(fast, ref, rtol=1e-12, atol=1e-12)
    for name, grad in fast_grads.items():
        torch.testing.assert_close(grad, ref_grads[name], rtol=1e-10, atol=1e-12, msg=name)
