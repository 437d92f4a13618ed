"""The two training stages end to end, from a dataset folder to trained models on disk.

* ``load_training_data``: demonstrations, entity table (per-entity, or whole-scene for Flat3D) and the
  two trajectory splits (VAE 80/20, heads 90/10, seed 42).
* ``vae_stage``: train the VAE once (resuming from its progress file) and keep it as ``vae.pt``; a second
  call finds ``vae.pt`` and loads it, so every variant reuses one VAE per task, profile and representation.
* ``heads_stage``: encode every entity once with the frozen VAE, build the samplers and the fixed
  held-out set, and train the feasibility and cost heads, then the policies, of one variant (resuming
  from their progress files).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.models.latent_prior import LatentPrior
from pasta.models.model_config import ModelConfig
from pasta.models.variants import variant_spec
from pasta.plan.input_shapes import skill_input_shapes
from pasta.plan.reach import skill_reach, skill_vertical_range
from pasta.train.action_range import demonstrated_action_ranges
from pasta.train.bundle import DEFAULT_FILTER_EPSILON, action_dim_of
from pasta.train.datasets import DecodedGoals, TransitionSampler, split_trajectories, vae_clouds
from pasta.train.demos import Demonstrations, load_demonstrations
from pasta.train.entities import EntityTable, PairChamfer, build_entity_table, decode_latents
from pasta.train.heads_loop import HeadsResult, HeadsSettings, HeldOut, encode_entities, train_heads
from pasta.train.progress import EpochCallback
from pasta.train.vae_loop import VAEResult, VAESettings, load_vae, save_vae, train_vae

__all__ = ["TrainingData", "heads_stage", "load_training_data", "vae_file_name", "vae_stage"]

VAE_TEST_FRACTION = 0.2
HEADS_TEST_FRACTION = 0.1
SPLIT_SEED = 42


@dataclass(frozen=True, eq=False)
class TrainingData:
    """A dataset ready for training: its states, entities and trajectory splits (positions into ``demos``)."""

    demos: Demonstrations
    table: EntityTable
    whole_scene: bool
    vae_train: np.ndarray
    vae_heldout: np.ndarray
    heads_train: np.ndarray
    heads_heldout: np.ndarray


def load_training_data(cfg: TaskConfig, folder: str | Path, *, whole_scene: bool = False, seed: int = 0,
                       entity_points: int = 1000) -> TrainingData:
    """Read the dataset in ``folder``, cut its states into entities of ``entity_points`` points (the VAE
    decoder's output size) and split it by trajectory."""
    demos = load_demonstrations(folder, cfg, seed=seed)
    table = build_entity_table(demos, n_points=entity_points, whole_scene=whole_scene, seed=seed)
    vae_train, vae_heldout = split_trajectories(demos, VAE_TEST_FRACTION, SPLIT_SEED)
    heads_train, heads_heldout = split_trajectories(demos, HEADS_TEST_FRACTION, SPLIT_SEED, every_skill=True)
    if len(vae_heldout) == 0 or len(heads_heldout) == 0:
        raise ValueError(f"{folder}: {len(demos)} trajectories leave no held-out trajectory; need at least 10")
    return TrainingData(demos, table, whole_scene, vae_train, vae_heldout, heads_train, heads_heldout)


def vae_file_name(whole_scene: bool) -> str:
    """``vae`` for the entity VAE, ``vae_scene`` for the whole-scene VAE of Flat3D."""
    return "vae_scene" if whole_scene else "vae"


def vae_stage(cfg: TaskConfig, data: TrainingData, folder: str | Path, *, model_config: ModelConfig | None = None,
              seed: int = 0, on_epoch: EpochCallback | None = None,
              device: torch.device | None = None) -> VAEResult:
    """``folder/vae.pt`` if it exists, else train (resuming from ``folder/training.pt``) and write it."""
    folder = Path(folder)
    final = folder / "vae.pt"
    if final.is_file():
        return load_vae(final)
    config = (model_config or ModelConfig()).with_latent_dim(cfg.train.latent_dim).with_vae_height_input(
        cfg.train.vae_height_input).vae
    settings = VAESettings(epochs=cfg.train.vae_epochs, lr=cfg.train.vae_lr, precision=cfg.train.precision,
                           seed=seed)
    result = train_vae(vae_clouds(data.demos, data.table, data.vae_train),
                       vae_clouds(data.demos, data.table, data.vae_heldout), config, settings,
                       folder / "training.pt", on_epoch=on_epoch, device=device)
    save_vae(final, result, whole_scene=data.whole_scene)
    return result


def heads_stage(cfg: TaskConfig, variant: str, data: TrainingData, vae: torch.nn.Module, progress_path: str | Path,
                *, model_config: ModelConfig | None = None, settings: HeadsSettings | None = None, seed: int = 0,
                on_epoch: EpochCallback | None = None, device: torch.device | None = None) -> HeadsResult:
    """Train the heads of ``variant`` on ``data`` with the frozen ``vae``; resume from ``progress_path``."""
    spec = variant_spec(variant)
    if spec.whole_scene_latent != data.whole_scene:
        raise ValueError(f"variant {variant!r} needs whole_scene={spec.whole_scene_latent} data, "
                         f"got whole_scene={data.whole_scene}")
    device = device or torch.device("cpu")
    latents = encode_entities(vae, data.table.clouds, device)
    chamfer = PairChamfer(data.table)
    epsilon = DEFAULT_FILTER_EPSILON if spec.filter_entities else 0.0
    points, chunk, hindsight = cfg.policy.points, cfg.policy.chunk, cfg.train.policy_hindsight_ratio
    keep_acted = cfg.train.filter_keeps_acted
    decoded = None
    if cfg.train.policy_decoded_goal_share > 0 and not spec.policy_on_latents:
        decoded = DecodedGoals(decode_latents(vae.eval(), latents), cfg.train.policy_decoded_goal_share)
    aimed = cfg.train.feasibility_target_share
    train_sampler = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_train, epsilon, chamfer, points,
                                      chunk, hindsight, keep_acted, decoded, target_share=aimed)
    test_sampler = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_heldout, epsilon, chamfer, points,
                                     chunk, hindsight, keep_acted, target_share=aimed)
    train_states = np.concatenate([np.arange(data.demos.first_state[i], data.demos.target_state[i] + 1)
                                   for i in data.heads_train])
    train_entities = torch.from_numpy(data.table.of_states(train_states)).to(device)
    prior = LatentPrior.from_centres(latents[train_entities, cfg.train.latent_dim :].cpu(), cfg.train.latent_dim)
    held_out = HeldOut.build(test_sampler, latents)
    actions = demonstrated_action_ranges(data.demos, data.heads_train, len(cfg.skills), action_dim_of(cfg))
    result = train_heads(cfg, variant, vae, latents, train_sampler, held_out, prior,
                         settings or HeadsSettings.from_config(cfg, variant, seed), progress_path,
                         model_config=model_config, on_epoch=on_epoch, device=device, action_range=actions)
    centres = latents[:, cfg.train.latent_dim :].cpu()
    whole_pairs = [train_sampler.whole_skill_pairs(k) for k in range(len(cfg.skills))]
    transitions = [[(centres[o], centres[g]) for o, g in zip(pairs.obs, pairs.goal, strict=True)]
                   for pairs in whole_pairs]
    reach = tuple(skill_reach(skill) for skill in transitions)
    vertical = tuple(skill_vertical_range(skill) for skill in transitions)
    shapes = tuple(tuple(map(tuple, skill_input_shapes((latents[o].cpu() for o in pairs.obs),
                                                       cfg.train.latent_dim).tolist())) for pairs in whole_pairs)
    return dataclasses.replace(result, bundle=dataclasses.replace(result.bundle, reach=reach, vertical_range=vertical,
                                                                  input_shapes=shapes))
