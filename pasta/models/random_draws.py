"""Seeded random tensors for any device: drawn where the generator lives, then moved.

Training and planning seed one CPU ``torch.Generator`` so results do not depend on the device. Torch refuses
a CPU generator for a CUDA draw, so these helpers draw on the generator's device (the requested device
when there is no generator) and move the result.
"""

from __future__ import annotations

import torch

__all__ = ["multinomial", "rand", "randint", "randn"]


def _source(generator: torch.Generator | None, device: torch.device | str | None) -> torch.device | str | None:
    return generator.device if generator is not None else device


def randn(shape: tuple[int, ...] | torch.Size, generator: torch.Generator | None, *, dtype: torch.dtype | None = None,
          device: torch.device | str | None = None) -> torch.Tensor:
    """Standard normal ``shape`` tensor on ``device``."""
    return torch.randn(shape, generator=generator, dtype=dtype, device=_source(generator, device)).to(device)


def rand(shape: tuple[int, ...] | torch.Size, generator: torch.Generator | None, *, dtype: torch.dtype | None = None,
         device: torch.device | str | None = None) -> torch.Tensor:
    """Uniform ``[0, 1)`` ``shape`` tensor on ``device``."""
    return torch.rand(shape, generator=generator, dtype=dtype, device=_source(generator, device)).to(device)


def randint(high: int, shape: tuple[int, ...] | torch.Size, generator: torch.Generator | None, *,
            device: torch.device | str | None = None) -> torch.Tensor:
    """Integers uniform in ``[0, high)``, ``shape``, on ``device``."""
    return torch.randint(high, shape, generator=generator, device=_source(generator, device)).to(device)


def multinomial(weights: torch.Tensor, n_samples: int, generator: torch.Generator | None) -> torch.Tensor:
    """``torch.multinomial`` of ``weights (R, C)``, ``(R, n_samples)`` indices on ``weights``' device."""
    source = _source(generator, weights.device)
    return torch.multinomial(weights.to(source), n_samples, generator=generator).to(weights.device)
