"""One action of a skill policy from point clouds, for every policy kind a variant can have.

* ``SetPolicy`` (PASTA and most ablations): observation, tool and goal points (model_spec §4.1).
* ``ToolConcatPolicy``: observation and goal points plus the tool's 8-number state.
* ``LatentSetPolicy`` ("shared encoder"): the VAE latents of the observation piece and of the subgoals.

Actions come back unclipped; :func:`checked_action` refuses non-finite ones (naming the step and the
value) and only then clips to [-1, 1], as the environment would, and to the skill's demonstrated range where
``eval.policy_action_range`` asks for it (:func:`skill_action_range`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from pasta.models.policy_ablations import LatentSetPolicy, ToolConcatPolicy
from pasta.models.policy_ensemble import policy_members
from pasta.train.action_range import ActionRange, bounded
from pasta.train.bundle import TrainedModels

__all__ = ["NonFiniteActionError", "PolicyInput", "checked_action", "policy_action", "skill_action_range"]


class NonFiniteActionError(RuntimeError):
    """A policy produced a NaN or infinite action."""


@dataclass(frozen=True, eq=False)
class PolicyInput:
    """What a skill policy sees at one environment step.

    Attributes:
        obs_points: ``(N_o, 3)`` the attended dough, resampled.
        tool_points: ``(N_t, 3)`` surface points of the skill's tool.
        tool_state: ``(8,)`` the tool's position, quaternion and gap.
        goal_points: ``(N_g, 3)`` the decoded new subgoals, stacked.
        goal_latents: ``(N_out, D_z + 3)`` the new subgoal latents.
        phase: the step within the skill over the skill's step budget, in [0, 1).
        previous_action: ``(A,)`` the action applied at the previous step of the skill (zeros at its first).
    """

    obs_points: np.ndarray
    tool_points: np.ndarray
    tool_state: np.ndarray
    goal_points: np.ndarray
    goal_latents: torch.Tensor
    phase: float = 0.0
    previous_action: np.ndarray | None = None


def policy_action(bundle: TrainedModels, skill: str, seen: PolicyInput) -> np.ndarray:
    """The raw ``(H * action_dim,)`` float64 actions of ``skill``'s policy for this step and the ``H - 1`` next
    (``H`` = 1 unless the policy predicts chunks; no clipping, no checks), computed on the policy's device."""
    policy = bundle.policy(skill)
    kind = policy_members(policy)[0]  # an ensemble (policy.members) takes its members' inputs
    device = next(itertools.chain(policy.parameters(), policy.buffers()), torch.empty(0)).device

    def batch(values: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.array(values, dtype=np.float32)).unsqueeze(0).to(device)

    with torch.no_grad():
        if isinstance(kind, LatentSetPolicy):
            obs = bundle.vae.encode_entities(batch(seen.obs_points)).unsqueeze(0)  # (1, 1, E)
            action = policy(obs, seen.goal_latents.float().unsqueeze(0).to(device))
        elif isinstance(kind, ToolConcatPolicy):
            action = policy(batch(seen.obs_points), batch(seen.goal_points), batch(seen.tool_state))
        else:
            phase = torch.tensor([seen.phase], dtype=torch.float32, device=device)
            previous = None if seen.previous_action is None else batch(seen.previous_action)
            action = policy(batch(seen.obs_points), batch(seen.tool_points), batch(seen.goal_points), phase,
                            previous)
    return action.reshape(-1).double().cpu().numpy()


def skill_action_range(bundle: TrainedModels, skill: str, mode: str) -> ActionRange | None:
    """The box beyond [-1, 1] that ``eval.policy_action_range`` = ``mode`` holds ``skill``'s policy actions to:
    None for ``"unit"``, the bundle's demonstrated range for ``"demonstrated"``."""
    if mode == "unit":
        return None
    if mode != "demonstrated":
        raise ValueError(f"unknown policy action range {mode!r}; choose 'unit' or 'demonstrated'")
    if bundle.action_range is None:
        raise ValueError("eval.policy_action_range 'demonstrated' needs a bundle that kept its demonstrations' action "
                         "range; this one was trained before it was kept: run `pasta train` again (it reuses the "
                         "trained networks) or set eval.policy_action_range=unit")
    return bundle.action_range[bundle.skill_index(skill)]


def checked_action(action: np.ndarray, skill: str, plan_step: int, env_step: int,
                   action_range: ActionRange | None = None) -> np.ndarray:
    """``action`` clipped to [-1, 1] and then to ``action_range`` (when given) as float32; raises
    :class:`NonFiniteActionError` if any value is not finite."""
    values = np.asarray(action, dtype=np.float64).reshape(-1)
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.argmax(bad))
        raise NonFiniteActionError(
            f"policy of skill {skill!r} (plan step {plan_step}) gave a non-finite action at environment step "
            f"{env_step}: value {float(values[i])} at index {i} of {values.tolist()}"
        )
    clipped = np.clip(values, -1.0, 1.0).astype(np.float32)
    return clipped if action_range is None else bounded(clipped, action_range)
