"""Set feasibility predictor ``f_k(U^o, U^g)``: is the goal set reachable from the observation set by skill k?

Architecture (model_spec §2.2, the official ``v3``/``v4`` reconstructed, appendix §1.4): a per-entity
MLP on the observation entities and a separate one on the goal entities, each max-pooled over its
set (permutation invariance), then an MLP on the concatenation ``512 -> 256 -> 256 -> 1``.

Differences from the official code, both deliberate:

* the output goes through a sigmoid, so it is a probability in (0, 1) with gradients everywhere; the
  official output was linear, regressed to {0, 1} and clamped to [0, 1] at planning, which kills
  gradients outside that range (model_spec §2.2, §10 item 8);
* one architecture for every skill shape (the official used a flat MLP for 1->1 skills); with one
  entity per side max-pooling is the identity, so it is the same function class.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pasta.models.layers import SetMaxPool, centre_set_positions, check_set, mlp, orthogonal_init_

__all__ = ["FeasibilityConfig", "SetFeasibilityPredictor"]


@dataclass(frozen=True)
class FeasibilityConfig:
    """Feasibility hyper-parameters.

    Attributes:
        latent_dim: ``D_z``; entities are ``D_z + 3`` numbers.
        entity_channels: per-entity MLP widths after the input (official net1/net2: ``5 -> 256 -> 256``).
        head_channels: hidden widths of the MLP on the pooled pair (official net3: ``512 -> 256 -> 256 -> 1``).
        centre_positions: subtract the mean ``t`` of all entities of both sets (official ``fea_center``),
            making the prediction invariant to translating the whole input.
    """

    latent_dim: int = 2
    entity_channels: tuple[int, ...] = (256, 256)
    head_channels: tuple[int, ...] = (256, 256)
    centre_positions: bool = True

    @property
    def entity_dim(self) -> int:
        return self.latent_dim + 3


class SetFeasibilityPredictor(nn.Module):
    """``f(U^o, U^g)`` in (0, 1) for observation and goal latent sets with optional masks.

    Orthogonal weights and zero biases, as the official ``weight_init``.
    """

    def __init__(self, config: FeasibilityConfig = FeasibilityConfig()) -> None:
        super().__init__()
        self.config = config
        self.obs_encoder = SetMaxPool((config.entity_dim, *config.entity_channels))
        self.goal_encoder = SetMaxPool((config.entity_dim, *config.entity_channels))
        self.head = mlp((2 * config.entity_channels[-1], *config.head_channels, 1), final_activation=False)
        orthogonal_init_(self)

    def forward(
        self,
        obs: torch.Tensor,
        goal: torch.Tensor,
        obs_mask: torch.Tensor | None = None,
        goal_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Feasibility of each pair of sets.

        Args:
            obs: ``(B, K_o, D_z + 3)`` observation entities (the attended inputs of the skill).
            goal: ``(B, K_g, D_z + 3)`` goal entities (the skill's outputs).
            obs_mask: ``(B, K_o)`` bool, ``True`` for real entities; ``None`` means all real.
            goal_mask: ``(B, K_g)`` likewise.

        Returns:
            ``(B,)`` probabilities; padded entities do not affect them.
        """
        obs_mask = check_set(obs, obs_mask, self.config.entity_dim, "obs")
        goal_mask = check_set(goal, goal_mask, self.config.entity_dim, "goal")
        if obs.shape[0] != goal.shape[0]:
            raise ValueError(f"batch sizes differ: obs {tuple(obs.shape)}, goal {tuple(goal.shape)}")
        if self.config.centre_positions:
            obs, goal = centre_set_positions((obs, goal), (obs_mask, goal_mask), self.config.latent_dim)
        pooled = torch.cat([self.obs_encoder(obs, obs_mask), self.goal_encoder(goal, goal_mask)], dim=-1)
        return torch.sigmoid(self.head(pooled).squeeze(-1))
