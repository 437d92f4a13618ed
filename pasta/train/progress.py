"""What the training loops share: the epoch callback type and per-epoch seeding.

Each epoch draws from generators seeded by ``(seed, epoch)`` alone (the official reseeds every epoch with
``(seed + 1) * (epoch + 1)``), so a run resumed from a checkpoint after epoch ``e`` draws exactly what an
uninterrupted run draws from epoch ``e + 1`` on.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

__all__ = ["EpochCallback", "epoch_generators"]

EpochCallback = Callable[[str, int, dict[str, float]], None]
"""``on_epoch(stage, epoch, metrics)``: called after each finished (and checkpointed) epoch, ``epoch`` from 0."""


def epoch_generators(seed: int, epoch: int, device: torch.device) -> tuple[np.random.Generator, torch.Generator]:
    """A numpy generator (sampling on the host) and a torch generator on ``device`` for one epoch."""
    mixed = (seed + 1) * 1_000_003 + epoch
    generator = torch.Generator(device=device)
    generator.manual_seed(mixed)
    return np.random.default_rng([seed, epoch]), generator
