"""``PolicyEnsemble``: several policies of one skill, trained apart, acting as their mean.

Each member starts from its own initial weights and, in training, sees its own draw of the input noise; every
member fits the demonstrations on its own loss (``pasta.train.policy_loop.policy_loss`` averages the members'
losses, so no member is trained through the others). Executed, the ensemble acts the mean of the members'
actions: where behaviour cloning meets a state no demonstration shows, independently trained members err in
different directions and their mean errs less (Lakshminarayanan, Pritzel and Blundell, 2017, "deep ensembles").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import nn

__all__ = ["PolicyEnsemble", "policy_members"]


class PolicyEnsemble(nn.Module):
    """``members`` policies with one signature; ``forward`` returns the mean of their outputs ``(B, ...)``."""

    def __init__(self, members: Sequence[nn.Module]) -> None:
        super().__init__()
        if len(members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
        self.members = nn.ModuleList(members)

    @classmethod
    def build(cls, n_members: int, build_member: Callable[[], nn.Module]) -> PolicyEnsemble:
        """``n_members`` members, each from a new call of ``build_member`` (so each draws its own weights)."""
        return cls([build_member() for _ in range(n_members)])

    def forward(self, *inputs: torch.Tensor | None) -> torch.Tensor:
        """The members' outputs on the same ``inputs``, averaged over the members."""
        return torch.stack([member(*inputs) for member in self.members]).mean(dim=0)


def policy_members(policy: nn.Module) -> tuple[nn.Module, ...]:
    """The networks trained on their own losses: an ensemble's members, or the policy itself."""
    return tuple(policy.members) if isinstance(policy, PolicyEnsemble) else (policy,)
