"""The range each skill's demonstrations span in every action dimension, and actions held to it.

A policy regressed on demonstrations can ask for actions none of them took: CutRearrange's rearrange policies
lower the gripper by up to 0.2 of its speed while they carry a piece, though every demonstration carries at
the height it gripped (its vertical actions lie in [0, 0.996]), and then lift the half-open fingers with the
piece on them. Training keeps, per skill, the lowest and highest value of every action dimension over the
skill's training trajectories; with ``eval.policy_action_range: demonstrated`` the executor clips each policy
action to that box after the environment's own [-1, 1].
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pasta.train.demos import Demonstrations

__all__ = ["ActionRange", "bounded", "demonstrated_action_ranges"]

ActionRange = tuple[tuple[float, ...], tuple[float, ...]]  # (lowest per dimension, highest per dimension)


def demonstrated_action_ranges(demos: Demonstrations, trajectories: Sequence[int] | np.ndarray, n_skills: int,
                               action_dim: int) -> tuple[ActionRange, ...]:
    """Per skill index ``0..n_skills-1``, the ``(A,)`` lowest and highest actions over the given trajectories
    (positions into ``demos``); ``[-1, 1]`` in every dimension for a skill without any."""
    ranges = []
    for k in range(n_skills):
        actions = [demos.actions[i] for i in trajectories if demos.skill_index[i] == k and len(demos.actions[i])]
        if not actions:
            ranges.append(((-1.0,) * action_dim, (1.0,) * action_dim))
            continue
        stacked = np.concatenate(actions).reshape(-1, action_dim)
        ranges.append((tuple(float(v) for v in stacked.min(0)), tuple(float(v) for v in stacked.max(0))))
    return tuple(ranges)


def bounded(action: np.ndarray, action_range: ActionRange) -> np.ndarray:
    """``(A,)`` ``action`` clipped to the ``(lowest, highest)`` box, as float32."""
    low, high = (np.asarray(bound, dtype=np.float32) for bound in action_range)
    if low.shape != np.shape(action) or high.shape != np.shape(action):
        raise ValueError(f"an action of shape {np.shape(action)} cannot be bounded by a range of "
                         f"{low.shape[0]} dimensions")
    return np.clip(np.asarray(action, dtype=np.float32), low, high)
