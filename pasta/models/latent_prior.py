"""The distribution ``P_u`` of random entity latents ``u = [z, t]`` (appendix §1.1-1.2).

``z ~ N(0, I)`` (the VAE prior) and ``t ~ Uniform[t_min, t_max]``, the bounding box of the training
entities' centres. Used for random and hard feasibility negatives and for the planner's initialisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pasta.models import random_draws

__all__ = ["LatentPrior"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class LatentPrior:
    """Independent ``z ~ N(0, I_{latent_dim})`` and ``t ~ U(t_low, t_high)`` per axis."""

    latent_dim: int
    t_low: Vec3
    t_high: Vec3

    def __post_init__(self) -> None:
        if self.latent_dim < 1:
            raise ValueError(f"latent_dim must be >= 1, got {self.latent_dim}")
        if len(self.t_low) != 3 or len(self.t_high) != 3 or any(
            lo > hi for lo, hi in zip(self.t_low, self.t_high, strict=True)
        ):
            raise ValueError(f"need a 3-D box with t_low <= t_high, got {self.t_low}, {self.t_high}")

    @classmethod
    def from_centres(cls, centres: torch.Tensor, latent_dim: int) -> LatentPrior:
        """The box of training entity centres ``(N, 3)`` (element-wise min and max, model_spec §1.5)."""
        if centres.ndim != 2 or centres.shape[1] != 3 or centres.shape[0] == 0:
            raise ValueError(f"centres must have shape (N, 3) with N >= 1, got {tuple(centres.shape)}")
        low = centres.min(dim=0).values.tolist()
        high = centres.max(dim=0).values.tolist()
        return cls(latent_dim, (low[0], low[1], low[2]), (high[0], high[1], high[2]))

    @property
    def entity_dim(self) -> int:
        return self.latent_dim + 3

    def sample(
        self,
        shape: tuple[int, ...],
        generator: torch.Generator | None,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> torch.Tensor:
        """Random entities ``(*shape, latent_dim + 3)``, drawn from ``generator``."""
        z = random_draws.randn((*shape, self.latent_dim), generator, dtype=dtype, device=device)
        low = torch.tensor(self.t_low, dtype=dtype, device=device)
        high = torch.tensor(self.t_high, dtype=dtype, device=device)
        unit = random_draws.rand((*shape, 3), generator, dtype=dtype, device=device)
        return torch.cat([z, low + unit * (high - low)], dim=-1)
