"""The arithmetic precision of training's forward passes: ``fp32`` throughout or ``bf16`` autocast.

``bf16`` runs the networks' matrix products (``Linear``, ``matmul``) in bfloat16 under ``torch.autocast``
while the weights, their gradients and Adam's state stay float32 (mixed precision). CPUs with AVX512-BF16
or AMX and recent GPUs multiply bfloat16 several times faster than float32; elsewhere torch emulates it
and ``bf16`` is slower. Losses are taken in float32: the callers cast the networks' outputs back before
comparing them, and distance computations that cancel (``|x|^2 + |y|^2 - 2 x.y``) switch autocast off.
"""

from __future__ import annotations

import contextlib

import torch

__all__ = ["PRECISIONS", "check_precision", "training_autocast"]

PRECISIONS = ("fp32", "bf16")


def check_precision(precision: str) -> str:
    """``precision`` if it is one of :data:`PRECISIONS`; a ``ValueError`` naming it otherwise."""
    if precision not in PRECISIONS:
        raise ValueError(f"unknown training precision {precision!r}; choose one of {list(PRECISIONS)}")
    return precision


def training_autocast(precision: str, device: torch.device) -> contextlib.AbstractContextManager:
    """A context for one forward pass on ``device``: bfloat16 autocast for ``bf16``, nothing for ``fp32``."""
    if check_precision(precision) == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
