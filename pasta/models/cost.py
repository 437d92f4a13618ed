"""Cost predictor: the Chamfer distance between two entities, from their latents (appendix eq. 5).

``c(u_a, u_b)`` is an MLP ``10 -> 1024 -> 1024 -> 1024 -> 1`` with ReLU (the official
``set_cost_predictor``: three hidden layers of 1024, model_spec §3.1). The two positions are centred on
their mean first (official ``rew_center``), so the input is ``(z_a, z_b, -dt/2, dt/2)``.

The output is linear, as in the official code. A softplus would keep it non-negative but saturates
where the targets live: Chamfer targets are 1e-4 to 1e-2 (squared metres), where
``softplus'(x) = sigmoid(x)`` is about the target itself, so the near-matched pairs the planner cares
about would learn slowest. The planner uses ``min(-C, 0)`` (model_spec §5.4), so a slightly negative
prediction is harmless.

A set cost sums the predicted costs of the entity pairs chosen by Hungarian matching on the predicted
pairwise costs (model_spec §3.4); the matching itself carries no gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from torch import nn

from pasta.models.layers import check_set, mlp, orthogonal_init_

__all__ = ["CostConfig", "CostPredictor", "hungarian_assignment", "matched_cost"]


@dataclass(frozen=True)
class CostConfig:
    """Cost hyper-parameters.

    Attributes:
        latent_dim: ``D_z``; entities are ``D_z + 3`` numbers.
        hidden_channels: hidden widths (official three of 1024).
        centre_positions: centre the two positions on their mean (official ``rew_center``, default on).
    """

    latent_dim: int = 2
    hidden_channels: tuple[int, ...] = (1024, 1024, 1024)
    centre_positions: bool = True

    @property
    def entity_dim(self) -> int:
        return self.latent_dim + 3


def hungarian_assignment(
    pair_costs: torch.Tensor, obs_mask: torch.Tensor | None = None, goal_mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Minimum-cost matching per batch element (``scipy.optimize.linear_sum_assignment``).

    Args:
        pair_costs: ``(B, K_o, K_g)``; only its values are used (no gradient).
        obs_mask: ``(B, K_o)`` bool or ``None``; padded entities take no part.
        goal_mask: ``(B, K_g)`` likewise.

    Returns:
        ``(B, K_o)`` long: the goal index matched to each observation entity, ``-1`` where unmatched.
        With unequal counts ``min(count_o, count_g)`` pairs are matched (partial matching, as RHP needs).
    """
    costs = pair_costs.detach().cpu().numpy()
    batch, n_obs, n_goal = costs.shape
    obs_ok = np.ones((batch, n_obs), bool) if obs_mask is None else obs_mask.cpu().numpy()
    goal_ok = np.ones((batch, n_goal), bool) if goal_mask is None else goal_mask.cpu().numpy()
    assignment = np.full((batch, n_obs), -1, dtype=np.int64)
    for b in range(batch):
        rows_valid = np.flatnonzero(obs_ok[b])
        cols_valid = np.flatnonzero(goal_ok[b])
        rows, cols = linear_sum_assignment(costs[b][np.ix_(rows_valid, cols_valid)])
        assignment[b, rows_valid[rows]] = cols_valid[cols]
    return torch.from_numpy(assignment).to(pair_costs.device)


def matched_cost(pair_costs: torch.Tensor, assignment: torch.Tensor) -> torch.Tensor:
    """Sum of ``pair_costs (B, K_o, K_g)`` over the pairs of ``assignment (B, K_o)`` (``-1`` skipped) -> ``(B,)``.

    Differentiable in ``pair_costs``; the planner can keep an assignment fixed across iterations.
    """
    matched = assignment >= 0
    picked = pair_costs.gather(2, assignment.clamp_min(0).unsqueeze(-1)).squeeze(-1)  # (B, K_o)
    return torch.where(matched, picked, torch.zeros_like(picked)).sum(dim=1)


class CostPredictor(nn.Module):
    """``c(u_a, u_b)``: predicted Chamfer distance between two entities. Orthogonal initialisation."""

    def __init__(self, config: CostConfig = CostConfig()) -> None:
        super().__init__()
        self.config = config
        self.net = mlp((2 * config.entity_dim, *config.hidden_channels, 1), final_activation=False)
        orthogonal_init_(self)

    def forward(self, u_a: torch.Tensor, u_b: torch.Tensor) -> torch.Tensor:
        """``u_a (..., E)``, ``u_b (..., E)`` (same leading shape) -> predicted Chamfer ``(...)``."""
        e = self.config.entity_dim
        if u_a.shape != u_b.shape or u_a.shape[-1] != e:
            raise ValueError(f"u_a and u_b must both have shape (..., {e}), got {tuple(u_a.shape)}, {tuple(u_b.shape)}")
        if self.config.centre_positions:
            d = self.config.latent_dim
            centre = 0.5 * (u_a[..., d:] + u_b[..., d:])
            u_a = torch.cat([u_a[..., :d], u_a[..., d:] - centre], dim=-1)
            u_b = torch.cat([u_b[..., :d], u_b[..., d:] - centre], dim=-1)
        return self.net(torch.cat([u_a, u_b], dim=-1)).squeeze(-1)

    def pairwise(self, obs: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Cost of every pair: ``obs (B, K_o, E)``, ``goal (B, K_g, E)`` -> ``(B, K_o, K_g)``."""
        n_obs, n_goal = obs.shape[1], goal.shape[1]
        a = obs.unsqueeze(2).expand(-1, -1, n_goal, -1)
        b = goal.unsqueeze(1).expand(-1, n_obs, -1, -1)
        return self.forward(a, b)

    def set_cost(
        self,
        obs: torch.Tensor,
        goal: torch.Tensor,
        obs_mask: torch.Tensor | None = None,
        goal_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``C(U^o, U^g)``: sum of predicted costs over the Hungarian matching of the predicted pairwise costs.

        Args:
            obs: ``(B, K_o, E)`` achieved entities.
            goal: ``(B, K_g, E)`` goal entities.
            obs_mask: ``(B, K_o)`` bool or ``None``; padded entities are never matched.
            goal_mask: ``(B, K_g)`` likewise.

        Returns:
            ``(B,)``, differentiable in the matched costs; invariant to the order of the entities.
        """
        obs_mask = check_set(obs, obs_mask, self.config.entity_dim, "obs")
        goal_mask = check_set(goal, goal_mask, self.config.entity_dim, "goal")
        pair_costs = self.pairwise(obs, goal)
        return matched_cost(pair_costs, hungarian_assignment(pair_costs, obs_mask, goal_mask))
