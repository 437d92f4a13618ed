"""The policies' own training loop: a budget of gradient steps per skill, a learning-rate schedule and early
stopping on the held-out action MSE, the best weights kept.

The policy term of eq. 6 touches only the policies' parameters, so minimising ``lambda_pi * L_pi`` on its
own follows the same gradient for them as the joint loss; the feasibility and cost heads keep their joint
epochs (``heads_loop``), and the policies get a budget of ``steps`` of their own, as the released scripts
train the policy in a run of its own (model_spec §6).

Steps run in rounds of ``eval_every``. A step takes, for every skill still training, the first
``batch_size`` valid policy samples among the next transitions of that skill's order (a fresh permutation
per round), sums ``lambda_pi * L_pi`` over those skills and takes one Adam step over every policy at the
learning rate ``lr_at(step)``. Before the first round and after each one, every skill still training is
measured on its fixed held-out samples: a new lowest MSE keeps a copy of its weights; ``patience``
evaluations in a row without one stop the skill. After every round the progress (current and best
weights, the optimiser, per-skill counters and the curve) is checkpointed; a round draws only from
generators seeded by ``(seed, round)``, so a rerun resumes at the next round and ends with the weights of
an uninterrupted run. At the end every policy with held-out samples gets its best weights back.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import nn

from pasta.config.schema import TaskConfig
from pasta.models.checkpoint import load_checkpoint, restore_models, save_checkpoint
from pasta.models.feasibility_samples import add_latent_noise
from pasta.models.policy import uniform_point_noise
from pasta.models.policy_ensemble import policy_members
from pasta.models.variants import VariantSpec, variant_spec
from pasta.train.bundle import TrainedModels
from pasta.train.datasets import PolicySamples, TransitionSampler, pad_sets
from pasta.train.metrics import action_mse
from pasta.train.mirror import mirror_action_signs, mirror_batch, reflection_codes
from pasta.train.precision import check_precision, training_autocast
from pasta.train.progress import EpochCallback, epoch_generators
from pasta.train.visits import VisitPool, concat_samples, take_samples

__all__ = ["PolicyResult", "PolicySettings", "evaluate_policies", "heldout_mse", "lr_at", "policy_forward",
           "policy_loss", "policy_progress_path", "train_policies", "weighted_rows"]

ROWS_PER_SAMPLE = 4  # transitions offered per wanted sample: filtering rejects some (empty or wrong counts)
PREDICTION_BATCH = 64  # held-out samples per forward pass (PointNet++'s grouped tensors grow with the batch)


@dataclass(frozen=True)
class PolicySettings:
    """Budget, schedule and inputs of policy training (``train.policy_*`` and Table 3)."""

    steps: int
    lr: float
    batch_size: int
    point_noise: float
    lr_schedule: Literal["cosine", "constant"] = "cosine"
    eval_every: int = 25
    patience: int | None = None
    lambda_policy: float = 1.0
    sigma_z: float = 0.0
    sigma_t: float = 0.0
    precision: str = "fp32"
    seed: int = 0
    mirror_signs: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    mirror_planes: Literal["x", "xz"] = "xz"
    first_step_weight: int = 1

    def __post_init__(self) -> None:
        if min(self.steps, self.batch_size, self.eval_every, self.first_step_weight) < 1 or self.lr <= 0 or (
                self.lr_schedule not in ("cosine", "constant")) or (self.patience is not None and self.patience < 1):
            raise ValueError(f"need steps, batch_size, eval_every, first_step_weight >= 1, lr > 0, lr_schedule "
                             f"cosine or constant and patience None or >= 1, got {self}")
        check_precision(self.precision)

    @classmethod
    def from_config(cls, cfg: TaskConfig, variant: str, seed: int = 0) -> PolicySettings:
        """``cfg.train``'s policy values; latent noise (latent-set policy) only for variants with ``latent_noise``."""
        spec = variant_spec(variant)
        train, noisy = cfg.train, spec.latent_noise
        mirrored = train.policy_mirror != "none" and not (spec.policy_on_latents or spec.tool_state_after_encoder)
        return cls(steps=train.policy_steps, lr=train.policy_lr, batch_size=train.policy_batch_size,
                   point_noise=train.policy_point_noise, lr_schedule=train.policy_lr_schedule,
                   eval_every=train.policy_eval_every, patience=train.policy_patience,
                   lambda_policy=train.lambda_policy, sigma_z=train.feasibility_sigma_z if noisy else 0.0,
                   sigma_t=train.feasibility_sigma_t if noisy else 0.0, precision=train.precision, seed=seed,
                   mirror_signs=mirror_action_signs(cfg) if mirrored else None,
                   mirror_planes="x" if train.policy_mirror == "x" else "xz",
                   first_step_weight=train.policy_first_step_weight)


def lr_at(step: int, settings: PolicySettings) -> float:
    """Learning rate of gradient step ``step`` (from 0): ``lr`` throughout (``constant``), or half a cosine
    from ``lr`` towards 0 over the budget (``cosine``: ``lr * (1 + cos(pi * step / steps)) / 2``)."""
    if settings.lr_schedule == "constant":
        return settings.lr
    return settings.lr * 0.5 * (1.0 + math.cos(math.pi * step / settings.steps))


def policy_progress_path(heads_path: str | Path) -> Path:
    """The policies' progress file beside the heads' one: ``training-<key>.pt`` -> ``training-<key>-policy.pt``."""
    path = Path(heads_path)
    return path.with_name(f"{path.stem}-policy{path.suffix}")


def policy_forward(policy: nn.Module, spec: VariantSpec, samples: PolicySamples, latents: torch.Tensor,
                   latent_dim: int, noise: PolicySettings | None = None,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """Actions ``(B, A)`` of one skill's policy on ``B`` samples; ``noise`` given = training-time input noise.

    Point-cloud policies read the clouds ``(B, P, 3)``, ``(B, Q, 3)``, ``(B, P, 3)`` (or the tool state
    ``(B, 8)``); the latent-set policy reads the entities' rows of ``latents (N, E)``.
    """
    device = latents.device
    if spec.policy_on_latents:
        obs, obs_mask = pad_sets(samples.obs_ids, latents)
        goal, goal_mask = pad_sets(samples.goal_ids, latents)
        if noise is not None:
            obs = add_latent_noise(obs, latent_dim, noise.sigma_z, noise.sigma_t, generator)
            goal = add_latent_noise(goal, latent_dim, noise.sigma_z, noise.sigma_t, generator)
        return policy(obs, goal, obs_mask, goal_mask)
    clouds = [samples.obs_points.to(device), samples.tool_points.to(device), samples.goal_points.to(device)]
    if noise is not None:
        clouds = [uniform_point_noise(c, noise.point_noise, generator) for c in clouds]
    obs, tool, goal = clouds
    if spec.tool_state_after_encoder:
        return policy(obs, goal, samples.tool_states.to(device))
    return policy(obs, tool, goal, samples.phases.to(device), samples.previous_actions.to(device))


def policy_loss(policy: nn.Module, spec: VariantSpec, settings: PolicySettings, samples: PolicySamples,
                latents: torch.Tensor, latent_dim: int, generator: torch.Generator) -> torch.Tensor:
    """``L_pi``: the squared action error summed over the ``A`` dimensions, averaged over the ``B`` samples
    (noisy inputs, model_spec §4.4) and over the ``H`` steps of the chunk a policy predicts (``H`` = 1 but for
    a set policy with ``chunk`` > 1); the forward pass in ``settings.precision``, the error in float32. For an
    ensemble (``PolicyEnsemble``) the mean of its members' own losses, each member with its own input noise, so
    that each member fits the demonstrations by itself."""
    if settings.mirror_signs is not None:
        samples = _mirrored(samples, settings.mirror_signs, settings.mirror_planes, generator)
    with training_autocast(settings.precision, latents.device):
        predicted = [policy_forward(member, spec, samples, latents, latent_dim, settings, generator)
                     for member in policy_members(policy)]
    width = predicted[0].shape[1]
    target = samples.action_chunks[:, :width].to(latents.device)
    steps = width // samples.actions.shape[1]
    return torch.stack([(p.float() - target).square().sum(dim=1).mean() for p in predicted]).mean() / steps


def _mirrored(samples: PolicySamples, signs: tuple[tuple[float, ...], tuple[float, ...]], planes: str,
              generator: torch.Generator) -> PolicySamples:
    """``samples`` each reflected at random (``pasta.train.mirror``): as they are or in x (``planes`` "x"); as
    they are, in x, in z or in both ("xz")."""
    choice = reflection_codes(len(samples), planes, generator, samples.obs_points.device)
    width = samples.actions.shape[1]
    # The previous action is reflected with the chunk, as one more step in front of it.
    actions = torch.cat([samples.previous_actions, samples.action_chunks], dim=1).to(samples.obs_points.device)
    obs, tool, goal, actions = mirror_batch(samples.obs_points, samples.tool_points, samples.goal_points, actions,
                                            signs, choice)
    return dataclasses.replace(samples, obs_points=obs, tool_points=tool, goal_points=goal,
                               previous_actions=actions[:, :width], action_chunks=actions[:, width:],
                               actions=actions[:, width : 2 * width])


def _predictions(policy: nn.Module, spec: VariantSpec, samples: PolicySamples, latents: torch.Tensor,
                 latent_dim: int) -> np.ndarray:
    """Noise-free actions ``(B, A)`` of ``policy`` at the samples' own step (the first of a chunk; eval mode, no
    gradient), ``PREDICTION_BATCH`` samples at a time."""
    policy.eval()
    width = samples.actions.shape[1]
    parts = []
    with torch.no_grad():
        for start in range(0, len(samples), PREDICTION_BATCH):
            part = take_samples(samples, np.arange(start, min(start + PREDICTION_BATCH, len(samples))))
            parts.append(policy_forward(policy, spec, part, latents, latent_dim)[:, :width].cpu().numpy())
    return np.concatenate(parts)


def heldout_mse(policy: nn.Module, spec: VariantSpec, samples: PolicySamples, latents: torch.Tensor,
                latent_dim: int) -> float:
    """Action MSE (summed over dimensions, averaged over samples) of ``policy`` on held-out ``samples``."""
    return action_mse(_predictions(policy, spec, samples, latents, latent_dim), samples.actions.numpy())


def evaluate_policies(bundle: TrainedModels, held_out: list[PolicySamples | None],
                      latents: torch.Tensor) -> dict[str, float]:
    """``policy_mse`` and its zero-action baseline ``policy_zero_mse``, all skills' held-out samples pooled, and
    per skill ``policy_mse_<skill>``, ``policy_zero_mse_<skill>`` and their ratio ``policy_mse_ratio_<skill>``
    (issue 13's bar reads the ratio per skill); nothing for a skill without held-out samples."""
    spec = variant_spec(bundle.variant)
    predicted, true, metrics = [], [], {}
    for k, samples in enumerate(held_out):
        if samples is None:
            continue
        predicted.append(_predictions(bundle.models["policy"][k], spec, samples, latents, bundle.prior.latent_dim))
        true.append(samples.actions.numpy())
        name = bundle.skill_names[k]
        mse, zero = action_mse(predicted[-1], true[-1]), action_mse(np.zeros_like(true[-1]), true[-1])
        metrics.update({f"policy_mse_{name}": mse, f"policy_zero_mse_{name}": zero,
                        f"policy_mse_ratio_{name}": mse / zero if zero > 0 else math.nan})
    if not predicted:
        return {}
    actions = np.concatenate(true)
    return {"policy_mse": action_mse(np.concatenate(predicted), actions),
            "policy_zero_mse": action_mse(np.zeros_like(actions), actions), **metrics}


@dataclass
class SkillProgress:
    """Where one skill's policy stands: steps taken, best held-out MSE and its step, evaluations since it,
    and whether it has finished (early-stopped, or no training transitions)."""

    steps: int = 0
    best_mse: float = math.inf
    best_step: int = 0
    stale: int = 0
    done: bool = False


@dataclass(frozen=True)
class PolicyResult:
    """Per skill (by name) the steps taken and the step of the kept weights; the curve of the evaluations,
    ``(steps taken, metrics)`` from step 0 on."""

    steps: dict[str, int]
    best_steps: dict[str, int]
    curve: list[tuple[int, dict[str, float]]]

    def metrics(self) -> dict[str, float]:
        """``policy_steps_<skill>`` and ``policy_best_step_<skill>`` of every skill."""
        return {**{f"policy_steps_{name}": float(n) for name, n in self.steps.items()},
                **{f"policy_best_step_{name}": float(n) for name, n in self.best_steps.items()}}


def weighted_rows(transitions: np.ndarray, first_step_weight: int) -> np.ndarray:
    """Positions into ``transitions`` ``(n, 2)`` (rows of trajectory, step), each row once and the rows of
    step 0 ``first_step_weight`` times: a permutation of these draws first steps that much more often."""
    positions = np.arange(len(transitions))
    first = np.flatnonzero(transitions[:, 1] == 0)
    return np.concatenate([positions, np.repeat(first, first_step_weight - 1)])


def _batch_rows(sampler: TransitionSampler, k: int, order: np.ndarray, step_in_round: int,
                batch_size: int) -> np.ndarray:
    """Transitions ``(ROWS_PER_SAMPLE * batch_size, 2)`` offered to step ``step_in_round`` of skill ``k``:
    the order read from ``step_in_round * batch_size`` on, wrapping around."""
    positions = (step_in_round * batch_size + np.arange(ROWS_PER_SAMPLE * batch_size)) % len(order)
    return sampler.transitions[k][order[positions]]


def _train_round(bundle: TrainedModels, settings: PolicySettings, sampler: TransitionSampler,
                 latents: torch.Tensor, skills: list[SkillProgress], optimiser: torch.optim.Optimizer,
                 first_step: int, n_steps: int, visits: VisitPool | None) -> dict[int, float]:
    """Steps ``first_step .. first_step + n_steps - 1`` for every unfinished skill; their mean losses. With
    ``visits``, each skill's batch also gets ``batch_size`` of its visited states."""
    spec, policies, latent_dim = variant_spec(bundle.variant), bundle.models["policy"], bundle.prior.latent_dim
    rng, generator = epoch_generators(settings.seed, first_step // settings.eval_every, latents.device)
    active = [k for k, skill in enumerate(skills) if not skill.done]
    orders = {k: rng.permutation(weighted_rows(sampler.transitions[k], settings.first_step_weight)) for k in active}
    losses: dict[int, list[float]] = {k: [] for k in active}
    policies.train()
    for j in range(n_steps):
        for group in optimiser.param_groups:
            group["lr"] = lr_at(first_step + j, settings)
        terms = []
        for k in active:
            samples = sampler.policy_samples(k, _batch_rows(sampler, k, orders[k], j, settings.batch_size), rng,
                                             settings.batch_size)
            visited = None if visits is None else visits.draw(k, settings.batch_size, rng)
            if visited is not None:
                samples = visited if samples is None else concat_samples([samples, visited])
            if samples is None:
                continue
            loss = policy_loss(policies[k], spec, settings, samples, latents, latent_dim, generator)
            terms.append(settings.lambda_policy * loss)
            losses[k].append(loss.item())
            skills[k].steps += 1
        if terms:
            optimiser.zero_grad(set_to_none=True)
            torch.stack(terms).sum().backward()
            optimiser.step()
    return {k: float(np.mean(values)) for k, values in losses.items() if values}


def _evaluate_round(bundle: TrainedModels, best: nn.ModuleList, held_out: list[PolicySamples | None],
                    latents: torch.Tensor, skills: list[SkillProgress], step: int,
                    patience: int | None) -> dict[int, float]:
    """Held-out MSE of every unfinished skill with held-out samples at ``step``; keeps new bests in ``best``
    and finishes a skill after ``patience`` evaluations in a row without one."""
    spec, policies = variant_spec(bundle.variant), bundle.models["policy"]
    values = {}
    for k, skill in enumerate(skills):
        if skill.done or held_out[k] is None:
            continue
        values[k] = heldout_mse(policies[k], spec, held_out[k], latents, bundle.prior.latent_dim)
        if values[k] < skill.best_mse:
            skill.best_mse, skill.best_step, skill.stale = values[k], step, 0
            best[k].load_state_dict(policies[k].state_dict())
        else:
            skill.stale += 1
            skill.done = patience is not None and skill.stale >= patience
    return values


def _round_metrics(names: tuple[str, ...], losses: dict[int, float], mse: dict[int, float],
                   lr: float | None) -> dict[str, float]:
    """Per skill ``policy_train_loss_<skill>`` and ``policy_heldout_mse_<skill>``, their means over skills
    (``policy_train_loss``, ``policy_heldout_mse``) and the last step's ``policy_lr``."""
    metrics = {f"policy_train_loss_{names[k]}": v for k, v in losses.items()}
    metrics.update({f"policy_heldout_mse_{names[k]}": v for k, v in mse.items()})
    if losses:
        metrics["policy_train_loss"] = float(np.mean(list(losses.values())))
    if mse:
        metrics["policy_heldout_mse"] = float(np.mean(list(mse.values())))
    if lr is not None:
        metrics["policy_lr"] = lr
    return metrics


def _save_progress(path: Path, policies: nn.ModuleList, best: nn.ModuleList, optimiser: torch.optim.Optimizer,
                   skills: list[SkillProgress], curve: list[tuple[int, dict[str, float]]]) -> None:
    """Checkpoint the current and best policies, the optimiser, the skills' counters and the curve; the
    checkpoint's epoch is the step of the curve's last point."""
    extra = {"skills": [asdict(skill) for skill in skills], "curve": curve}
    save_checkpoint(path, {"policy": policies, "best": best}, {"policy": optimiser.state_dict()}, curve[-1][0],
                    {"extra": extra})


def train_policies(bundle: TrainedModels, sampler: TransitionSampler, held_out: list[PolicySamples | None],
                   latents: torch.Tensor, settings: PolicySettings, checkpoint_path: str | Path, *,
                   visits: VisitPool | None = None, on_epoch: EpochCallback | None = None) -> PolicyResult:
    """Train ``bundle``'s policies in place on ``latents``' device; resume from ``checkpoint_path``.

    Args:
        bundle: the models; only ``models["policy"]`` (one network per skill) changes.
        sampler: the training transitions.
        held_out: per skill, the fixed held-out samples (``HeldOut.policy``), or ``None``.
        latents: every entity's latent ``(N, E)`` (the latent-set policy's input).
        settings: budget, schedule, early stopping and input noise.
        checkpoint_path: progress file, rewritten after every round.
        visits: states the policies visited with their expert labels (DAgger, :mod:`pasta.train.dagger`), drawn
            into every batch beside the demonstrations' samples; ``held_out`` should then hold some too.
        on_epoch: ``on_epoch("policy", steps, metrics)`` after each evaluation (``steps`` taken so far, 0 for
            the untrained policies), once it is checkpointed.

    Returns:
        The steps each skill took, the step of the weights it keeps, and the evaluation curve.
    """
    policies = bundle.models["policy"]
    best = copy.deepcopy(policies)
    optimiser = torch.optim.Adam(policies.parameters(), lr=settings.lr)
    skills = [SkillProgress(done=sampler.count(k) == 0) for k in range(len(policies))]
    curve: list[tuple[int, dict[str, float]]] = []
    path, step = Path(checkpoint_path), 0
    if path.is_file():
        checkpoint = load_checkpoint(path, latents.device)
        restore_models({"policy": policies, "best": best}, checkpoint)
        optimiser.load_state_dict(checkpoint.optimiser_states["policy"])
        skills = [SkillProgress(**state) for state in checkpoint.config["extra"]["skills"]]
        curve = [(int(s), dict(m)) for s, m in checkpoint.config["extra"]["curve"]]
        step = checkpoint.epoch
    else:
        mse = _evaluate_round(bundle, best, held_out, latents, skills, 0, settings.patience)
        curve.append((0, _round_metrics(bundle.skill_names, {}, mse, None)))
        _save_progress(path, policies, best, optimiser, skills, curve)
        if on_epoch is not None:
            on_epoch("policy", 0, curve[-1][1])
    while step < settings.steps and not all(skill.done for skill in skills):
        started = time.perf_counter()
        n_steps = min(settings.eval_every, settings.steps - step)
        losses = _train_round(bundle, settings, sampler, latents, skills, optimiser, step, n_steps, visits)
        step += n_steps
        mse = _evaluate_round(bundle, best, held_out, latents, skills, step, settings.patience)
        metrics = _round_metrics(bundle.skill_names, losses, mse, lr_at(step - 1, settings))
        metrics["policy_round_s"] = time.perf_counter() - started
        curve.append((step, metrics))
        _save_progress(path, policies, best, optimiser, skills, curve)
        if on_epoch is not None:
            on_epoch("policy", step, metrics)
    for k, samples in enumerate(held_out):
        if samples is not None:
            policies[k].load_state_dict(best[k].state_dict())
    policies.eval()
    names = bundle.skill_names
    return PolicyResult({names[k]: s.steps for k, s in enumerate(skills)},
                        {names[k]: s.best_step if held_out[k] is not None else s.steps for k, s in enumerate(skills)},
                        curve)
