"""Training loop of the entity VAE (appendix eq. 2): Adam, held-out reconstruction Chamfer, best kept.

Optimisation follows the official PointFlow runs (model_spec §1.7): Adam at ``lr`` (Table 3: 2e-3),
constant for the first half of the epochs, then a linear decay stepped once per epoch. The batch size
(64) is ours: the official global batch of 1024-2048 spread over 8 GPUs gives a CPU a handful of steps
per epoch. After every epoch the reconstruction Chamfer of held-out entities (world units, decoding the
posterior mean) is measured; the weights with the lowest value are kept, and the progress (current and
best weights, optimiser, history) is checkpointed so an interrupted run resumes at the next epoch.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from pasta.geometry.distances import chamfer_distance
from pasta.models.checkpoint import load_checkpoint, restore_models, save_checkpoint
from pasta.models.vae import PointCloudVAE, VAEConfig
from pasta.train.precision import check_precision, training_autocast
from pasta.train.progress import EpochCallback, epoch_generators

__all__ = ["VAEResult", "VAESettings", "heldout_chamfer", "load_vae", "lr_factor", "save_vae", "train_vae"]


@dataclass(frozen=True)
class VAESettings:
    """Epochs, learning rate, batch size, forward precision (``fp32`` or ``bf16``) and seed of VAE training."""

    epochs: int
    lr: float
    batch_size: int = 64
    precision: str = "fp32"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.batch_size < 1 or self.lr <= 0:
            raise ValueError(f"need epochs >= 1, batch_size >= 1 and lr > 0, got {self}")
        check_precision(self.precision)


@dataclass(frozen=True, eq=False)
class VAEResult:
    """The best VAE (by held-out Chamfer), its epoch and value, and the per-epoch metrics."""

    vae: PointCloudVAE
    best_epoch: int
    heldout_chamfer: float
    history: list[dict[str, float]]


def lr_factor(epoch: int, epochs: int) -> float:
    """Learning-rate factor of ``epoch``: 1 for the first half, then linearly down to ``1 / (epochs - half)``."""
    half = epochs // 2
    return 1.0 if epoch < half else (epochs - epoch) / (epochs - half)


def heldout_chamfer(vae: PointCloudVAE, clouds: torch.Tensor, batch_size: int = 64) -> float:
    """Mean Chamfer distance (world units) between ``clouds (N, M, 3)`` and their decoded posterior means."""
    total = 0.0
    device = vae.scale.device
    with torch.no_grad():
        for start in range(0, len(clouds), batch_size):
            points = clouds[start : start + batch_size].to(device)
            z, _, t = vae.encode(points)
            total += float(chamfer_distance(vae.decode(z, t), points).sum())
    return total / len(clouds)


def _build_vae(config: VAEConfig, seed: int) -> PointCloudVAE:
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return PointCloudVAE(config)


def train_vae(train_clouds: torch.Tensor, heldout_clouds: torch.Tensor, config: VAEConfig, settings: VAESettings,
              checkpoint_path: str | Path, *, on_epoch: EpochCallback | None = None,
              device: torch.device | None = None) -> VAEResult:
    """Train a VAE on ``train_clouds (N, M, 3)``; resume from ``checkpoint_path`` when it holds progress.

    Args:
        train_clouds: training entities, world frame (they also fix the VAE's ``scale``).
        heldout_clouds: held-out entities for the per-epoch reconstruction Chamfer.
        config: the VAE's hyper-parameters.
        settings: epochs, learning rate, batch size, seed.
        checkpoint_path: progress file, rewritten after every epoch.
        on_epoch: ``on_epoch("vae", epoch, metrics)`` after each epoch's checkpoint.
        device: where to train (default CPU).

    Returns:
        ``VAEResult`` with the best weights (CPU).
    """
    if len(train_clouds) == 0 or len(heldout_clouds) == 0:
        raise ValueError(f"need training and held-out entities, got {len(train_clouds)} and {len(heldout_clouds)}")
    device = device or torch.device("cpu")
    vae = _build_vae(config, settings.seed)
    vae.fit_scale(train_clouds)
    vae.to(device)
    best = copy.deepcopy(vae)
    optimiser = torch.optim.Adam(vae.parameters(), lr=settings.lr)
    history: list[dict[str, float]] = []
    best_value, best_epoch, start = math.inf, -1, 0
    path = Path(checkpoint_path)
    if path.is_file():
        checkpoint = load_checkpoint(path, device)
        restore_models({"vae": vae, "best": best}, checkpoint)
        optimiser.load_state_dict(checkpoint.optimiser_states["vae"])
        extra = checkpoint.config["extra"]
        history, best_value, best_epoch = list(extra["history"]), float(extra["best_value"]), int(extra["best_epoch"])
        start = checkpoint.epoch
    n = len(train_clouds)
    for epoch in range(start, settings.epochs):
        started = time.perf_counter()
        rng, generator = epoch_generators(settings.seed, epoch, device)
        for group in optimiser.param_groups:
            group["lr"] = settings.lr * lr_factor(epoch, settings.epochs)
        order = torch.from_numpy(rng.permutation(n))
        sums = {"loss": 0.0, "reconstruction": 0.0, "kl": 0.0}
        vae.train()
        for begin in range(0, n, settings.batch_size):
            points = train_clouds[order[begin : begin + settings.batch_size]].to(device)
            with training_autocast(settings.precision, device):
                loss, parts = vae.elbo_loss(points, generator)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            for key in sums:
                sums[key] += parts[key] * len(points)
        vae.eval()
        value = heldout_chamfer(vae, heldout_clouds)
        if value < best_value:
            best.load_state_dict(vae.state_dict())
            best_value, best_epoch = value, epoch
        metrics = {f"vae_train_{k}": v / n for k, v in sums.items()}
        metrics.update(vae_heldout_chamfer_epoch=value, vae_lr=optimiser.param_groups[0]["lr"],
                       vae_epoch_s=time.perf_counter() - started)
        history.append(metrics)
        extra = {"stage": "vae", "history": history, "best_value": best_value, "best_epoch": best_epoch}
        save_checkpoint(path, {"vae": vae, "best": best}, {"vae": optimiser.state_dict()}, epoch + 1,
                        {"extra": extra})
        if on_epoch is not None:
            on_epoch("vae", epoch, metrics)
    best.eval()
    return VAEResult(best.cpu(), best_epoch, best_value, history)


def save_vae(path: str | Path, result: VAEResult, *, whole_scene: bool) -> Path:
    """Write the trained VAE (best weights), its config and held-out Chamfer atomically."""
    config = {"vae_config": asdict(result.vae.config), "whole_scene": whole_scene, "best_epoch": result.best_epoch,
              "heldout_chamfer": result.heldout_chamfer, "history": result.history}
    return save_checkpoint(path, {"vae": result.vae}, None, result.best_epoch + 1, config)


def load_vae(path: str | Path) -> VAEResult:
    """Read a VAE written by ``save_vae`` (CPU, eval mode)."""
    checkpoint = load_checkpoint(path)
    raw = checkpoint.config["vae_config"]
    config = VAEConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()})
    vae = PointCloudVAE(config)
    restore_models({"vae": vae}, checkpoint)
    vae.eval()
    return VAEResult(vae, int(checkpoint.config["best_epoch"]), float(checkpoint.config["heldout_chamfer"]),
                     list(checkpoint.config["history"]))
