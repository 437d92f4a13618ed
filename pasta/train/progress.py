"""What the training loops share: the epoch callback type, per-epoch seeding and the epoch progress bars.

Each epoch (each round of policy steps) draws from generators seeded by ``(seed, epoch)`` alone (the official
reseeds every epoch with ``(seed + 1) * (epoch + 1)``), so a run resumed from a checkpoint after epoch ``e``
draws exactly what an uninterrupted run draws from epoch ``e + 1`` on.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import torch
from rich.console import Console

from pasta.progress import stage_progress

__all__ = ["STEP_STAGES", "EpochBars", "EpochCallback", "epoch_generators", "epoch_status"]

EpochCallback = Callable[[str, int, dict[str, float]], None]
"""``on_epoch(stage, epoch, metrics)``: called after each finished (and checkpointed) epoch, ``epoch`` from 0;
for the stages of ``STEP_STAGES``, after each evaluation, ``epoch`` being the gradient steps taken so far."""

STEP_STAGES = frozenset({"policy", "dagger"})
"""Stages that count gradient steps instead of epochs (the policies' own loop, ``policy_loop``, and its DAgger
rounds, ``dagger``, counting on from the loop's last step)."""


def epoch_generators(seed: int, epoch: int, device: torch.device) -> tuple[np.random.Generator, torch.Generator]:
    """A numpy generator (sampling on the host) and a torch generator on ``device`` for one epoch."""
    mixed = (seed + 1) * 1_000_003 + epoch
    generator = torch.Generator(device=device)
    generator.manual_seed(mixed)
    return np.random.default_rng([seed, epoch]), generator


# Per stage, the metrics a bar shows: (key in the epoch's metrics, label).
SHOWN_METRICS: Mapping[str, tuple[tuple[str, str], ...]] = {
    "vae": (("vae_train_loss", "loss"), ("vae_heldout_chamfer_epoch", "held-out Chamfer")),
    "heads": (("train_feasibility_loss", "feasibility loss"), ("feasibility_auc_hard", "held-out AUC hard"),
              ("cost_r2", "held-out cost R2")),
    "policy": (("policy_train_loss", "loss"), ("policy_heldout_mse", "held-out policy MSE")),
    "dagger": (("dagger_round", "round"), ("dagger_train_loss", "loss"), ("dagger_heldout_mse", "held-out MSE")),
}


def epoch_status(stage: str, metrics: Mapping[str, float]) -> str:
    """The shown metrics of one epoch, e.g. ``loss 0.0412  held-out Chamfer 0.0105``."""
    return "  ".join(f"{label} {metrics[key]:.4g}" for key, label in SHOWN_METRICS.get(stage, ()) if key in metrics)


class EpochBars:
    """An :data:`EpochCallback` that shows one rich progress bar per training stage, then calls ``then``.

    Each bar counts the stage's epochs (gradient steps for ``STEP_STAGES``) out of ``totals[stage]`` and shows
    the latest loss and held-out metric (:func:`epoch_status`) and an ETA. A resumed stage jumps to its epoch
    at its first callback (the ETA counts only the epochs trained here). Use as a context manager around the
    training.
    """

    def __init__(self, labels: Mapping[str, str], totals: Mapping[str, int], then: EpochCallback | None = None,
                 console: Console | None = None) -> None:
        self.progress = stage_progress(console)
        self.totals = dict(totals)
        self.bars = {stage: self.progress.add_task(labels[stage], total=total, status="")
                     for stage, total in self.totals.items()}
        self.then = then

    def __enter__(self) -> EpochBars:
        self.progress.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.progress.stop()

    def __call__(self, stage: str, epoch: int, metrics: dict[str, float]) -> None:
        done = epoch if stage in STEP_STAGES else epoch + 1
        self.progress.update(self.bars[stage], completed=done, status=epoch_status(stage, metrics))
        if self.then is not None:
            self.then(stage, epoch, metrics)

    def finish(self, stage: str, status: str) -> None:
        """Fill ``stage``'s bar (also when it had nothing left to train) and show ``status``."""
        self.progress.update(self.bars[stage], completed=self.totals[stage], status=status)
