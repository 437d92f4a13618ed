"""Small synthetic problems and tiny configs shared by the model tests."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch

from pasta.models import (
    CostConfig,
    FeasibilityConfig,
    LatentPolicyConfig,
    ModelConfig,
    PointNetPlusPlusConfig,
    PolicyConfig,
    SetAbstractionStage,
    ToolConcatPolicyConfig,
    VAEConfig,
    uniform_point_noise,
)


def box_clouds(batch: int, n_points: int, generator: torch.Generator) -> torch.Tensor:
    """``(batch, n_points, 3)`` points filling random axis-aligned boxes (half sizes 0.02-0.08) in [0.2, 0.8]^3."""
    centre = 0.3 + 0.4 * torch.rand(batch, 1, 3, generator=generator)
    half = 0.02 + 0.06 * torch.rand(batch, 1, 3, generator=generator)
    return centre + half * (2 * torch.rand(batch, n_points, 3, generator=generator) - 1)


def goal_offset_problem(generator: torch.Generator) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Behaviour cloning toward a goal: noisy (obs, tool, goal) clouds of 8 samples and the actions ``(8, 3)``
    that move the observation's centre toward the goal's (clamped to [-1, 1])."""
    obs, tool = box_clouds(8, 48, generator), box_clouds(8, 8, generator)
    goal = obs + 0.3 * (2 * torch.rand(8, 1, 3, generator=generator) - 1)
    action = ((goal.mean(1) - obs.mean(1)) / 0.3).clamp(-1, 1)
    clouds = [uniform_point_noise(x, 0.005, generator) for x in (obs, tool, goal)]
    return clouds, action


def tiny_encoder(in_features: int) -> PointNetPlusPlusConfig:
    return PointNetPlusPlusConfig(
        in_features=in_features,
        stages=(SetAbstractionStage(0.5, 0.05, (16, 32)), SetAbstractionStage(0.25, 0.1, (32, 32))),
        global_channels=(32, 64),
        max_neighbours=16,
    )


def tiny_model_config() -> ModelConfig:
    """Narrow layers everywhere, for fast training tests."""
    return ModelConfig(
        vae=VAEConfig(encoder_channels=(32, 64), head_hidden=32, decoder_channels=(64,), n_decoded_points=64),
        feasibility=FeasibilityConfig(entity_channels=(32, 32), head_channels=(32,)),
        cost=CostConfig(hidden_channels=(64, 64, 64)),
        policy=PolicyConfig(encoder=tiny_encoder(3), head_channels=(32,)),
        tool_concat_policy=ToolConcatPolicyConfig(encoder=tiny_encoder(2), tool_channels=(16,), head_channels=(32,)),
        latent_policy=LatentPolicyConfig(entity_channels=(32,), head_channels=(32,)),
    )


def train(loss_fn: Callable[[], torch.Tensor], params: Iterable[torch.nn.Parameter], steps: int = 20, lr: float = 1e-3):
    """Adam on a fixed problem; returns (initial loss, final loss), the final one measured after the last step."""
    optimiser = torch.optim.Adam(list(params), lr=lr)
    first = None
    for _ in range(steps):
        loss = loss_fn()
        first = loss.item() if first is None else first
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        return first, float(loss_fn())
