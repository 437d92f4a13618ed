"""Entities of every state: point clouds resampled to a fixed size, and their Chamfer distances.

An entity is one DBSCAN cluster of one state (or, for the whole-scene Flat3D baseline, the whole
state). ``EntityTable`` holds every entity of a ``Demonstrations`` table as a ``(N, M, 3)`` cloud
(``M`` = 1000, resampled as the official ``decompose_pc``). ``PairChamfer`` computes and remembers the
Chamfer distance between entity pairs on their first 200 points (a random subset, since ``resample``
permutes; the official ``chamfer_downsample`` = 200), which is what filtering and the cost targets use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pasta.geometry.distances import chamfer_distance
from pasta.geometry.entities import resample
from pasta.train.demos import Demonstrations

__all__ = ["CHAMFER_POINTS", "EntityTable", "PairChamfer", "build_entity_table", "decode_latents", "state_cloud"]

CHAMFER_POINTS = 200


@dataclass(frozen=True, eq=False)
class EntityTable:
    """Every entity of every state.

    Attributes:
        clouds: ``(N, M, 3)`` float32 entity clouds, world frame.
        state: ``(N,)`` the state each entity belongs to.
        label: ``(N,)`` its DBSCAN label in that state (``-1``: the whole scene).
        state_entities: per state, the ids of its entities in label order.
    """

    clouds: torch.Tensor
    state: np.ndarray
    label: np.ndarray
    state_entities: tuple[np.ndarray, ...]

    def __len__(self) -> int:
        return len(self.state)

    def of_states(self, states: np.ndarray) -> np.ndarray:
        """Ids of all entities of the given states, in state then label order."""
        parts = [self.state_entities[s] for s in states]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def build_entity_table(demos: Demonstrations, *, n_points: int = 1000, whole_scene: bool = False,
                       seed: int = 0) -> EntityTable:
    """Split every state by its labels (or not, with ``whole_scene``) and resample each entity to ``n_points``.

    Each state's resampling draws from its own seeded generator, so the table does not depend on the order
    in which states are processed.
    """
    clouds, state, label, per_state = [], [], [], []
    for s in range(len(demos.points)):
        rng = np.random.default_rng([seed, s])
        points, labels = demos.points[s], demos.labels[s]
        groups = [(-1, points)] if whole_scene else [(int(k), points[labels == k]) for k in np.unique(labels)]
        start = len(state)
        for k, group in groups:
            clouds.append(resample(group, n_points, rng))
            state.append(s)
            label.append(k)
        per_state.append(np.arange(start, len(state), dtype=np.int64))
    return EntityTable(
        clouds=torch.from_numpy(np.stack(clouds).astype(np.float32)),
        state=np.asarray(state, dtype=np.int64),
        label=np.asarray(label, dtype=np.int64),
        state_entities=tuple(per_state),
    )


def state_cloud(demos: Demonstrations, table: EntityTable, entity_ids: np.ndarray, n_points: int,
                rng: np.random.Generator) -> np.ndarray:
    """The original points of the given entities (all of one state) together, resampled to ``(n_points, 3)``."""
    states = table.state[entity_ids]
    if len(states) == 0 or (states != states[0]).any():
        raise ValueError(f"entities {entity_ids.tolist()} belong to states {np.unique(states).tolist()}, "
                         f"need exactly one")
    points = demos.points[states[0]]
    labels = table.label[entity_ids]
    if (labels < 0).any():
        chosen = points
    else:  # a few labels: comparing against each is faster than np.isin's sort
        chosen = points[(demos.labels[states[0]][:, None] == labels[None, :]).any(axis=1)]
    return resample(chosen, n_points, rng)


class PairChamfer:
    """Chamfer distance (squared, both directions summed) between entity pairs, on 200-point subsets, memoised."""

    def __init__(self, table: EntityTable, n_points: int = CHAMFER_POINTS) -> None:
        self._sub = table.clouds[:, :n_points].contiguous()
        self._known: dict[tuple[int, int], float] = {}

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Distances ``(n,)`` between entities ``a[i]`` and ``b[i]`` (``(n,)`` int arrays)."""
        keys = list(zip(np.asarray(a).tolist(), np.asarray(b).tolist(), strict=True))
        missing = sorted({k for k in keys if k not in self._known})
        if missing:
            index = torch.as_tensor(missing, dtype=torch.long)
            with torch.no_grad():
                values = chamfer_distance(self._sub[index[:, 0]], self._sub[index[:, 1]])
            self._known.update(zip(missing, values.tolist(), strict=True))
        return np.asarray([self._known[k] for k in keys], dtype=np.float64)


def decode_latents(vae: torch.nn.Module, latents: torch.Tensor, batch_size: int = 256) -> np.ndarray:
    """Float32 world clouds ``(N, M, 3)`` of entity latents ``u = [z, t]`` ``(N, D_z + 3)``: ``vae.decode(z, t)`` in
    batches on the VAE's device, without gradients."""
    device, d = next(vae.parameters()).device, vae.config.latent_dim
    with torch.no_grad():
        parts = [vae.decode(u[:, :d].to(device).float(), u[:, d:].to(device).float()).float().cpu()
                 for u in latents.split(batch_size)]
    return torch.cat(parts).numpy()
