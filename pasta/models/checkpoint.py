"""Model checkpoints: state dicts, optimiser states, epoch and the resolved config, in one atomic file.

``save_checkpoint`` writes to a temporary file in the destination's directory, fsyncs it and
``os.replace``s it over the destination, so an interrupted save never leaves a half file.
``load_checkpoint`` uses ``torch.load(weights_only=True)``: no arbitrary pickles are executed, so the
config must be plain data (dicts, lists, tuples, strings, numbers, booleans, ``None``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from pasta.data.storage import atomic_write_bytes

__all__ = ["CHECKPOINT_FORMAT", "Checkpoint", "load_checkpoint", "restore_models", "save_checkpoint"]

CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class Checkpoint:
    """What ``load_checkpoint`` returns. Tensors are on the ``map_location`` device."""

    model_states: dict[str, dict[str, Any]]
    optimiser_states: dict[str, dict[str, Any]]
    epoch: int
    config: dict[str, Any]


def save_checkpoint(
    path: str | os.PathLike[str],
    models: Mapping[str, nn.Module],
    optimiser_states: Mapping[str, dict[str, Any]] | None,
    epoch: int,
    config_dict: Mapping[str, Any],
) -> Path:
    """Write ``models``' state dicts, optimiser states, ``epoch`` and ``config_dict`` to ``path`` atomically.

    Args:
        path: destination file (its directory is created if missing); an existing file is replaced.
        models: name -> module (e.g. the dict of ``build_models``).
        optimiser_states: name -> ``optimizer.state_dict()``, or ``None``.
        epoch: epochs completed.
        config_dict: the resolved configuration, plain data.

    Returns:
        The destination path.
    """
    destination = Path(path)
    destination.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "models": {name: module.state_dict() for name, module in models.items()},
        "optimisers": dict(optimiser_states or {}),
        "epoch": int(epoch),
        "config": dict(config_dict),
    }
    atomic_write_bytes(destination, lambda handle: torch.save(payload, handle))
    return destination


def load_checkpoint(path: str | os.PathLike[str], map_location: str | torch.device = "cpu") -> Checkpoint:
    """Read a checkpoint written by ``save_checkpoint``.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: the file is not a checkpoint of this format.
    """
    payload = torch.load(Path(path), map_location=map_location, weights_only=True)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a pasta checkpoint of format {CHECKPOINT_FORMAT}")
    return Checkpoint(payload["models"], payload["optimisers"], payload["epoch"], payload["config"])


def restore_models(models: Mapping[str, nn.Module], checkpoint: Checkpoint) -> None:
    """Load the checkpoint's state dicts into ``models`` (strict: the names and every key must match)."""
    if set(models) != set(checkpoint.model_states):
        raise ValueError(f"model names differ: given {sorted(models)}, checkpoint {sorted(checkpoint.model_states)}")
    for name, module in models.items():
        module.load_state_dict(checkpoint.model_states[name])
