from __future__ import annotations

import itertools

import pytest
import torch

from pasta.plan import best_matching, matched_pair_cost
from pasta.plan.adam import RowAdam


def _brute_force(costs: torch.Tensor) -> float:
    k_a, k_g = costs.shape
    if k_a <= k_g:
        return min(sum(float(costs[i, p[i]]) for i in range(k_a)) for p in itertools.permutations(range(k_g), k_a))
    return _brute_force(costs.T)


def test_best_matching_is_optimal_for_square_and_partial_sets():
    gen = torch.Generator().manual_seed(0)
    for k_a, k_g in [(1, 1), (2, 2), (3, 3), (4, 4), (2, 3), (3, 2), (1, 4)]:
        costs = torch.rand((20, k_a, k_g), generator=gen)
        for max_candidates in (720, 1):  # enumeration, then the scipy fallback
            rows, cols = best_matching(costs, max_candidates)
            assert rows.shape == cols.shape == (20, min(k_a, k_g))
            totals = matched_pair_cost(costs, rows, cols)
            expected = torch.tensor([_brute_force(c) for c in costs])
            torch.testing.assert_close(totals, expected)


def test_matched_pair_cost_is_differentiable():
    gen = torch.Generator().manual_seed(1)
    for k_a, k_g in [(2, 2), (2, 3), (3, 2)]:
        costs = torch.rand((4, k_a, k_g), generator=gen, requires_grad=True)
        rows, cols = best_matching(costs)
        weights = torch.tensor([1.0, 2.0, 3.0, 4.0])  # tells the batch elements apart in the gradient
        (matched_pair_cost(costs, rows, cols) * weights).sum().backward()
        expected = torch.zeros_like(costs)
        for b in range(4):
            assert len(set(rows[b].tolist())) == len(set(cols[b].tolist())) == min(k_a, k_g), "a matching"
            expected[b, rows[b], cols[b]] = weights[b]
            assert float(costs.detach()[b, rows[b], cols[b]].sum()) == pytest.approx(_brute_force(costs[b].detach()))
        # d cost / d pair cost is 1 at the matched pairs and 0 elsewhere, per batch element
        torch.testing.assert_close(costs.grad, expected, rtol=0, atol=0)


def test_row_adam_matches_torch_adam_and_drops_rows():
    gen = torch.Generator().manual_seed(0)
    target = torch.randn((6, 4), generator=gen)
    ours = torch.zeros(6, 4)
    theirs = torch.zeros(6, 4, requires_grad=True)
    adam, reference = RowAdam(ours, 0.1), torch.optim.Adam([theirs], lr=0.1)
    for _ in range(5):
        adam.step(ours, 2 * (ours - target))
        reference.zero_grad()
        ((theirs - target) ** 2).sum().backward()
        reference.step()
    torch.testing.assert_close(ours, theirs.detach())
    keep = torch.tensor([1, 4])
    adam.keep_rows(keep)
    assert adam.exp_avg.shape == (2, 4)
    torch.testing.assert_close(adam.exp_avg, reference.state[theirs]["exp_avg"][keep])
