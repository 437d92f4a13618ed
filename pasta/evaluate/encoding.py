"""Point clouds to entity latents: DBSCAN the cloud into entities, resample each, encode with the VAE.

The planner sees a scene as a set ``U = {u_i}`` of entity latents ``u = [z, t]`` (appendix §1.1;
model_spec §5.1). Here a cloud (the observation or the goal) is split into entities by
:func:`pasta.geometry.label_entities` with the task's ``cfg.data.dbscan_*`` values, every entity is
resampled to ``ENTITY_POINTS`` points and encoded with the bundle's VAE (posterior mean ``z``,
``t`` = the entity's mean). The Flat3D baseline (``whole_scene_latent``) encodes the whole cloud as
one entity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.geometry.entities import label_entities, resample
from pasta.models.variants import variant_spec
from pasta.train.bundle import TrainedModels

__all__ = ["ENTITY_POINTS", "EncodedScene", "encode_scene", "segment"]

ENTITY_POINTS = 1000  # points per entity handed to the VAE (model_spec §0.2)


@dataclass(frozen=True, eq=False)
class EncodedScene:
    """One encoded cloud.

    Attributes:
        latents: ``(K, D_z + 3)`` float32 entity latents ``[z, t]``, in label order.
        labels: ``(P,)`` int64 entity label of every input point (all 0 for a whole-scene encoding).
        entities: ``(K, ENTITY_POINTS, 3)`` float32 resampled entity clouds that were encoded.
    """

    latents: torch.Tensor
    labels: np.ndarray
    entities: np.ndarray

    @property
    def n_entities(self) -> int:
        return int(self.latents.shape[0])


def segment(cfg: TaskConfig, points: np.ndarray) -> np.ndarray:
    """``(P,)`` DBSCAN entity labels of a ``(P, 3)`` cloud with ``cfg.data``'s eps, min_samples, min_points."""
    return label_entities(points, eps=cfg.data.dbscan_eps, min_samples=cfg.data.dbscan_min_samples,
                          min_points=cfg.data.dbscan_min_points)


def encode_scene(cfg: TaskConfig, bundle: TrainedModels, points: np.ndarray, rng: np.random.Generator
                 ) -> EncodedScene:
    """Encode a ``(P, 3)`` world cloud into entity latents ``(K, D_z + 3)`` with ``bundle.vae``.

    Entities are resampled with ``rng`` (subsampled without replacement, or padded with duplicates).
    """
    cloud = np.asarray(points, dtype=np.float32)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) == 0:
        raise ValueError(f"points must have shape (P, 3) with P >= 1, got {cloud.shape}")
    if variant_spec(bundle.variant).whole_scene_latent:
        labels = np.zeros(len(cloud), dtype=np.int64)
    else:
        labels = segment(cfg, cloud)
    entities = np.stack([resample(cloud[labels == k], ENTITY_POINTS, rng) for k in range(int(labels.max()) + 1)])
    vae = bundle.vae
    device = next(vae.parameters()).device
    with torch.no_grad():
        latents = vae.encode_entities(torch.from_numpy(entities).to(device)).float().cpu()
    return EncodedScene(latents=latents, labels=labels, entities=entities.astype(np.float32))
