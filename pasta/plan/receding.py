"""Receding-horizon planning (appendix §2.4, model_spec §5.7) for long fixed skill sequences (CRS-Twice).

For ``t = 0 .. H-1`` the window ``skills[t : t + window]`` (shrinking at the end) is optimised from the
previous stage's chosen set, its final set scored against the *full* goal (partial matching when it
holds fewer entities); only the first step of the best sample is kept. With ``warm_start`` one sample of
each window after the first continues the previous window's best plan (its steps after the kept one, with
their attention and latents), so the windows refine one plan instead of each starting afresh.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import torch

from pasta.plan.from_bundle import frozen_parameters, settings_functions
from pasta.plan.functions import PlanningFunctions
from pasta.plan.optimiser import Candidate, WarmStart, optimise
from pasta.plan.planner import check_set, describe, score_of, set_cost
from pasta.plan.result import Plan
from pasta.plan.sequences import resolve_sequence, set_sizes
from pasta.plan.settings import PlanSettings
from pasta.train.bundle import TrainedModels

__all__ = ["plan_receding_horizon", "plan_receding_horizon_with"]


def plan_receding_horizon_with(functions: PlanningFunctions, obs: torch.Tensor, goal: torch.Tensor,
                               skill_sequence: Sequence[str], window: int, settings: PlanSettings,
                               device: torch.device | str = "cpu", warm_start: bool = False) -> Plan:
    """Receding-horizon planning with given functions (see ``plan_receding_horizon``)."""
    started = time.perf_counter()
    device = torch.device(device)
    check_set(obs, functions.entity_dim, "obs")
    check_set(goal, functions.entity_dim, "goal")
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    sequence = resolve_sequence(functions.skills, skill_sequence, obs.shape[0])
    if not sequence:
        raise ValueError("skill_sequence is empty")
    set_sizes(sequence, obs.shape[0])
    generator = torch.Generator().manual_seed(settings.seed)
    goal_d = goal.to(device=device, dtype=torch.float32)
    current = obs.to(device=device, dtype=torch.float32)
    sets, attention, feasibilities, penalties = [current.cpu()], [], [], []
    carried: WarmStart | None = None
    for t in range(len(sequence)):
        candidate = optimise(functions, current, goal_d, [sequence[t : t + window]], settings, generator, device,
                             carried)
        steps = describe(functions, candidate)
        attention.append(steps.attention[0])
        feasibilities.append(steps.feasibilities[0])
        penalties.append(steps.penalties[0])
        sets.append(steps.latent_sets[1])
        current = steps.latent_sets[1].to(device)
        if warm_start and len(steps.skills) > 1:
            carried = _remainder(candidate)
    cost = set_cost(functions, sets[-1], goal_d)
    return Plan(tuple(skill_sequence), tuple(attention), tuple(sets), tuple(feasibilities), cost,
                score_of(tuple(feasibilities), cost, settings, tuple(penalties)), time.perf_counter() - started,
                tuple(penalties))


def _remainder(candidate: Candidate) -> WarmStart:
    """The best sample's steps after its first: their attention in ``U^1 ..`` and their new vectors."""
    structures = candidate.structures[candidate.sequence_index]
    first_new = structures.n_fixed + structures.created[0].shape[0]
    return WarmStart(structures.structure(candidate.row)[1:], candidate.pool[first_new:].detach())


def plan_receding_horizon(bundle: TrainedModels, obs: torch.Tensor, goal: torch.Tensor, skill_sequence: Sequence[str],
                          window: int, settings: PlanSettings, device: torch.device | str = "cpu",
                          warm_start: bool = False) -> Plan:
    """A ``len(skill_sequence)``-step plan built one step at a time with a ``window``-step look-ahead.

    Args:
        bundle: the models; moved to ``device``.
        obs: ``(K_o, D_z + 3)`` observed entity latents.
        goal: ``(K_g, D_z + 3)`` goal entity latents.
        skill_sequence: the fixed skills, e.g. ``("cut", "push", "spread") * 2`` for CRS-Twice.
        window: look-ahead ``H_RHP`` (3 in the paper).
        settings: optimiser settings for every window.
        device: where to optimise.
        warm_start: seed one sample of each window with the rest of the previous window's best plan.

    Returns:
        A ``Plan`` whose step ``h`` starts from ``latent_sets[h - 1]``, the set chosen at stage ``h - 1``.
    """
    started = time.perf_counter()
    bundle.to(device)
    with frozen_parameters(bundle):
        functions = settings_functions(bundle, settings)
        result = plan_receding_horizon_with(functions, obs, goal, skill_sequence, window, settings, device,
                                             warm_start)
    return Plan(result.skills, result.attention, result.latent_sets, result.feasibilities, result.cost,
                result.score, time.perf_counter() - started, result.penalties)
