"""Minimum-cost matching of achieved entities to goal entities, batched.

For small sets every injective assignment is tried at once as tensor ops (at most ``max_candidates``
of them; 24 for four entities), which is far cheaper than one scipy call per sample. Larger sets fall back
to ``scipy.optimize.linear_sum_assignment`` per sample. With unequal counts ``min(K_a, K_g)`` pairs are
matched (partial matching).
"""

from __future__ import annotations

import itertools
import math

import torch

from pasta.models.cost import hungarian_assignment

__all__ = ["best_matching", "matched_pair_cost"]


def best_matching(pair_costs: torch.Tensor, max_candidates: int = 720) -> tuple[torch.Tensor, torch.Tensor]:
    """Pairs of the cheapest matching of each batch element.

    Args:
        pair_costs: ``(B, K_a, K_g)``; only its values are used.
        max_candidates: enumerate assignments when there are at most this many, else use scipy.

    Returns:
        ``(rows, cols)``, each ``(B, M)`` long with ``M = min(K_a, K_g)``: row ``rows[b, i]`` of ``pair_costs[b]``
        is matched to column ``cols[b, i]``.
    """
    costs = pair_costs.detach()
    batch, k_a, k_g = costs.shape
    small, big = min(k_a, k_g), max(k_a, k_g)
    device = costs.device
    if math.perm(big, small) > max_candidates:
        assignment = hungarian_assignment(costs)  # (B, K_a), -1 where unmatched
        order = (assignment < 0).to(torch.int8).argsort(dim=1, stable=True)[:, :small]
        return order, assignment.gather(1, order)
    if k_a > k_g:
        cols, rows = best_matching(costs.transpose(1, 2), max_candidates)
        return rows, cols
    candidates = torch.tensor(list(itertools.permutations(range(k_g), k_a)), device=device)  # (P, K_a)
    rows = torch.arange(k_a, device=device)
    totals = costs[:, rows.expand_as(candidates), candidates].sum(dim=-1)  # (B, P)
    best = candidates[totals.argmin(dim=1)]  # (B, K_a)
    return rows.expand(batch, k_a), best


def matched_pair_cost(pair_costs: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """Sum of ``pair_costs (B, K_a, K_g)`` over the pairs ``(rows, cols)`` (each ``(B, M)``) -> ``(B,)``."""
    picked = pair_costs.gather(1, rows.unsqueeze(-1).expand(-1, -1, pair_costs.shape[2]))  # (B, M, K_g)
    return picked.gather(2, cols.unsqueeze(-1)).squeeze(-1).sum(dim=1)
