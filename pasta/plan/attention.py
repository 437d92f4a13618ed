"""Random attention structures: which entities of ``U^{h-1}`` each step of each sample works on.

Every sample owns an entity *pool* ``[U^0 entities | new vectors of step 1 | of step 2 | ...]``; a latent
set ``U^h`` is a list of pool indices. At step ``h`` a uniformly random permutation of the ``K_{h-1}``
entities picks the attended ones (its first ``n_in``); the rest are kept in their order, and
``U^h = [the n_out new vectors, then the kept entities]`` (appendix §1.3, model_spec §5.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from pasta.plan.sequences import SkillSpec, set_sizes

__all__ = ["Structures", "sample_structures"]


@dataclass(frozen=True, eq=False)
class Structures:
    """The attention structures of ``S`` samples of one skill sequence (CPU long tensors).

    Attributes:
        sequence: the skills, length ``H``.
        attention: per step, ``(S, n_in)`` positions in ``U^{h-1}`` of the attended entities.
        attended: per step, ``(S, n_in)`` pool indices of the attended entities.
        created: per step, ``(n_out,)`` pool indices of the step's new vectors (the same for every sample).
        sets: per ``h = 0 .. H``, ``(S, K_h)`` pool indices of ``U^h``.
        n_fixed: ``K_0``, the pool's leading constant entities.
        n_variables: new vectors per sample (``sum_h n_out``); pool index ``n_fixed + j`` is variable ``j``.
    """

    sequence: tuple[SkillSpec, ...]
    attention: tuple[torch.Tensor, ...]
    attended: tuple[torch.Tensor, ...]
    created: tuple[torch.Tensor, ...]
    sets: tuple[torch.Tensor, ...]
    n_fixed: int
    n_variables: int

    @property
    def n_samples(self) -> int:
        return self.sets[0].shape[0]

    def structure(self, row: int) -> tuple[tuple[int, ...], ...]:
        """Sample ``row``'s attention: per step, the attended positions in ``U^{h-1}``."""
        return tuple(tuple(int(i) for i in step[row]) for step in self.attention)


def sample_structures(sequence: tuple[SkillSpec, ...], k_obs: int, n_samples: int,
                      generator: torch.Generator, first_row: tuple[tuple[int, ...], ...] = ()) -> Structures:
    """Draw ``n_samples`` independent attention structures for ``sequence`` from ``k_obs`` entities.

    ``first_row`` fixes sample 0's attended positions for the first ``len(first_row)`` steps (a warm start);
    the random draws are the same with or without it, so every other sample is unchanged.
    """
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    sizes = set_sizes(sequence, k_obs)
    if len(first_row) > len(sequence):
        raise ValueError(f"first_row has {len(first_row)} steps, the sequence {len(sequence)}")
    current = torch.arange(k_obs).expand(n_samples, k_obs)
    sets, attention, attended, created = [current], [], [], []
    next_index = k_obs
    for h, (skill, size) in enumerate(zip(sequence, sizes[:-1], strict=True)):
        order = torch.rand((n_samples, size), generator=generator).argsort(dim=1)
        if h < len(first_row):
            order[0] = _fixed_order(first_row[h], skill.n_in, size, h)
        chosen = order[:, : skill.n_in]
        kept = order[:, skill.n_in :].sort(dim=1).values
        new = torch.arange(next_index, next_index + skill.n_out)
        next_index += skill.n_out
        attention.append(chosen)
        attended.append(current.gather(1, chosen))
        created.append(new)
        current = torch.cat([new.expand(n_samples, -1), current.gather(1, kept)], dim=1)
        sets.append(current)
    return Structures(sequence, tuple(attention), tuple(attended), tuple(created), tuple(sets), k_obs,
                      next_index - k_obs)


def _fixed_order(positions: tuple[int, ...], n_in: int, size: int, step: int) -> torch.Tensor:
    """The ordering whose first ``n_in`` entries are ``positions`` and the rest the other positions, ascending."""
    if len(positions) != n_in or len(set(positions)) != n_in or not all(0 <= p < size for p in positions):
        raise ValueError(f"step {step}: attended positions {positions} must be {n_in} distinct values in "
                         f"[0, {size})")
    rest = [p for p in range(size) if p not in positions]
    return torch.tensor([*positions, *rest])
