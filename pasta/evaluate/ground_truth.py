"""The generator's ground-truth chain written as a plan: skills, attention and latent sets ``U^0 .. U^H``.

The chain (:func:`pasta.data.configurations.oracle_chain`) names, per skill, the particles it acts on and the
stage it must reach. :func:`ground_truth_plan` turns it into the planner's own terms, so the planner's
objective can score it and its attention can be compared with the planner's:

* ``U^0`` is the encoded observation the planner started from (its entities are the observation's DBSCAN
  components, in label order);
* step ``h`` attends the entities of ``U^{h-1}`` most of whose particles the chain acts on (the oracle's rule,
  :func:`pasta.evaluate.oracle.attended_components`, with each entity's particles tracked by identity);
* its new entities are the acted particles' places in stage ``h``, split by DBSCAN and encoded with the VAE
  (the new subgoals the oracle hands the policies);
* ``U^h`` = [the new entities, then the kept entities of ``U^{h-1}`` in their order], as the planner builds
  its sets (:mod:`pasta.plan.attention`).

For a whole-scene variant (Flat3D) every step acts on the one entity and ``U^h`` is the encoded stage.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from pasta.config.schema import TaskConfig
from pasta.data.configurations import OracleStep
from pasta.evaluate.encoding import EncodedScene, encode_scene
from pasta.evaluate.oracle import attended_components
from pasta.models.variants import variant_spec
from pasta.train.bundle import TrainedModels

__all__ = ["GroundTruthPlan", "ground_truth_plan"]

NO_ENTITY = -1  # a particle of an attended entity that the chain left alone belongs to no later entity


@dataclass(frozen=True, eq=False)
class GroundTruthPlan:
    """The ground-truth chain in the planner's terms.

    Attributes:
        skills: skill names, length ``H``.
        attention: per step ``h``, the positions in ``U^{h-1}`` of the entities the chain acts on.
        latent_sets: ``U^0 .. U^H``, each ``(K_h, D_z + 3)`` float32 on the CPU; ``U^h`` = [new, kept].
        stages: per step ``h = 1 .. H``, ``(P, 3)`` float32, every observed particle where the chain puts it.
    """

    skills: tuple[str, ...]
    attention: tuple[tuple[int, ...], ...]
    latent_sets: tuple[torch.Tensor, ...]
    stages: tuple[np.ndarray, ...]


def ground_truth_plan(cfg: TaskConfig, bundle: TrainedModels, chain: Sequence[OracleStep], start: EncodedScene,
                      rng: np.random.Generator) -> GroundTruthPlan:
    """Write ``chain`` as a plan from ``start``, the encoded observation the planner was given.

    Args:
        chain: the problem's ground-truth steps (particles in the generator's order, which the simulator keeps).
        start: the settled observation's ``P`` points encoded (``latents`` ``(K_0, D_z + 3)``, ``labels`` ``(P,)``).
        rng: resamples the new entities' clouds before encoding.
    """
    n_points = len(start.labels)
    whole_scene = variant_spec(bundle.variant).whole_scene_latent
    latents = start.latents.float().cpu()
    owner = np.asarray(start.labels, dtype=np.int64)  # (P,) position in U^h of the entity holding each particle
    sets, attention, stages = [latents], [], []
    for step in chain:
        acted = np.ones(n_points, bool) if whole_scene else np.asarray(step.acted[:n_points], bool)
        known = owner != NO_ENTITY
        attended = attended_components(owner[known], acted[known])
        stage = np.asarray(step.subgoal[:n_points], np.float32)
        new = encode_scene(cfg, bundle, stage[acted], rng)
        kept = [k for k in range(latents.shape[0]) if k not in attended]
        latents = torch.cat([new.latents.float().cpu(), latents[kept]])
        next_owner = np.full(n_points, NO_ENTITY, dtype=np.int64)
        for position, k in enumerate(kept, start=new.n_entities):
            next_owner[owner == k] = position
        next_owner[acted] = new.labels
        owner = next_owner
        sets.append(latents)
        attention.append(attended)
        stages.append(stage)
    return GroundTruthPlan(tuple(step.skill for step in chain), tuple(attention), tuple(sets), tuple(stages))
