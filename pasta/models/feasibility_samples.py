"""Training samples for the feasibility predictor: latent noise, random and hard negatives (appendix §1.2).

Pure functions on latent sets ``(n, K, D_z + 3)`` with masks ``(n, K)``; all randomness comes from an
explicit ``torch.Generator``. Following the official ``get_succ_loss`` (model_spec §2.5-2.6):

* positives get Gaussian noise ``sigma_z`` on ``z`` and ``sigma_t`` on ``t`` (appendix Table 3);
* hard negatives are ``copies`` copies of each *noised* positive with one real entity, chosen uniformly
  among the observation and goal entities, replaced by a fresh draw from ``P_u``;
* random negatives are whole sets of independent draws from ``P_u``; each takes the masks of a random
  positive, so padded layouts match;
* labels are 1 for positives and 0 for negatives; weights are ``0.5 / n_pos`` per positive,
  ``0.25 / n_hard`` per hard and ``0.25 / n_random`` per random negative. (The official code divided the
  weighted sum once more by the sample count, which only rescales the learning rate; not done here.)
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from pasta.models import random_draws
from pasta.models.latent_prior import LatentPrior

__all__ = [
    "FeasibilityBatch",
    "HardNegatives",
    "add_latent_noise",
    "feasibility_batch",
    "hard_negatives",
    "random_negatives",
    "weighted_mse",
]


def _mask_or_full(u: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    return torch.ones(u.shape[:2], dtype=torch.bool, device=u.device) if mask is None else mask


def add_latent_noise(
    u: torch.Tensor, latent_dim: int, sigma_z: float, sigma_t: float, generator: torch.Generator | None
) -> torch.Tensor:
    """``z + sigma_z * eps`` and ``t + sigma_t * eps`` with ``eps ~ N(0, I)``, for ``u (..., D_z + 3)``.

    Returns a new tensor; with both sigmas 0 it equals ``u``.
    """
    sigma = torch.tensor([sigma_z] * latent_dim + [sigma_t] * 3, dtype=u.dtype, device=u.device)
    return u + sigma * random_draws.randn(u.shape, generator, dtype=u.dtype, device=u.device)


def random_negatives(
    prior: LatentPrior,
    n: int,
    n_obs: int,
    n_goal: int,
    generator: torch.Generator | None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` random set pairs, every entity drawn from ``prior``: obs ``(n, n_obs, E)``, goal ``(n, n_goal, E)``."""
    return (
        prior.sample((n, n_obs), generator, dtype, device),
        prior.sample((n, n_goal), generator, dtype, device),
    )


class HardNegatives(NamedTuple):
    """Hard negatives and which entity of each was replaced.

    ``replaced (n,)`` indexes the concatenated entity axis ``[obs entities, goal entities]``: values
    below ``K_o`` are observation entities, the rest goal entity ``replaced - K_o``.
    """

    obs: torch.Tensor
    goal: torch.Tensor
    obs_mask: torch.Tensor
    goal_mask: torch.Tensor
    replaced: torch.Tensor


def hard_negatives(
    obs: torch.Tensor,
    goal: torch.Tensor,
    obs_mask: torch.Tensor | None,
    goal_mask: torch.Tensor | None,
    prior: LatentPrior,
    copies: int,
    generator: torch.Generator | None,
) -> HardNegatives:
    """``copies`` copies of each positive with exactly one real entity replaced by a draw from ``prior``.

    Args:
        obs: ``(n, K_o, E)`` positive observation sets.
        goal: ``(n, K_g, E)`` positive goal sets.
        obs_mask: ``(n, K_o)`` bool or ``None`` (all real); padded slots are never replaced.
        goal_mask: ``(n, K_g)`` likewise.
        prior: where the replacement entity comes from.
        copies: negatives per positive (official 10).
        generator: source of the choice and the draw.

    Returns:
        ``HardNegatives`` with ``n * copies`` rows; copy ``j`` of positive ``i`` is row ``i * copies + j``.
    """
    obs_mask = _mask_or_full(obs, obs_mask)
    goal_mask = _mask_or_full(goal, goal_mask)
    n_obs = obs.shape[1]
    entities = torch.cat([obs, goal], dim=1).repeat_interleave(copies, dim=0)  # (n * c, K_o + K_g, E)
    valid = torch.cat([obs_mask, goal_mask], dim=1).repeat_interleave(copies, dim=0)
    replaced = random_draws.multinomial(valid.to(obs.dtype), 1, generator).squeeze(1)  # (n * c,)
    rows = torch.arange(entities.shape[0], device=obs.device)
    entities[rows, replaced] = prior.sample((entities.shape[0],), generator, obs.dtype, obs.device)
    return HardNegatives(
        entities[:, :n_obs],
        entities[:, n_obs:],
        valid[:, :n_obs],
        valid[:, n_obs:],
        replaced,
    )


class FeasibilityBatch(NamedTuple):
    """Positives, then hard negatives, then random negatives, with labels and loss weights ``(n_total,)``."""

    obs: torch.Tensor
    goal: torch.Tensor
    obs_mask: torch.Tensor
    goal_mask: torch.Tensor
    labels: torch.Tensor
    weights: torch.Tensor


def feasibility_batch(
    obs: torch.Tensor,
    goal: torch.Tensor,
    obs_mask: torch.Tensor | None,
    goal_mask: torch.Tensor | None,
    prior: LatentPrior,
    *,
    sigma_z: float,
    sigma_t: float,
    hard_copies: int,
    n_random: int,
    generator: torch.Generator | None,
) -> FeasibilityBatch:
    """One training batch from ``n_pos`` positive pairs (model_spec §2.3-2.6).

    Args:
        obs: ``(n_pos, K_o, E)`` positive observation sets.
        goal: ``(n_pos, K_g, E)`` positive goal sets.
        obs_mask: ``(n_pos, K_o)`` bool or ``None``.
        goal_mask: ``(n_pos, K_g)`` bool or ``None``.
        prior: ``P_u`` for the negatives.
        sigma_z: latent noise on ``z`` of the positives (0 for "No Smoothing Feasibility").
        sigma_t: latent noise on ``t`` of the positives.
        hard_copies: hard negatives per positive (official 10).
        n_random: random negatives (official 2048).
        generator: all randomness.

    Returns:
        ``n_pos + hard_copies * n_pos + n_random`` rows.
    """
    obs_mask = _mask_or_full(obs, obs_mask)
    goal_mask = _mask_or_full(goal, goal_mask)
    n_pos = obs.shape[0]
    if n_pos == 0 or goal.shape[0] != n_pos:
        raise ValueError(f"need the same number (>= 1) of observation and goal sets, got {n_pos}, {goal.shape[0]}")
    obs = add_latent_noise(obs, prior.latent_dim, sigma_z, sigma_t, generator)
    goal = add_latent_noise(goal, prior.latent_dim, sigma_z, sigma_t, generator)
    hard = hard_negatives(obs, goal, obs_mask, goal_mask, prior, hard_copies, generator)
    rand_obs, rand_goal = random_negatives(
        prior, n_random, obs.shape[1], goal.shape[1], generator, obs.dtype, obs.device
    )
    source = random_draws.randint(n_pos, (n_random,), generator, device=obs.device)
    n_hard = hard.obs.shape[0]

    def weights(count: int, total: float) -> torch.Tensor:
        return torch.full((count,), total / max(count, 1), dtype=obs.dtype, device=obs.device)

    return FeasibilityBatch(
        obs=torch.cat([obs, hard.obs, rand_obs]),
        goal=torch.cat([goal, hard.goal, rand_goal]),
        obs_mask=torch.cat([obs_mask, hard.obs_mask, obs_mask[source]]),
        goal_mask=torch.cat([goal_mask, hard.goal_mask, goal_mask[source]]),
        labels=torch.cat([torch.ones(n_pos), torch.zeros(n_hard + n_random)]).to(obs),
        weights=torch.cat([weights(n_pos, 0.5), weights(n_hard, 0.25), weights(n_random, 0.25)]),
    )


def weighted_mse(prediction: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """``sum(weights * (prediction - labels)^2)``: the feasibility loss of appendix eq. 4 with the official weights."""
    return (weights * (prediction - labels).square()).sum()
