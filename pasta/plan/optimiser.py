"""The batched latent optimiser: every sample of every skill sequence in one tensor program.

Per sample the variables are the new vectors of every step (``(V, D_z + 3)``); the objective is

    J = sum_h log max(f_{k_h}(attended inputs of step h, its new vectors), floor) - alpha * max(C(U^H, goal), 0)

with ``C`` the summed predicted cost of the matched (achieved, goal) entity pairs. The matching is chosen
on the first iteration and frozen (only the matched pairs are evaluated afterwards); the last iteration
re-matches optimally and only evaluates. Samples are independent, so the batch can be cut into chunks
(bounded memory) and the worse half of the survivors can be dropped at chosen iterations
(successive halving) without changing any surviving sample's trajectory.

Feasibility is evaluated once per skill per chunk on all (sample, step) pairs that use that skill,
across all sequences; the cost once per chunk, as every sequence ends with the same entity count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from pasta.plan.adam import RowAdam
from pasta.plan.attention import Structures, sample_structures
from pasta.plan.functions import PlanningFunctions
from pasta.plan.goal_init import goal_directed_latents
from pasta.plan.matching import best_matching, matched_pair_cost
from pasta.plan.sequences import SkillSpec
from pasta.plan.settings import PlanSettings

__all__ = ["Candidate", "WarmStart", "optimise"]


@dataclass(frozen=True, eq=False)
class Candidate:
    """The best sample of one optimisation.

    Attributes:
        structures: the sampled structures of every sequence (CPU).
        sequence_index: which sequence (index into ``structures``) the best sample belongs to.
        row: its row within that sequence's structures.
        pool: ``(K_0 + V, D_z + 3)`` its entity pool, detached, on the planning device.
        score: its final objective.
        sample_iterations: objective evaluations done over all samples (the work done).
    """

    structures: tuple[Structures, ...]
    sequence_index: int
    row: int
    pool: torch.Tensor
    score: float
    sample_iterations: int


@dataclass(frozen=True, eq=False)
class WarmStart:
    """A partial plan that sample 0 of the first sequence starts from (the previous receding window's plan).

    Attributes:
        attention: per leading step, the attended positions in ``U^{h-1}``.
        variables: ``(V_w, D_z + 3)`` the new vectors of those steps, in step order.
    """

    attention: tuple[tuple[int, ...], ...]
    variables: torch.Tensor


@dataclass(frozen=True, eq=False)
class _Group:
    """All (sample, step) pairs that use one skill: rows (sorted), attended and new pool indices."""

    skill: int
    rows: torch.Tensor  # (M,)
    inputs: torch.Tensor  # (M, n_in)
    outputs: torch.Tensor  # (M, n_out)

    def keep(self, new_position: torch.Tensor) -> _Group:
        mapped = new_position[self.rows]
        kept = mapped >= 0
        return _Group(self.skill, mapped[kept], self.inputs[kept], self.outputs[kept])


def _groups(structures: tuple[Structures, ...], skills: tuple[SkillSpec, ...], device: torch.device) -> list[_Group]:
    """Every (sample, step) of every sequence, grouped by skill; rows sorted so a chunk is one slice."""
    parts: dict[int, list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]] = {}
    offset = 0
    for st in structures:
        rows = torch.arange(offset, offset + st.n_samples)
        for skill, attended, created in zip(st.sequence, st.attended, st.created, strict=True):
            k = skills.index(skill)
            parts.setdefault(k, []).append((rows, attended, created.expand(st.n_samples, -1)))
        offset += st.n_samples
    groups = []
    for k, items in sorted(parts.items()):
        rows = torch.cat([r for r, _, _ in items])
        order = rows.argsort(stable=True)
        groups.append(_Group(k, rows[order].to(device), torch.cat([i for _, i, _ in items])[order].to(device),
                             torch.cat([o for _, _, o in items])[order].to(device)))
    return groups


def _evaluate(functions: PlanningFunctions, pool: torch.Tensor, groups: list[_Group],
              slices: list[tuple[int, int]], row_start: int, final: torch.Tensor, goal: torch.Tensor,
              settings: PlanSettings, match: tuple[torch.Tensor, torch.Tensor] | None
              ) -> tuple[torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Objective of one chunk of samples (rows ``row_start ..``).

    Args:
        functions: feasibility and pair cost.
        pool: ``(b, P, E)`` entity pools of the chunk's samples.
        groups: the skill groups; ``slices[g]`` is group ``g``'s slice of rows inside this chunk.
        slices: per group, ``(start, stop)`` into its rows.
        row_start: batch row of the chunk's first sample.
        final: ``(b, K_H)`` pool indices of ``U^H``.
        goal: ``(K_g, E)``.
        settings: floor and alpha.
        match: frozen matching ``(rows, cols)``, each ``(b, M)``, or ``None`` to match optimally now.

    Returns:
        ``score (b,)``, ``cost (b,)`` and the matching used.
    """
    b, _, e = pool.shape
    log_f = pool.new_zeros(b)
    for group, (lo, hi) in zip(groups, slices, strict=True):
        if lo == hi:
            continue
        local = group.rows[lo:hi] - row_start
        sample = local.unsqueeze(1)
        inputs, outputs = pool[sample, group.inputs[lo:hi]], pool[sample, group.outputs[lo:hi]]
        f = functions.feasibility(group.skill, inputs, outputs)
        step = f.clamp_min(settings.feasibility_floor).log() - functions.step_penalty(group.skill, inputs, outputs)
        log_f = log_f.index_add(0, local, step)
    achieved = pool.gather(1, final.unsqueeze(-1).expand(-1, -1, e))  # (b, K_H, E)
    if match is None:
        k_h, k_g = achieved.shape[1], goal.shape[0]
        a = achieved.unsqueeze(2).expand(-1, -1, k_g, -1).reshape(-1, e)
        pair_costs = functions.pair_cost(a, goal.expand(b, k_h, -1, -1).reshape(-1, e)).view(b, k_h, k_g)
        match = best_matching(pair_costs)
        cost = matched_pair_cost(pair_costs, *match)
    else:
        rows, cols = match
        a = achieved.gather(1, rows.unsqueeze(-1).expand(-1, -1, e)).reshape(-1, e)
        cost = functions.pair_cost(a, goal[cols].reshape(-1, e)).view(b, -1).sum(dim=1)
    return log_f - settings.alpha * cost.clamp_min(0.0), cost, match


def _chunks(n: int, size: int) -> list[tuple[int, int]]:
    return [(lo, min(lo + size, n)) for lo in range(0, n, size)]


def _slices(groups: list[_Group], chunks: list[tuple[int, int]]) -> list[list[tuple[int, int]]]:
    """Per chunk, per group: the slice of the group's (sorted) rows that fall in the chunk."""
    edges = torch.tensor([lo for lo, _ in chunks] + [chunks[-1][1]])
    cuts = [torch.searchsorted(g.rows.cpu(), edges).tolist() for g in groups]
    return [[(c[i], c[i + 1]) for c in cuts] for i in range(len(chunks))]


def optimise(functions: PlanningFunctions, start: torch.Tensor, goal: torch.Tensor,
             sequences: list[tuple[SkillSpec, ...]], settings: PlanSettings, generator: torch.Generator,
             device: torch.device, warm_start: WarmStart | None = None) -> Candidate:
    """Optimise ``settings.samples`` samples of each sequence from ``start`` towards ``goal``; return the best.

    Args:
        functions: skills, prior, feasibility and pair cost (on ``device``).
        start: ``(K_0, E)`` the constant initial entities, on ``device``.
        goal: ``(K_g, E)`` the goal entities, on ``device``.
        sequences: skill sequences; all must end with the same entity count.
        settings: optimiser settings.
        generator: CPU generator for the structures and initial latents (so results do not depend on device).
        device: where to compute.
        warm_start: sample 0 of the first sequence takes these leading steps (attention and initial vectors);
            its remaining vectors and every other sample are drawn as without it.
    """
    k_obs = start.shape[0]
    first_row = warm_start.attention if warm_start is not None else ()
    structures = tuple(sample_structures(seq, k_obs, settings.samples, generator, first_row if i == 0 else ())
                       for i, seq in enumerate(sequences))
    final_sizes = {st.sets[-1].shape[1] for st in structures}
    if len(final_sizes) != 1:
        raise ValueError(f"skill sequences end with different entity counts {sorted(final_sizes)}: "
                         f"{[[s.name for s in seq] for seq in sequences]}")
    n_vars = max(st.n_variables for st in structures)
    prior = functions.prior
    draws = [prior.sample((st.n_samples, n_vars), generator) for st in structures]
    if settings.goal_init_share > 0:
        draws = [goal_directed_latents(st, start.cpu(), goal.cpu(), drawn,
                                       (torch.rand(st.n_samples, generator=generator) < settings.goal_init_share
                                        ).nonzero().squeeze(1), generator)
                 for st, drawn in zip(structures, draws, strict=True)]
    x = torch.cat(draws).to(device)
    if warm_start is not None:
        x[0, : warm_start.variables.shape[0]] = warm_start.variables.to(device=device, dtype=x.dtype)
    t_low = torch.tensor(prior.t_low, dtype=x.dtype, device=device)
    t_high = torch.tensor(prior.t_high, dtype=x.dtype, device=device)
    d = prior.latent_dim
    groups = _groups(structures, functions.skills, device)
    final = torch.cat([st.sets[-1] for st in structures]).to(device)
    origin = torch.arange(x.shape[0], device=device)
    adam = RowAdam(x, settings.lr)
    halving = settings.halving_iterations()
    match_rows = match_cols = torch.empty(0)
    work = 0
    for iteration in range(settings.iterations):
        last = iteration == settings.iterations - 1
        rematch = iteration == 0 or last
        n = x.shape[0]
        chunks = _chunks(n, settings.chunk_samples)
        slices = _slices(groups, chunks)
        scores = x.new_empty(n)
        grad = torch.zeros_like(x)
        new_rows, new_cols = [], []
        for (lo, hi), chunk_slices in zip(chunks, slices, strict=True):
            variables = x[lo:hi].detach().requires_grad_(not last)
            with torch.set_grad_enabled(not last):
                pool = torch.cat([start.expand(hi - lo, -1, -1), variables], dim=1)
                match = None if rematch else (match_rows[lo:hi], match_cols[lo:hi])
                score, _, used = _evaluate(functions, pool, groups, chunk_slices, lo, final[lo:hi], goal, settings,
                                           match)
            if not last and score.requires_grad:
                (grad_chunk,) = torch.autograd.grad(-score.sum(), variables, allow_unused=True)
                if grad_chunk is not None:
                    grad[lo:hi] = grad_chunk
            scores[lo:hi] = score.detach()
            if rematch:
                new_rows.append(used[0])
                new_cols.append(used[1])
        work += n
        if rematch:
            match_rows, match_cols = torch.cat(new_rows), torch.cat(new_cols)
        if last:
            break
        adam.step(x, grad)
        x[..., d:] = torch.maximum(torch.minimum(x[..., d:], t_high), t_low)
        n_keep = max(math.ceil(n / 2), min(n, settings.min_survivors))
        if iteration in halving and n_keep < n:
            keep = scores.topk(n_keep).indices.sort().values
            new_position = torch.full((n,), -1, dtype=torch.long, device=device)
            new_position[keep] = torch.arange(keep.shape[0], device=device)
            x, final, origin = x[keep], final[keep], origin[keep]
            match_rows, match_cols = match_rows[keep], match_cols[keep]
            adam.keep_rows(keep)
            groups = [g.keep(new_position) for g in groups]
    best = int(scores.argmax())
    global_row = int(origin[best])
    offsets = [0]
    for st in structures:
        offsets.append(offsets[-1] + st.n_samples)
    sequence_index = max(i for i, o in enumerate(offsets[:-1]) if o <= global_row)
    pool = torch.cat([start, x[best]]).detach()
    return Candidate(structures, sequence_index, global_row - offsets[sequence_index], pool, float(scores[best]), work)
