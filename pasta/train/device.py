"""The device training runs on: CUDA when available, else the CPU; chosen once, overridable."""

from __future__ import annotations

import torch

__all__ = ["training_device"]


def training_device(override: str | torch.device | None = None) -> torch.device:
    """``override`` if given (e.g. ``"cpu"``), else ``cuda`` when ``torch.cuda.is_available()``, else ``cpu``."""
    if override is not None:
        return torch.device(override)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")
