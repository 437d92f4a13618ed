"""``ModelConfig``: the hyper-parameters of every model, as one frozen dataclass that round-trips through a dict.

The dict form (``to_dict`` / ``from_dict``) is what checkpoints and MLflow runs store; ``from_dict``
rebuilds nested configs and turns lists back into tuples, and refuses unknown keys.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field, replace
from typing import Any

from pasta.models.cost import CostConfig
from pasta.models.feasibility import FeasibilityConfig
from pasta.models.policy import PolicyConfig
from pasta.models.policy_ablations import LatentPolicyConfig, ToolConcatPolicyConfig
from pasta.models.vae import VAEConfig

__all__ = ["ModelConfig"]


@dataclass(frozen=True)
class ModelConfig:
    """Hyper-parameters of the VAE, the feasibility and cost predictors and the three policy kinds.

    Every part that sees latents must agree on ``latent_dim``. ``policy_members`` > 1 makes each skill's policy
    (of whichever kind the variant has) an ensemble of that many (``pasta.models.policy_ensemble``).
    """

    vae: VAEConfig = field(default_factory=VAEConfig)
    feasibility: FeasibilityConfig = field(default_factory=FeasibilityConfig)
    cost: CostConfig = field(default_factory=CostConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    tool_concat_policy: ToolConcatPolicyConfig = field(default_factory=ToolConcatPolicyConfig)
    latent_policy: LatentPolicyConfig = field(default_factory=LatentPolicyConfig)
    policy_members: int = 1

    def __post_init__(self) -> None:
        if self.policy_members < 1:
            raise ValueError(f"policy_members must be at least 1, got {self.policy_members}")
        dims = {
            "vae": self.vae.latent_dim,
            "feasibility": self.feasibility.latent_dim,
            "cost": self.cost.latent_dim,
            "latent_policy": self.latent_policy.latent_dim,
        }
        if len(set(dims.values())) != 1:
            raise ValueError(f"latent_dim must agree across models, got {dims}")

    @property
    def latent_dim(self) -> int:
        return self.vae.latent_dim

    def with_latent_dim(self, latent_dim: int) -> ModelConfig:
        """This config with ``latent_dim`` set in every part (e.g. from ``TrainConfig.latent_dim``)."""
        return ModelConfig(
            vae=replace(self.vae, latent_dim=latent_dim),
            feasibility=replace(self.feasibility, latent_dim=latent_dim),
            cost=replace(self.cost, latent_dim=latent_dim),
            policy=self.policy,
            tool_concat_policy=self.tool_concat_policy,
            latent_policy=replace(self.latent_policy, latent_dim=latent_dim),
            policy_members=self.policy_members,
        )

    def with_vae_height_input(self, height_input: bool) -> ModelConfig:
        """This config with the VAE decoder reading the entity centre's height or not (``VAEConfig.height_input``;
        e.g. from ``TrainConfig.vae_height_input``)."""
        return replace(self, vae=replace(self.vae, height_input=height_input))

    def with_policy_encoder(self, name: str) -> ModelConfig:
        """This config with the point-cloud policies' encoder ``name`` (``pointnet2`` or ``pointnet``; e.g. from
        the task config's ``policy.encoder``): the set policy's and the tool-concat ablation's."""
        return replace(self, policy=replace(self.policy, point_encoder=name),
                       tool_concat_policy=replace(self.tool_concat_policy, point_encoder=name))

    def with_policy_io(self, frame: str, phase_input: bool, chunk: int, shape_quantiles: int = 0,
                       gap_features: bool = False, heading_pairs: tuple[tuple[int, ...], ...] = (),
                       previous_action_input: bool = False) -> ModelConfig:
        """This config with the set policy's cloud frame (``world`` or ``dough``), phase input, actions per call,
        shape quantiles, gap features, per-skill heading pairs and previous-action input (e.g. from the task
        config's ``policy.frame``, ``policy.phase_input``, ``policy.chunk``, ``policy.shape_quantiles``,
        ``policy.gap_features``, ``policy.heading_skills`` and ``policy.previous_action``)."""
        return replace(self, policy=replace(self.policy, frame=frame, phase_input=phase_input, chunk=chunk,
                                            shape_quantiles=shape_quantiles, gap_features=gap_features,
                                            heading_pairs=heading_pairs, previous_action_input=previous_action_input))

    def with_policy_members(self, members: int) -> ModelConfig:
        """This config with ``members`` policies per skill (e.g. from the task config's ``policy.members``)."""
        return replace(self, policy_members=members)

    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict (tuples stay tuples)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Inverse of ``to_dict``; accepts lists for tuples (as from JSON or YAML)."""
        return _build(cls, data)


def _build(kind: Any, value: Any) -> Any:
    if dataclasses.is_dataclass(kind) and isinstance(kind, type):
        if not isinstance(value, dict):
            raise TypeError(f"{kind.__name__} needs a dict, got {type(value).__name__}")
        names = {f.name for f in dataclasses.fields(kind)}
        unknown = set(value) - names
        if unknown:
            raise ValueError(f"unknown keys for {kind.__name__}: {sorted(unknown)}; allowed: {sorted(names)}")
        hints = typing.get_type_hints(kind)
        return kind(**{key: _build(hints[key], item) for key, item in value.items()})
    if typing.get_origin(kind) is tuple:
        args = typing.get_args(kind)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_build(args[0], item) for item in value)
        return tuple(_build(arg, item) for arg, item in zip(args, value, strict=True))
    return value
