"""PASTA, its ablations (appendix §4.1, Table 5) and the Flat3D baseline as data: one table of switches.

=========================  =============  ==================  ========================  ======  ============
variant                    latent noise   policy on latents   tool state after encoder  filter  whole scene
=========================  =============  ==================  ========================  ======  ============
pasta                      yes            no                  no                        yes     no
no_smoothing_feasibility   **no**         no                  no                        yes     no
shared_encoder_policy      yes            **yes**             no                        yes     no
tool_concat_policy         yes            no                  **yes**                   yes     no
set_without_filtering      yes            no                  no                        **no**  no
flat3d                     yes            no                  no                        **no**  **yes**
=========================  =============  ==================  ========================  ======  ============

Only the policy switches change which networks exist; the others tell the data and training code what
to do (``latent_noise``: sigma_z, sigma_t on feasibility inputs; ``filter_entities``: epsilon-filtering of
matched entities; ``whole_scene_latent``: encode the whole scene as one entity, so every set has K = 1).
Flat3D (model_spec §8.1) thus reuses the same classes: a whole-scene VAE, the set predictors with one
entity per side (with centred positions the feasibility input is ``(z_o, z_g, dt)``, as Flat3D's
``t_relative``), and the point-cloud policy (the official script's policy is [UNCLEAR], model_spec §8.1).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from types import MappingProxyType

import torch
from torch import nn

from pasta.config.schema import VARIANT_NAMES
from pasta.models.cost import CostPredictor
from pasta.models.feasibility import SetFeasibilityPredictor
from pasta.models.model_config import ModelConfig
from pasta.models.policy import SetPolicy
from pasta.models.policy_ablations import LatentSetPolicy, ToolConcatPolicy
from pasta.models.policy_ensemble import PolicyEnsemble
from pasta.models.vae import PointCloudVAE

__all__ = ["VARIANTS", "VARIANT_SPECS", "VariantSpec", "build_models", "variant_spec"]

VARIANTS = VARIANT_NAMES  # named in the config schema, so the CLI checks a variant without importing torch


@dataclass(frozen=True)
class VariantSpec:
    """The switches of one variant.

    Attributes:
        latent_noise: Gaussian noise (sigma_z, sigma_t) on the feasibility predictor's training latents.
        policy_on_latents: the policy acts on max-pooled entity latents (``LatentSetPolicy``).
        tool_state_after_encoder: the tool state joins after the point encoder (``ToolConcatPolicy``)
            instead of tool points joining the cloud.
        filter_entities: drop entities already matched to the goal (Chamfer < epsilon) in training and
            planning.
        whole_scene_latent: one latent for the whole scene instead of one per entity.
    """

    latent_noise: bool
    policy_on_latents: bool
    tool_state_after_encoder: bool
    filter_entities: bool
    whole_scene_latent: bool

    def __post_init__(self) -> None:
        if self.policy_on_latents and self.tool_state_after_encoder:
            raise ValueError("a policy on latents has no point encoder to concatenate the tool state after")


VARIANT_SPECS: Mapping[str, VariantSpec] = MappingProxyType(
    {
        "pasta": VariantSpec(True, False, False, True, False),
        "no_smoothing_feasibility": VariantSpec(False, False, False, True, False),
        "shared_encoder_policy": VariantSpec(True, True, False, True, False),
        "tool_concat_policy": VariantSpec(True, False, True, True, False),
        "set_without_filtering": VariantSpec(True, False, False, False, False),
        "flat3d": VariantSpec(True, False, False, False, True),
    }
)

# (policy_on_latents, tool_state_after_encoder) -> policy for one skill.
def _set_policy(action_dim: int, config: ModelConfig, skill: int) -> SetPolicy:
    pairs = config.policy.heading_pairs
    if pairs and len(pairs) <= skill:
        raise ValueError(f"policy.heading_pairs has {len(pairs)} entries; skill index {skill} has none")
    return SetPolicy(action_dim, config.policy, heading_pairs=pairs[skill] if pairs else ())


# The two policy ablations keep the appendix's inputs: no heading frame.
_POLICY_BUILDERS: Mapping[tuple[bool, bool], Callable[[int, ModelConfig, int], nn.Module]] = MappingProxyType(
    {
        (False, False): _set_policy,
        (True, False): lambda action_dim, config, skill: LatentSetPolicy(action_dim, config.latent_policy),
        (False, True): lambda action_dim, config, skill: ToolConcatPolicy(action_dim, config.tool_concat_policy),
    }
)


def _members(count: int, build: Callable[[], nn.Module]) -> nn.Module:
    """One policy from ``build``, or an ensemble of ``count`` (``ModelConfig.policy_members``)."""
    return build() if count == 1 else PolicyEnsemble.build(count, build)


def variant_spec(variant: str) -> VariantSpec:
    """The switches of ``variant``; raises ``ValueError`` naming the known variants."""
    try:
        return VARIANT_SPECS[variant]
    except KeyError:
        raise ValueError(f"unknown variant {variant!r}; known: {', '.join(VARIANTS)}") from None


def build_models(
    variant: str,
    action_dim: int,
    model_config: ModelConfig | None = None,
    *,
    n_skills: int = 1,
    seed: int = 0,
) -> dict[str, nn.Module]:
    """Freshly initialised networks of a variant.

    Args:
        variant: one of ``VARIANTS``.
        action_dim: the environment's full action vector (every skill policy outputs all of it).
        model_config: hyper-parameters (default ``ModelConfig()``).
        n_skills: one feasibility predictor and one policy per skill (official ``nn.ModuleList``).
        seed: weights are drawn from this seed without touching torch's global generator.

    Returns:
        ``{"vae": PointCloudVAE, "feasibility": ModuleList[n_skills], "cost": CostPredictor,
        "policy": ModuleList[n_skills]}``.
    """
    spec = variant_spec(variant)
    config = ModelConfig() if model_config is None else model_config
    if action_dim < 1 or n_skills < 1:
        raise ValueError(f"action_dim and n_skills must be >= 1, got {action_dim}, {n_skills}")
    build_policy = _POLICY_BUILDERS[(spec.policy_on_latents, spec.tool_state_after_encoder)]
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return {
            "vae": PointCloudVAE(config.vae),
            "feasibility": nn.ModuleList(SetFeasibilityPredictor(config.feasibility) for _ in range(n_skills)),
            "cost": CostPredictor(config.cost),
            "policy": nn.ModuleList(_members(config.policy_members, partial(build_policy, action_dim, config, k))
                                    for k in range(n_skills)),
        }
