"""What the training tests build on the tiny synthetic dataset: a tiny VAE, the latents, the prior and the
train and held-out samplers of one variant."""

from __future__ import annotations

import torch

from pasta.models import LatentPrior, PointCloudVAE, variant_spec
from pasta.train.bundle import DEFAULT_FILTER_EPSILON
from pasta.train.datasets import TransitionSampler
from pasta.train.entities import PairChamfer
from pasta.train.heads_loop import encode_entities
from tests.models.synthetic import tiny_model_config


def heads_inputs(cfg, data, variant):
    """``(model config, VAE, latents (N, 2 + 3), prior, train sampler, held-out sampler)`` for ``variant``."""
    config = tiny_model_config()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        vae = PointCloudVAE(config.vae)
    vae.fit_scale(data.table.clouds)
    latents = encode_entities(vae, data.table.clouds, torch.device("cpu"))
    prior = LatentPrior.from_centres(latents[:, 2:], 2)
    epsilon = DEFAULT_FILTER_EPSILON if variant_spec(variant).filter_entities else 0.0
    chamfer = PairChamfer(data.table)
    train = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_train, epsilon, chamfer)
    test = TransitionSampler(data.demos, data.table, cfg.skills, data.heads_heldout, epsilon, chamfer)
    return config, vae, latents, prior, train, test
