"""The mass of every entity of a plan, carried from the observation through the plan's steps.

A decoded entity cloud has ``M`` points whatever the entity's size, so a decoded set needs a share of the mass
per entity before it can be compared with a real scene. ``cfg.eval.decoded_entity_weights`` says where the
shares come from:

* ``volume``: each decoded entity's convex hull (:func:`pasta.geometry.mass.merge_by_volume`). This charges the
  plan for the decoder's errors of thickness. At ``small`` the VAE decodes CRS's spread piece about as thick as
  the other piece, so the planned goal gets equal halves for a goal cut 0.39 / 0.61 (docs/planning.md).
* ``carried``: the masses a plan implies. No skill makes or destroys dough, so each step hands the total mass
  of the entities it attends to its new entities. When a step makes one entity (a push, a spread, a rearrange,
  a merge), that entity gets the whole mass. When it makes several (a cut), they split it by their decoded
  volumes. The observation's entities start with their shares of the observed points. The decoder's thickness
  then matters only where a step splits the dough, and there it only sets the ratio of the pieces.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from pasta.geometry.mass import hull_volume
from pasta.plan import Plan

__all__ = ["carried_masses", "observed_masses", "plan_masses"]


def observed_masses(labels: np.ndarray, n_entities: int) -> np.ndarray:
    """``(K,)`` share of the observed points in each entity, from the ``(P,)`` entity labels of an encoded scene
    (labels ``0 .. K - 1``; negative labels, noise, are not counted)."""
    labels = np.asarray(labels)
    counts = np.bincount(labels[labels >= 0], minlength=n_entities).astype(np.float64)
    if len(counts) != n_entities or counts.sum() == 0:
        raise ValueError(f"labels name entities {sorted(set(labels.tolist()))}, expected 0 .. {n_entities - 1}")
    return counts / counts.sum()


def carried_masses(attention: Sequence[Sequence[int]], initial: np.ndarray,
                   new_volumes: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Masses of ``U^0 .. U^H``.

    Args:
        attention: per step ``h``, the positions in ``U^{h-1}`` of the entities it attends to.
        initial: ``(K_0,)`` masses of ``U^0``.
        new_volumes: per step ``h``, ``(N_out,)`` the decoded volumes of its new entities (the first ``N_out`` of
            ``U^h``, whose other entities are ``U^{h-1}``'s unattended ones, in order).

    Returns:
        ``H + 1`` arrays, ``(K_h,)``: at step ``h`` the attended mass split among the new entities in proportion
        to their volumes (equally when none has volume), the unattended entities keeping theirs.
    """
    if len(attention) != len(new_volumes):
        raise ValueError(f"{len(attention)} steps of attention but {len(new_volumes)} steps of volumes")
    masses = [np.asarray(initial, dtype=np.float64)]
    for h, (attended, volumes) in enumerate(zip(attention, new_volumes, strict=True), start=1):
        before = masses[-1]
        chosen = [int(i) for i in attended]
        if not chosen or any(i < 0 or i >= len(before) for i in chosen) or len(set(chosen)) != len(chosen):
            raise ValueError(f"step {h} attends {chosen}, not distinct positions in a set of {len(before)}")
        volumes = np.asarray(volumes, dtype=np.float64)
        if volumes.ndim != 1 or len(volumes) == 0 or (volumes < 0).any():
            raise ValueError(f"step {h}: new volumes must be a non-empty vector >= 0, got {volumes}")
        shares = volumes / volumes.sum() if volumes.sum() > 0 else np.full(len(volumes), 1.0 / len(volumes))
        kept = np.delete(before, chosen)
        masses.append(np.concatenate([before[chosen].sum() * shares, kept]))
    return masses


def plan_masses(plan: Plan, decode: Callable[[torch.Tensor], np.ndarray], initial: np.ndarray) -> list[np.ndarray]:
    """:func:`carried_masses` of ``plan``, each step's new entities decoded (``decode``: ``(K, D_z + 3)`` latents
    -> ``(K, M, 3)`` clouds) for their volumes; ``initial`` ``(K_0,)`` (:func:`observed_masses`)."""
    volumes = []
    for attended, before, after in zip(plan.attention, plan.latent_sets[:-1], plan.latent_sets[1:], strict=True):
        n_out = after.shape[0] - (before.shape[0] - len(attended))
        volumes.append(np.array([hull_volume(cloud) for cloud in decode(after[:n_out])]))
    return carried_masses(plan.attention, initial, volumes)
