"""``TrainedModels``: everything the planner and the executor need from training, saved as one checkpoint.

A bundle holds the networks of one variant (``build_models``), the task's skill names in config
order (index ``k`` of ``feasibility`` and ``policy`` is skill ``skill_names[k]``), the latent prior
(the box of training entity centres, for sampling and clamping ``t``) and the filtering threshold.
Training writes it with ``save_trained``; evaluation reads it with ``load_trained``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from pasta.config.schema import TaskConfig
from pasta.models.checkpoint import load_checkpoint, restore_models, save_checkpoint
from pasta.models.latent_prior import LatentPrior
from pasta.models.model_config import ModelConfig
from pasta.models.variants import build_models, variant_spec
from pasta.train.action_range import ActionRange

__all__ = ["DEFAULT_FILTER_EPSILON", "TrainedModels", "action_dim_of", "load_trained", "save_trained", "untrained"]

# Squared Chamfer below which an observation entity counts as already at its goal (model_spec §0.4).
DEFAULT_FILTER_EPSILON = 5e-4


def action_dim_of(cfg: TaskConfig) -> int:
    """Length of the task's full action vector: the action dims of every non-static tool."""
    return sum(len(tool.action_scales) for tool in cfg.tools if not tool.static)


def heading_pairs_of(cfg: TaskConfig) -> tuple[tuple[int, ...], ...]:
    """Per skill, the flat ``(x, z)`` index pairs of its tool's horizontal action vectors within the full action
    vector if ``policy.heading_skills`` names it (a box's translation and world-frame rotation; a gripper's
    translation, its rotation being in its own frame), else ``()``; ``()`` overall when no skill is named."""
    if not any(skill.name in cfg.policy.heading_skills for skill in cfg.skills):
        return ()
    starts, offset = {}, 0
    for tool in cfg.tools:
        if not tool.static:
            starts[tool.name] = offset
            offset += len(tool.action_scales)
    tools = {tool.name: tool for tool in cfg.tools}
    pairs = []
    for skill in cfg.skills:
        if skill.name not in cfg.policy.heading_skills:
            pairs.append(())
            continue
        a0 = starts[skill.tool]
        local = (0, 2, 3, 5) if tools[skill.tool].kind == "box" else (0, 2)
        pairs.append(tuple(a0 + i for i in local))
    return tuple(pairs)


@dataclass(frozen=True, eq=False)
class TrainedModels:
    """The trained networks of one (task, variant) and what is needed to use them.

    Attributes:
        task: task name the models were trained on (CRS-Twice uses CRS's models).
        variant: one of ``pasta.models.VARIANTS``.
        skill_names: skill names in config order; ``feasibility[k]`` and ``policy[k]`` belong to skill k.
        action_dim: the environment's full action vector length.
        model_config: hyper-parameters the networks were built with.
        prior: ``z ~ N(0, I)``, ``t ~ U(t_low, t_high)`` from the training entity centres.
        filter_epsilon: squared-Chamfer threshold of entity filtering (0 when the variant does not filter).
        models: ``{"vae", "feasibility" (ModuleList), "cost", "policy" (ModuleList)}``.
        reach: per skill, the largest displacement along x, y and z of an output entity's centre from the nearest
            input entity's centre over the training transitions (:mod:`pasta.plan.reach`; ``nan`` for a skill
            without any); ``None`` for a bundle trained before it was measured.
        vertical_range: per skill, the lowest and highest signed vertical displacement of an output entity's centre
            over the same transitions (:func:`pasta.plan.reach.skill_vertical_range`); ``None`` for a bundle
            trained before it was measured.
        input_shapes: per skill, the shape latents ``z`` (``D_z`` floats each) of every input entity of its training
            transitions (:mod:`pasta.plan.input_shapes`); ``None`` for a bundle trained before they were kept.
        action_range: per skill, the ``(A,)`` lowest and highest actions of its training demonstrations
            (:mod:`pasta.train.action_range`); ``None`` for a bundle trained before they were kept.
    """

    task: str
    variant: str
    skill_names: tuple[str, ...]
    action_dim: int
    model_config: ModelConfig
    prior: LatentPrior
    filter_epsilon: float
    models: dict[str, nn.Module]
    reach: tuple[tuple[float, float, float], ...] | None = None
    vertical_range: tuple[tuple[float, float], ...] | None = None
    input_shapes: tuple[tuple[tuple[float, ...], ...], ...] | None = None
    action_range: tuple[ActionRange, ...] | None = None

    def __post_init__(self) -> None:
        variant_spec(self.variant)
        if self.reach is not None and len(self.reach) != len(self.skill_names):
            raise ValueError(f"reach has {len(self.reach)} values for {len(self.skill_names)} skills")
        if self.reach is not None and any(len(r) != 3 for r in self.reach):
            raise ValueError(f"each skill's reach must be (x, y, z), got {self.reach}")
        if self.vertical_range is not None and (len(self.vertical_range) != len(self.skill_names)
                                                or any(len(r) != 2 for r in self.vertical_range)):
            raise ValueError(f"vertical_range must hold a (lowest, highest) pair per skill, got {self.vertical_range}")
        if self.input_shapes is not None and (
                len(self.input_shapes) != len(self.skill_names)
                or any(len(z) != self.prior.latent_dim for skill in self.input_shapes for z in skill)):
            raise ValueError(f"input_shapes must hold, per skill of {list(self.skill_names)}, shapes of "
                             f"{self.prior.latent_dim} floats")
        if self.action_range is not None and (
                len(self.action_range) != len(self.skill_names)
                or any(len(bound) != self.action_dim for pair in self.action_range for bound in pair)):
            raise ValueError(f"action_range must hold a (lowest, highest) pair of {self.action_dim} floats per skill "
                             f"of {list(self.skill_names)}")
        for key in ("vae", "feasibility", "cost", "policy"):
            if key not in self.models:
                raise ValueError(f"models lacks {key!r}; has {sorted(self.models)}")
        for key in ("feasibility", "policy"):
            if len(self.models[key]) != len(self.skill_names):  # type: ignore[arg-type]
                raise ValueError(
                    f"{key} has {len(self.models[key])} networks for {len(self.skill_names)} skills"  # type: ignore[arg-type]
                )

    def skill_index(self, skill: str) -> int:
        try:
            return self.skill_names.index(skill)
        except ValueError:
            raise KeyError(f"unknown skill {skill!r}; this bundle has {list(self.skill_names)}") from None

    @property
    def vae(self) -> nn.Module:
        return self.models["vae"]

    @property
    def cost(self) -> nn.Module:
        return self.models["cost"]

    def feasibility(self, skill: str) -> nn.Module:
        return self.models["feasibility"][self.skill_index(skill)]  # type: ignore[index]

    def policy(self, skill: str) -> nn.Module:
        return self.models["policy"][self.skill_index(skill)]  # type: ignore[index]

    def to(self, device: torch.device | str) -> TrainedModels:
        for module in self.models.values():
            module.to(device)
        return self

    def eval(self) -> TrainedModels:
        for module in self.models.values():
            module.eval()
        return self

    def metadata(self) -> dict[str, Any]:
        """Plain-data description (what the checkpoint's config holds)."""
        return {
            "task": self.task,
            "variant": self.variant,
            "skill_names": list(self.skill_names),
            "action_dim": self.action_dim,
            "model_config": self.model_config.to_dict(),
            "prior": {"latent_dim": self.prior.latent_dim, "t_low": list(self.prior.t_low),
                      "t_high": list(self.prior.t_high)},
            "filter_epsilon": self.filter_epsilon,
            "reach": None if self.reach is None else [list(r) for r in self.reach],
            "vertical_range": None if self.vertical_range is None else [list(r) for r in self.vertical_range],
            "input_shapes": None if self.input_shapes is None
            else [[list(z) for z in skill] for skill in self.input_shapes],
            "action_range": None if self.action_range is None
            else [[list(bound) for bound in pair] for pair in self.action_range],
        }


def untrained(cfg: TaskConfig, variant: str, prior: LatentPrior, *, model_config: ModelConfig | None = None,
              seed: int = 0) -> TrainedModels:
    """Freshly initialised networks for ``cfg``'s skills and action space (the start of training); ``cfg`` sets
    the latent size and the policies' point encoder, inputs and outputs (``policy.encoder``, ``frame``,
    ``phase_input``, ``chunk``, ``shape_quantiles``, ``gap_features``, ``heading_skills``, ``previous_action``,
    ``members``) of ``model_config``."""
    base = (model_config or ModelConfig()).with_latent_dim(cfg.train.latent_dim).with_vae_height_input(
        cfg.train.vae_height_input)
    config = base.with_policy_encoder(cfg.policy.encoder).with_policy_io(
        cfg.policy.frame, cfg.policy.phase_input, cfg.policy.chunk, cfg.policy.shape_quantiles,
        cfg.policy.gap_features, heading_pairs_of(cfg), cfg.policy.previous_action).with_policy_members(
        cfg.policy.members)
    spec = variant_spec(variant)
    return TrainedModels(
        task=cfg.task,
        variant=variant,
        skill_names=tuple(skill.name for skill in cfg.skills),
        action_dim=action_dim_of(cfg),
        model_config=config,
        prior=prior,
        filter_epsilon=DEFAULT_FILTER_EPSILON if spec.filter_entities else 0.0,
        models=build_models(variant, action_dim_of(cfg), config, n_skills=len(cfg.skills), seed=seed),
    )


def save_trained(path: str | os.PathLike[str], bundle: TrainedModels, *, epoch: int = 0,
                 optimiser_states: Mapping[str, dict[str, Any]] | None = None,
                 extra: Mapping[str, Any] | None = None) -> Path:
    """Write the bundle atomically; ``extra`` (plain data, e.g. training progress) rides in the config."""
    config = {"bundle": bundle.metadata(), "extra": dict(extra or {})}
    return save_checkpoint(path, bundle.models, optimiser_states, epoch, config)


def load_trained(path: str | os.PathLike[str], map_location: str | torch.device = "cpu") -> TrainedModels:
    """Rebuild the bundle written by ``save_trained`` (networks in eval mode)."""
    checkpoint = load_checkpoint(path, map_location)
    meta = checkpoint.config["bundle"]
    config = ModelConfig.from_dict(meta["model_config"])
    prior_meta = meta["prior"]
    prior = LatentPrior(int(prior_meta["latent_dim"]), tuple(prior_meta["t_low"]), tuple(prior_meta["t_high"]))
    models = build_models(meta["variant"], int(meta["action_dim"]), config, n_skills=len(meta["skill_names"]))
    restore_models(models, checkpoint)
    bundle = TrainedModels(
        task=meta["task"],
        variant=meta["variant"],
        skill_names=tuple(meta["skill_names"]),
        action_dim=int(meta["action_dim"]),
        model_config=config,
        prior=prior,
        filter_epsilon=float(meta["filter_epsilon"]),
        models=models,
        reach=None if meta.get("reach") is None else tuple(tuple(float(v) for v in r) for r in meta["reach"]),
        vertical_range=None if meta.get("vertical_range") is None
        else tuple(tuple(float(v) for v in r) for r in meta["vertical_range"]),
        input_shapes=None if meta.get("input_shapes") is None
        else tuple(tuple(tuple(float(v) for v in z) for z in skill) for skill in meta["input_shapes"]),
        action_range=None if meta.get("action_range") is None
        else tuple(tuple(tuple(float(v) for v in bound) for bound in pair) for pair in meta["action_range"]),
    )
    return bundle.to(map_location).eval()
