"""``plan``: the best skill sequence, attention structure and latent subgoals from an observed set to a goal set."""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch

from pasta.plan.from_bundle import frozen_parameters, settings_functions
from pasta.plan.functions import PlanningFunctions
from pasta.plan.matching import best_matching, matched_pair_cost
from pasta.plan.optimiser import Candidate, optimise
from pasta.plan.result import Plan
from pasta.plan.sequences import enumerate_sequences, resolve_sequence, set_sizes
from pasta.plan.settings import PlanSettings
from pasta.train.bundle import TrainedModels

__all__ = ["Steps", "check_set", "describe", "plan", "plan_with", "score_of", "set_cost"]


@dataclass(frozen=True, eq=False)
class Steps:
    """The chosen sample's steps: skills, attention, ``U^0 .. U^H`` (CPU), per-step feasibility and guard
    penalty."""

    skills: tuple[str, ...]
    attention: tuple[tuple[int, ...], ...]
    latent_sets: tuple[torch.Tensor, ...]
    feasibilities: tuple[float, ...]
    penalties: tuple[float, ...]


def check_set(u: torch.Tensor, entity_dim: int, name: str) -> None:
    """Raise ``ValueError`` naming ``u``'s shape unless it is ``(K, entity_dim)`` with ``K >= 1`` and finite."""
    if not isinstance(u, torch.Tensor) or u.ndim != 2 or u.shape[1] != entity_dim:
        shape = tuple(u.shape) if isinstance(u, torch.Tensor) else type(u).__name__
        raise ValueError(f"{name} must have shape (K, {entity_dim}), got {shape}")
    if u.shape[0] == 0:
        raise ValueError(f"{name} must hold at least one entity, got shape {tuple(u.shape)}")
    if not bool(torch.isfinite(u).all()):
        raise ValueError(f"{name} holds non-finite values")


def describe(functions: PlanningFunctions, candidate: Candidate) -> Steps:
    """Read the steps of the best sample out of its pool and score each step's feasibility."""
    structures = candidate.structures[candidate.sequence_index]
    row, pool = candidate.row, candidate.pool
    feasibilities, penalties = [], []
    with torch.no_grad():
        for h, skill in enumerate(structures.sequence):
            inputs = pool[structures.attended[h][row].to(pool.device)].unsqueeze(0)
            outputs = pool[structures.created[h].to(pool.device)].unsqueeze(0)
            index = functions.skills.index(skill)
            feasibilities.append(float(functions.feasibility(index, inputs, outputs)[0]))
            penalties.append(float(functions.step_penalty(index, inputs, outputs)[0]))
    sets = tuple(pool[s[row].to(pool.device)].cpu() for s in structures.sets)
    return Steps(tuple(s.name for s in structures.sequence), structures.structure(row), sets, tuple(feasibilities),
                 tuple(penalties))


def set_cost(functions: PlanningFunctions, achieved: torch.Tensor, goal: torch.Tensor) -> float:
    """Predicted cost of ``achieved (K, E)`` against ``goal (K_g, E)`` under the optimal (partial) matching."""
    with torch.no_grad():
        a = achieved.to(goal.device)
        pair_costs = functions.pair_cost(a.unsqueeze(1).expand(-1, goal.shape[0], -1),
                                         goal.unsqueeze(0).expand(a.shape[0], -1, -1)).unsqueeze(0)
        return float(matched_pair_cost(pair_costs, *best_matching(pair_costs))[0])


def score_of(feasibilities: tuple[float, ...], cost: float, settings: PlanSettings,
             penalties: tuple[float, ...] = ()) -> float:
    """``sum_h (log max(f_h, floor) - penalty_h) - alpha * max(cost, 0)``."""
    log_f = torch.tensor(feasibilities, dtype=torch.float64).clamp_min(settings.feasibility_floor).log().sum()
    return float(log_f) - sum(penalties) - settings.alpha * max(cost, 0.0)


def plan_with(functions: PlanningFunctions, obs: torch.Tensor, goal: torch.Tensor, horizon: int,
              settings: PlanSettings, device: torch.device | str = "cpu",
              skill_sequences: list[tuple[str, ...]] | None = None) -> Plan:
    """Plan with given feasibility and cost functions (see ``plan``)."""
    started = time.perf_counter()
    device = torch.device(device)
    check_set(obs, functions.entity_dim, "obs")
    check_set(goal, functions.entity_dim, "goal")
    if skill_sequences is None:
        sequences = enumerate_sequences(functions.skills, horizon, obs.shape[0], goal.shape[0])
    else:
        if not skill_sequences:
            raise ValueError("skill_sequences is empty; pass None to enumerate them")
        sequences = [resolve_sequence(functions.skills, names, obs.shape[0]) for names in skill_sequences]
        for seq in sequences:
            if len(seq) != horizon:
                raise ValueError(f"sequence {[s.name for s in seq]} has length {len(seq)}, horizon is {horizon}")
            set_sizes(seq, obs.shape[0])
    generator = torch.Generator().manual_seed(settings.seed)
    goal_d = goal.to(device=device, dtype=torch.float32)
    candidate = optimise(functions, obs.to(device=device, dtype=torch.float32), goal_d, sequences, settings,
                         generator, device)
    steps = describe(functions, candidate)
    cost = set_cost(functions, steps.latent_sets[-1], goal_d)
    return Plan(steps.skills, steps.attention, steps.latent_sets, steps.feasibilities, cost,
                score_of(steps.feasibilities, cost, settings, steps.penalties), time.perf_counter() - started,
                steps.penalties)


def plan(bundle: TrainedModels, obs: torch.Tensor, goal: torch.Tensor, horizon: int, settings: PlanSettings,
         device: torch.device | str = "cpu", skill_sequences: list[tuple[str, ...]] | None = None) -> Plan:
    """The best plan from ``obs`` to ``goal`` with the bundle's feasibility and cost networks.

    Args:
        bundle: the models; moved to ``device``.
        obs: ``(K_o, D_z + 3)`` observed entity latents.
        goal: ``(K_g, D_z + 3)`` goal entity latents.
        horizon: steps ``H``.
        settings: optimiser settings.
        device: where to optimise ("cpu", "cuda", ...).
        skill_sequences: sequences to try; default every sequence of ``horizon`` whose net entity change is
            ``K_g - K_o``.

    Returns:
        The best sample's ``Plan`` (tensors on the CPU), with the time spent planning.
    """
    started = time.perf_counter()
    bundle.to(device)
    with frozen_parameters(bundle):
        functions = settings_functions(bundle, settings)
        result = plan_with(functions, obs, goal, horizon, settings, device, skill_sequences)
    return Plan(result.skills, result.attention, result.latent_sets, result.feasibilities, result.cost,
                result.score, time.perf_counter() - started, result.penalties)
