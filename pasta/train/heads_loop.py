"""Training loop of the feasibility and cost heads (appendix eq. 6), then of the policies (``policy_loop``).

Every step takes one batch of transitions per skill and minimises
``sum_k lambda_f * L_f,k + lambda_c * L_c,k`` with one Adam whose parameter groups carry Table 3's learning
rates (model_spec §6):

* ``L_f``: ``weighted_mse`` of the skill's feasibility predictor on its positives (filtered, hindsight
  goals), ``hard_copies`` hard negatives per positive and ``n_random`` random negatives (model_spec §2.5);
  Gaussian latent noise ``sigma_z``, ``sigma_t`` on the positives for variants with ``latent_noise``;
* ``L_c``: MSE of the shared cost predictor to the true Chamfer distance of entity pairs (model_spec §3.3).

The policy term ``lambda_pi * L_pi`` of eq. 6 touches only the policies, so they train apart, after the
heads, with a step budget, schedule and early stopping of their own (``train_policies``).

The VAE is frozen: every entity is encoded once (posterior mean) before the first epoch and the heads
train on these cached latents. An epoch is ``ceil(max_k n_k / feasibility_batch_size)`` steps, each skill
cycling through its own shuffled transitions. After every epoch the held-out metrics are measured, the
progress is checkpointed (``save_trained`` with the optimiser state and the history) and ``on_epoch`` is
called; a rerun resumes after the last checkpointed epoch, then the policies resume from their own
progress file (``policy_progress_path``). The heads' final weights are those of the last epoch.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.models.checkpoint import load_checkpoint, restore_models
from pasta.models.feasibility_samples import feasibility_batch, weighted_mse
from pasta.models.latent_prior import LatentPrior
from pasta.models.model_config import ModelConfig
from pasta.models.vae import PointCloudVAE
from pasta.models.variants import variant_spec
from pasta.train.action_range import ActionRange
from pasta.train.bundle import TrainedModels, save_trained, untrained
from pasta.train.dagger import DaggerSettings, dagger_rounds
from pasta.train.datasets import PolicySamples, TransitionSampler, pad_sets
from pasta.train.metrics import r_squared, roc_auc
from pasta.train.policy_loop import (
    PolicyResult,
    PolicySettings,
    evaluate_policies,
    policy_progress_path,
    train_policies,
)
from pasta.train.progress import EpochCallback, epoch_generators

__all__ = ["HeadsResult", "HeadsSettings", "HeldOut", "encode_entities", "evaluate_abstraction", "skill_loss",
           "train_heads"]


@dataclass(frozen=True)
class HeadsSettings:
    """Hyper-parameters of head training (Table 3 and model_spec §2-4, §6); ``policy`` those of the policies."""

    epochs: int
    feasibility_lr: float
    cost_lr: float
    feasibility_batch_size: int
    cost_batch_size: int
    sigma_z: float
    sigma_t: float
    policy: PolicySettings
    lambda_feasibility: float = 10.0
    lambda_cost: float = 1.0
    hard_copies: int = 10
    n_random: int = 2048
    seed: int = 0

    def __post_init__(self) -> None:
        if min(self.epochs, self.feasibility_batch_size, self.cost_batch_size) < 1:
            raise ValueError(f"need epochs and batch sizes >= 1, got {self}")

    @classmethod
    def from_config(cls, cfg: TaskConfig, variant: str, seed: int = 0) -> HeadsSettings:
        """Table 3 values of ``cfg``; no latent noise for variants without ``latent_noise``."""
        train, noisy = cfg.train, variant_spec(variant).latent_noise
        return cls(
            epochs=train.epochs, feasibility_lr=train.feasibility_lr, cost_lr=train.cost_lr,
            feasibility_batch_size=train.feasibility_batch_size, cost_batch_size=train.cost_batch_size,
            sigma_z=train.feasibility_sigma_z if noisy else 0.0, sigma_t=train.feasibility_sigma_t if noisy else 0.0,
            policy=PolicySettings.from_config(cfg, variant, seed), lambda_feasibility=train.lambda_feasibility,
            lambda_cost=train.lambda_cost, seed=seed,
        )


def encode_entities(vae: PointCloudVAE, clouds: torch.Tensor, device: torch.device,
                    batch_size: int = 256) -> torch.Tensor:
    """Entity latents ``(N, D_z + 3)`` (posterior means) of ``clouds (N, M, 3)``, on ``device``."""
    vae = vae.to(device).eval()
    with torch.no_grad():
        parts = [vae.encode_entities(clouds[i : i + batch_size].to(device)) for i in range(0, len(clouds), batch_size)]
    return torch.cat(parts)


@dataclass(frozen=True, eq=False)
class HeldOut:
    """Fixed held-out samples per skill (drawn once with a fixed seed): positives, policy samples, cost pairs.

    Up to ``max_policy`` policy samples per skill: at ``small`` that is every valid sample of the held-out
    trajectories (LiftSpread's spread has 50). The earlier 32 measured LiftSpread's spread at 0.18x the zero
    action's MSE where all 50 gave 0.33x.
    """

    positives: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None]
    policy: list[PolicySamples | None]
    cost_a: torch.Tensor
    cost_b: torch.Tensor
    cost_target: torch.Tensor

    @classmethod
    def build(cls, sampler: TransitionSampler, latents: torch.Tensor, *, max_rows: int = 512,
              max_policy: int = 256, seed: int = 12345) -> HeldOut:
        rng = np.random.default_rng(seed)
        positives, policy, cost_a, cost_b, cost_t = [], [], [], [], []
        for k in range(len(sampler.skills)):
            rows = sampler.transitions[k]
            if len(rows) == 0:
                positives.append(None)
                policy.append(None)
                continue
            rows = rows[rng.permutation(len(rows))[:max_rows]]
            found = sampler.feasibility_positives(k, rows, rng)
            positives.append((*pad_sets(found.obs, latents), *pad_sets(found.goal, latents)) if found.obs else None)
            policy.append(sampler.policy_samples(k, rows, rng, max_policy))
            pairs = sampler.cost_pairs(rows[: max_rows // 2], rng)
            cost_a.append(pairs.a)
            cost_b.append(pairs.b)
            cost_t.append(pairs.chamfer)
        if not cost_a:
            raise ValueError("the held-out trajectories hold no transitions")
        return cls(positives, policy, latents[torch.from_numpy(np.concatenate(cost_a)).to(latents.device)],
                   latents[torch.from_numpy(np.concatenate(cost_b)).to(latents.device)], torch.cat(cost_t))


def evaluate_abstraction(bundle: TrainedModels, held_out: HeldOut, *, hard_copies: int = 10,
                         seed: int = 777) -> dict[str, float]:
    """Held-out metrics of the feasibility and cost heads: feasibility ROC-AUC vs random and vs hard negatives
    (all skills pooled; negatives drawn from a fixed seed) and cost R^2."""
    device = held_out.cost_a.device
    generator = torch.Generator(device=device)
    generator.manual_seed(seed)
    pos, hard, rand = [], [], []
    with torch.no_grad():
        for k, found in enumerate(held_out.positives):
            if found is None:
                continue
            obs, obs_mask, goal, goal_mask = found
            n = len(obs)
            batch = feasibility_batch(obs, goal, obs_mask, goal_mask, bundle.prior, sigma_z=0.0, sigma_t=0.0,
                                      hard_copies=hard_copies, n_random=hard_copies * n, generator=generator)
            scores = bundle.models["feasibility"][k](batch.obs, batch.goal, batch.obs_mask, batch.goal_mask).cpu()
            pos.append(scores[:n])
            hard.append(scores[n : n + hard_copies * n])
            rand.append(scores[n + hard_copies * n :])
        cost = bundle.cost(held_out.cost_a, held_out.cost_b).cpu().numpy()
    metrics = {"cost_r2": r_squared(cost, held_out.cost_target.numpy())}
    if pos:
        positives = torch.cat(pos).numpy()
        metrics["feasibility_auc_random"] = roc_auc(positives, torch.cat(rand).numpy())
        metrics["feasibility_auc_hard"] = roc_auc(positives, torch.cat(hard).numpy())
    return metrics


@dataclass(frozen=True, eq=False)
class HeadsResult:
    """The trained bundle (heads of the last epoch, policies' best weights), its held-out metrics, the heads'
    per-epoch history, the policies' result (steps, curve) and each DAgger round's (none without rounds)."""

    bundle: TrainedModels
    metrics: dict[str, float]
    history: list[dict[str, float]]
    policy: PolicyResult
    dagger: tuple[PolicyResult, ...] = ()


def _optimiser(bundle: TrainedModels, settings: HeadsSettings) -> torch.optim.Adam:
    return torch.optim.Adam([
        {"params": list(bundle.models["feasibility"].parameters()), "lr": settings.feasibility_lr},
        {"params": list(bundle.models["cost"].parameters()), "lr": settings.cost_lr},
    ])


def skill_loss(bundle: TrainedModels, settings: HeadsSettings, sampler: TransitionSampler, latents: torch.Tensor,
               k: int, rows: np.ndarray, rng: np.random.Generator,
               generator: torch.Generator) -> tuple[torch.Tensor, dict[str, float]]:
    """``lambda_f * L_f + lambda_c * L_c`` of skill ``k`` on the transitions ``rows (n, 2)``, and its parts."""
    parts: dict[str, float] = {}
    total = torch.zeros((), device=latents.device)
    found = sampler.feasibility_positives(k, rows[: settings.feasibility_batch_size], rng)
    if found.obs:
        obs, obs_mask = pad_sets(found.obs, latents)
        goal, goal_mask = pad_sets(found.goal, latents)
        batch = feasibility_batch(obs, goal, obs_mask, goal_mask, bundle.prior, sigma_z=settings.sigma_z,
                                  sigma_t=settings.sigma_t, hard_copies=settings.hard_copies,
                                  n_random=settings.n_random, generator=generator)
        scores = bundle.models["feasibility"][k](batch.obs, batch.goal, batch.obs_mask, batch.goal_mask)
        loss = weighted_mse(scores, batch.labels, batch.weights)
        total = total + settings.lambda_feasibility * loss
        parts["feasibility_loss"] = loss.item()
    pairs = sampler.cost_pairs(rows[: settings.cost_batch_size], rng)
    index_a = torch.from_numpy(pairs.a).to(latents.device)
    index_b = torch.from_numpy(pairs.b).to(latents.device)
    cost = bundle.cost(latents[index_a], latents[index_b])
    loss = (cost - pairs.chamfer.to(latents.device)).square().mean()
    total = total + settings.lambda_cost * loss
    parts["cost_loss"] = loss.item()
    return total, parts


def _fit_abstraction(bundle: TrainedModels, sampler: TransitionSampler, held_out: HeldOut, latents: torch.Tensor,
                     settings: HeadsSettings, path: Path,
                     on_epoch: EpochCallback | None) -> list[dict[str, float]]:
    """The feasibility and cost epochs, resumed from ``path`` when it holds progress; the per-epoch history."""
    device = latents.device
    optimiser = _optimiser(bundle, settings)
    history: list[dict[str, float]] = []
    start = 0
    if path.is_file():
        checkpoint = load_checkpoint(path, device)
        restore_models(bundle.models, checkpoint)
        optimiser.load_state_dict(checkpoint.optimiser_states["heads"])
        history = list(checkpoint.config["extra"]["history"])
        start = checkpoint.epoch
    counts = [sampler.count(k) for k in range(len(bundle.skill_names))]
    steps = math.ceil(max(counts) / settings.feasibility_batch_size)
    rows_per_step = max(settings.feasibility_batch_size, settings.cost_batch_size)
    for epoch in range(start, settings.epochs):
        started = time.perf_counter()
        rng, generator = epoch_generators(settings.seed, epoch, device)
        orders = [rng.permutation(n) for n in counts]
        bundle.models["feasibility"].train()
        bundle.models["cost"].train()
        sums: dict[str, list[float]] = {}
        for step in range(steps):
            total = torch.zeros((), device=device)
            for k, n in enumerate(counts):
                if n == 0:
                    continue
                chosen = orders[k][(step * rows_per_step + np.arange(rows_per_step)) % n]
                loss, parts = skill_loss(bundle, settings, sampler, latents, k, sampler.transitions[k][chosen],
                                         rng, generator)
                total = total + loss
                for key, value in parts.items():
                    sums.setdefault(key, []).append(value)
            optimiser.zero_grad(set_to_none=True)
            total.backward()
            optimiser.step()
        bundle.eval()
        metrics = {f"train_{key}": float(np.mean(values)) for key, values in sums.items()}
        metrics.update(evaluate_abstraction(bundle, held_out, hard_copies=settings.hard_copies))
        metrics["heads_epoch_s"] = time.perf_counter() - started
        history.append(metrics)
        save_trained(path, bundle, epoch=epoch + 1, optimiser_states={"heads": optimiser.state_dict()},
                     extra={"stage": "heads", "history": history, "epochs": settings.epochs})
        if on_epoch is not None:
            on_epoch("heads", epoch, metrics)
    return history


def train_heads(cfg: TaskConfig, variant: str, vae: PointCloudVAE, latents: torch.Tensor,
                train_sampler: TransitionSampler, held_out: HeldOut, prior: LatentPrior, settings: HeadsSettings,
                checkpoint_path: str | Path, *, model_config: ModelConfig | None = None,
                on_epoch: EpochCallback | None = None, device: torch.device | None = None,
                action_range: tuple[ActionRange, ...] | None = None) -> HeadsResult:
    """Train the heads of ``variant`` on cached entity ``latents (N, E)``, then its policies; resume from
    ``checkpoint_path`` (heads) and ``policy_progress_path(checkpoint_path)`` (policies).

    Args:
        cfg: the task (skills, action space).
        variant: one of ``pasta.models.VARIANTS``.
        vae: the trained, frozen VAE (copied into the bundle).
        latents: every entity's latent, from ``encode_entities`` (moved to ``device``).
        train_sampler: transitions of the training trajectories.
        held_out: fixed held-out samples for the metrics and the policies' early stopping.
        prior: ``P_u`` for the negatives (box of the training entity centres).
        settings: Table 3 and friends, the policies' budget and schedule.
        checkpoint_path: the heads' progress file (``save_trained``), rewritten after every epoch.
        model_config: network sizes (default ``ModelConfig()``).
        on_epoch: ``on_epoch("heads", epoch, metrics)`` after each epoch's checkpoint, then
            ``on_epoch("policy", steps, metrics)`` after each policy evaluation (``train_policies``) and, with
            ``cfg.train.dagger_rounds``, ``on_epoch("dagger", steps, metrics)`` after each evaluation of the
            DAgger rounds (``pasta.train.dagger.dagger_rounds``; they simulate, in this thread).
        device: where to train (default: where ``latents`` are).
        action_range: the skills' demonstrated action ranges (:mod:`pasta.train.action_range`), kept in the
            bundle from the start, so DAgger's visits clip to them as the executor does.

    Returns:
        The bundle on the CPU; its metrics: the last epoch's, the policies' pooled held-out MSE with the kept
        weights (``evaluate_policies``, after the DAgger rounds if any) and each skill's steps of behaviour
        cloning (``PolicyResult.metrics``).
    """
    device = device or latents.device
    latents = latents.to(device)
    if max(train_sampler.count(k) for k in range(len(cfg.skills))) == 0:
        raise ValueError(f"no training transitions for any skill of {cfg.task}")
    bundle = dataclasses.replace(untrained(cfg, variant, prior, model_config=model_config, seed=settings.seed),
                                 action_range=action_range)
    bundle.models["vae"].load_state_dict(vae.state_dict())
    bundle.to(device).eval()
    path = Path(checkpoint_path)
    history = _fit_abstraction(bundle, train_sampler, held_out, latents, settings, path, on_epoch)
    policy = train_policies(bundle, train_sampler, held_out.policy, latents, settings.policy,
                            policy_progress_path(path), on_epoch=on_epoch)
    dagger, rounds = DaggerSettings.from_config(cfg), []
    if dagger.rounds:
        rounds = dagger_rounds(cfg, bundle, train_sampler, held_out.policy, latents, settings.policy, dagger,
                               path.with_suffix(""), first_step=settings.policy.steps, on_epoch=on_epoch)
    bundle.eval()
    metrics = {**history[-1], **evaluate_policies(bundle, held_out.policy, latents), **policy.metrics()}
    if dagger.rounds:
        metrics["dagger_rounds"] = float(dagger.rounds)
    return HeadsResult(bundle.to("cpu"), metrics, history, policy, tuple(rounds))
