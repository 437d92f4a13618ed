"""Networks of PASTA: entity VAE, set feasibility and cost predictors, point-cloud policies, variants.

Models see tensors only: points ``(B, N, 3)`` and latent sets ``(B, K, D_z + 3)`` with boolean masks
``(B, K)``; they know nothing of the simulator. See ``docs/models.md``.
"""

from pasta.models.checkpoint import Checkpoint, load_checkpoint, restore_models, save_checkpoint
from pasta.models.cloud_pointnet import CloudPointNet, CloudPointNetConfig
from pasta.models.cost import CostConfig, CostPredictor, hungarian_assignment, matched_cost
from pasta.models.feasibility import FeasibilityConfig, SetFeasibilityPredictor
from pasta.models.feasibility_samples import (
    FeasibilityBatch,
    HardNegatives,
    add_latent_noise,
    feasibility_batch,
    hard_negatives,
    random_negatives,
    weighted_mse,
)
from pasta.models.latent_prior import LatentPrior
from pasta.models.model_config import ModelConfig
from pasta.models.pointnet import (
    GlobalSetAbstraction,
    PointNetPlusPlusConfig,
    PointNetPlusPlusEncoder,
    SetAbstraction,
    SetAbstractionStage,
    ball_query,
    farthest_point_sample,
)
from pasta.models.policy import FilteredEntities, PolicyConfig, SetPolicy, filter_entities, uniform_point_noise
from pasta.models.policy_ablations import LatentPolicyConfig, LatentSetPolicy, ToolConcatPolicy, ToolConcatPolicyConfig
from pasta.models.vae import PointCloudVAE, VAEConfig
from pasta.models.variants import VARIANT_SPECS, VARIANTS, VariantSpec, build_models, variant_spec

__all__ = [
    "VARIANTS",
    "VARIANT_SPECS",
    "Checkpoint",
    "CloudPointNet",
    "CloudPointNetConfig",
    "CostConfig",
    "CostPredictor",
    "FeasibilityBatch",
    "FeasibilityConfig",
    "FilteredEntities",
    "GlobalSetAbstraction",
    "HardNegatives",
    "LatentPolicyConfig",
    "LatentPrior",
    "LatentSetPolicy",
    "ModelConfig",
    "PointCloudVAE",
    "PointNetPlusPlusConfig",
    "PointNetPlusPlusEncoder",
    "PolicyConfig",
    "SetAbstraction",
    "SetAbstractionStage",
    "SetFeasibilityPredictor",
    "SetPolicy",
    "ToolConcatPolicy",
    "ToolConcatPolicyConfig",
    "VAEConfig",
    "VariantSpec",
    "add_latent_noise",
    "ball_query",
    "build_models",
    "farthest_point_sample",
    "feasibility_batch",
    "filter_entities",
    "hard_negatives",
    "hungarian_assignment",
    "load_checkpoint",
    "matched_cost",
    "random_negatives",
    "restore_models",
    "save_checkpoint",
    "uniform_point_noise",
    "variant_spec",
    "weighted_mse",
]
