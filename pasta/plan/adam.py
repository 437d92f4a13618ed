"""Adam on one tensor of independent rows, with rows that can be dropped mid-run.

The update is element-wise and identical to ``torch.optim.Adam`` with its defaults; keeping the moments
as plain tensors lets the planner drop samples (rows) together with their optimiser state.
"""

from __future__ import annotations

import math

import torch

__all__ = ["RowAdam"]


class RowAdam:
    """Adam state for a ``(B, ...)`` tensor whose rows are independent problems."""

    def __init__(self, like: torch.Tensor, lr: float, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.lr, self.betas, self.eps = lr, betas, eps
        self.exp_avg = torch.zeros_like(like)
        self.exp_avg_sq = torch.zeros_like(like)
        self.steps = 0

    @torch.no_grad()
    def step(self, params: torch.Tensor, grad: torch.Tensor) -> None:
        """Descend ``grad`` in place on ``params`` (same shape as the state)."""
        beta1, beta2 = self.betas
        self.steps += 1
        self.exp_avg.lerp_(grad, 1 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        correction1 = 1 - beta1 ** self.steps
        correction2 = 1 - beta2 ** self.steps
        denom = (self.exp_avg_sq.sqrt() / math.sqrt(correction2)).add_(self.eps)
        params.addcdiv_(self.exp_avg, denom, value=-self.lr / correction1)

    def keep_rows(self, rows: torch.Tensor) -> None:
        """Keep only the state of ``rows`` (long indices), in that order."""
        self.exp_avg = self.exp_avg[rows]
        self.exp_avg_sq = self.exp_avg_sq[rows]
