"""The two policy ablations of appendix §4.1 (model_spec §4.6).

* ``ToolConcatPolicy`` ("Tool Concat Policy", official ``PointActorCat``): PointNet++ over the
  observation and goal clouds only (two one-hot roles), the tool *state* encoded by a small MLP and
  concatenated after the encoder: ``[1024, 16] -> 512 -> 256 -> action_dim``. With the compact encoder
  (``point_encoder = "pointnet"``) the two clouds get a PointNet each instead:
  ``[2 x 256, 16] -> 256 -> 256 -> action_dim``.
* ``LatentSetPolicy`` ("Shared Encoder Policy", official ``ActorV4``): acts on the VAE latents instead
  of points. As the appendix describes it ("very similar to our Set Feasibility Predictor"), the
  observation and goal sets go through separate per-entity MLPs, are max-pooled, concatenated and mapped
  to the action; the official ``ActorV4`` pooled both sets together through one MLP. No tool input and no
  point encoder, so the choice of point encoder does not concern it.

Both outputs are linear; ``ToolConcatPolicy`` is scaled by 1/5 like the set policy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from pasta.models.cloud_pointnet import CloudPointNetConfig
from pasta.models.layers import SetMaxPool, check_set, mlp, orthogonal_init_
from pasta.models.pointnet import PointNetPlusPlusConfig
from pasta.models.policy import check_point_encoder, encode_clouds, point_encoder

__all__ = ["LatentPolicyConfig", "LatentSetPolicy", "ToolConcatPolicy", "ToolConcatPolicyConfig"]


@dataclass(frozen=True)
class ToolConcatPolicyConfig:
    """Tool-concat hyper-parameters (official ``actor_latent_dim`` = 64 for the tool MLP).

    Attributes:
        point_encoder: ``pointnet2`` (``encoder``, then ``head_channels``) or ``pointnet`` (``pointnet``, then
            ``pointnet.head_channels``), as the set policy's.
        encoder: PointNet++ with ``in_features`` = 2 (observation, goal).
        tool_state_dim: numbers per tool state (8: position, quaternion, gap).
        tool_channels: tool-state MLP widths after the input (``8 -> 64 -> 64 -> 16``).
        head_channels: hidden widths of the action MLP after the PointNet++ (``[512, 256]``).
        pointnet: the compact encoder and the widths of its action MLP.
        output_scale: factor on the linear output (official 1/5).
    """

    point_encoder: str = "pointnet2"
    encoder: PointNetPlusPlusConfig = field(default_factory=lambda: PointNetPlusPlusConfig(in_features=2))
    tool_state_dim: int = 8
    tool_channels: tuple[int, ...] = (64, 64, 16)
    head_channels: tuple[int, ...] = (512, 256)
    pointnet: CloudPointNetConfig = field(default_factory=CloudPointNetConfig)
    output_scale: float = 0.2

    def __post_init__(self) -> None:
        check_point_encoder(self.point_encoder)

    @property
    def action_head_channels(self) -> tuple[int, ...]:
        """Hidden widths of the action MLP that follows the chosen encoder."""
        return self.pointnet.head_channels if self.point_encoder == "pointnet" else self.head_channels


class ToolConcatPolicy(nn.Module):
    """``(obs (B, N_o, 3), goal (B, N_g, 3), tool_state (B, tool_state_dim))`` -> action ``(B, action_dim)``."""

    def __init__(self, action_dim: int, config: ToolConcatPolicyConfig = ToolConcatPolicyConfig()) -> None:
        super().__init__()
        self.config = config
        self.action_dim = action_dim
        self.encoder = point_encoder(config.point_encoder, config.encoder, config.pointnet, n_clouds=2)
        self.tool_net = mlp((config.tool_state_dim, *config.tool_channels), final_activation=True)
        width = self.encoder.out_dim + config.tool_channels[-1]
        self.head = mlp((width, *config.action_head_channels, action_dim), final_activation=False)
        orthogonal_init_(self.tool_net)
        orthogonal_init_(self.head)

    def forward(self, obs_points: torch.Tensor, goal_points: torch.Tensor, tool_state: torch.Tensor) -> torch.Tensor:
        if tool_state.shape != (obs_points.shape[0], self.config.tool_state_dim):
            raise ValueError(
                f"tool_state must have shape ({obs_points.shape[0]}, {self.config.tool_state_dim}), "
                f"got {tuple(tool_state.shape)}"
            )
        points = encode_clouds(self.encoder, (obs_points, goal_points))
        features = torch.cat([points, self.tool_net(tool_state)], dim=-1)
        return self.head(features) * self.config.output_scale


@dataclass(frozen=True)
class LatentPolicyConfig:
    """Latent-set policy hyper-parameters (official ``actor_latent_dim`` h = 64).

    Attributes:
        latent_dim: ``D_z``.
        entity_channels: per-entity MLP widths after the input (``5 -> 64 -> 64``).
        head_channels: hidden widths of the action MLP (``128 -> 64 -> 64 -> 64 -> action_dim``).
    """

    latent_dim: int = 2
    entity_channels: tuple[int, ...] = (64, 64)
    head_channels: tuple[int, ...] = (64, 64, 64)

    @property
    def entity_dim(self) -> int:
        return self.latent_dim + 3


class LatentSetPolicy(nn.Module):
    """``(obs (B, K_o, E), goal (B, K_g, E), masks)`` -> action ``(B, action_dim)``; invariant to entity order."""

    def __init__(self, action_dim: int, config: LatentPolicyConfig = LatentPolicyConfig()) -> None:
        super().__init__()
        self.config = config
        self.action_dim = action_dim
        self.obs_encoder = SetMaxPool((config.entity_dim, *config.entity_channels))
        self.goal_encoder = SetMaxPool((config.entity_dim, *config.entity_channels))
        self.head = mlp((2 * config.entity_channels[-1], *config.head_channels, action_dim), final_activation=False)
        orthogonal_init_(self)

    def forward(
        self,
        obs: torch.Tensor,
        goal: torch.Tensor,
        obs_mask: torch.Tensor | None = None,
        goal_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        obs_mask = check_set(obs, obs_mask, self.config.entity_dim, "obs")
        goal_mask = check_set(goal, goal_mask, self.config.entity_dim, "goal")
        pooled = torch.cat([self.obs_encoder(obs, obs_mask), self.goal_encoder(goal, goal_mask)], dim=-1)
        return self.head(pooled)
