"""Policy samples of states the policies visited (DAgger rounds, :mod:`pasta.train.dagger`), kept beside the
demonstrations' transitions and drawn into the policies' batches (:func:`pasta.train.policy_loop.train_policies`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from pasta.train.datasets import PolicySamples

__all__ = ["VisitPool", "concat_samples", "take_samples"]


def concat_samples(parts: Sequence[PolicySamples]) -> PolicySamples:
    """The samples of ``parts`` one after the other (their chunks must have the same length)."""
    if not parts:
        raise ValueError("nothing to concatenate")
    return PolicySamples(
        obs_points=torch.cat([p.obs_points for p in parts]),
        tool_points=torch.cat([p.tool_points for p in parts]),
        goal_points=torch.cat([p.goal_points for p in parts]),
        tool_states=torch.cat([p.tool_states for p in parts]),
        actions=torch.cat([p.actions for p in parts]),
        action_chunks=torch.cat([p.action_chunks for p in parts]),
        phases=torch.cat([p.phases for p in parts]),
        previous_actions=torch.cat([p.previous_actions for p in parts]),
        obs_ids=[i for p in parts for i in p.obs_ids],
        goal_ids=[i for p in parts for i in p.goal_ids],
    )


def take_samples(samples: PolicySamples, rows: np.ndarray) -> PolicySamples:
    """The samples at positions ``rows`` (repeats allowed)."""
    index = torch.from_numpy(np.asarray(rows, dtype=np.int64))
    return PolicySamples(
        obs_points=samples.obs_points[index], tool_points=samples.tool_points[index],
        goal_points=samples.goal_points[index], tool_states=samples.tool_states[index],
        actions=samples.actions[index], action_chunks=samples.action_chunks[index], phases=samples.phases[index],
        previous_actions=samples.previous_actions[index],
        obs_ids=[samples.obs_ids[i] for i in rows], goal_ids=[samples.goal_ids[i] for i in rows],
    )


@dataclass(frozen=True, eq=False)
class VisitPool:
    """The visited states of every round so far, per skill (config order; None where a skill has none)."""

    samples: tuple[PolicySamples | None, ...]

    @classmethod
    def merge(cls, skill_names: Sequence[str], rounds: Sequence[dict[str, PolicySamples]]) -> VisitPool:
        """One pool from the rounds' ``{skill: samples}``."""
        merged = []
        for name in skill_names:
            parts = [r[name] for r in rounds if name in r]
            merged.append(concat_samples(parts) if parts else None)
        return cls(tuple(merged))

    def count(self, skill: int) -> int:
        samples = self.samples[skill]
        return 0 if samples is None else len(samples)

    def draw(self, skill: int, n: int, rng: np.random.Generator) -> PolicySamples | None:
        """``n`` samples of ``skill`` drawn uniformly (with replacement when the pool is smaller)."""
        size = self.count(skill)
        if size == 0:
            return None
        return take_samples(self.samples[skill], rng.choice(size, size=n, replace=size < n))
