"""Build ``PlanningFunctions`` from a ``TrainedModels`` bundle, with its parameters frozen while planning."""

from __future__ import annotations

from collections.abc import Collection, Iterator, Sequence
from contextlib import contextmanager
from functools import cache

import torch

from pasta.config import load
from pasta.models.variants import variant_spec
from pasta.plan.decoded_cost import decoded_chamfer_cost
from pasta.plan.functions import PlanningFunctions
from pasta.plan.input_shapes import input_shape_penalty, sum_penalties
from pasta.plan.reach import reach_penalty
from pasta.plan.sequences import SkillSpec
from pasta.plan.settings import COSTS, GUARDS, REACH_VERTICAL, PlanSettings
from pasta.train.bundle import TrainedModels

__all__ = ["bundle_functions", "bundle_skills", "frozen_parameters", "settings_functions"]


@cache
def _task_skills(task: str) -> tuple[SkillSpec, ...]:
    # Skills do not depend on the profile; "smoke" is the cheapest to resolve. One spec per arity.
    return tuple(SkillSpec(s.name, n_in, s.entities_out) for s in load(task, "smoke").skills for n_in in s.input_counts)


def bundle_skills(bundle: TrainedModels) -> tuple[SkillSpec, ...]:
    """The bundle's skills with the task config's entity counts, one spec per arity, in ``bundle.skill_names``
    order (1 -> 1 for whole-scene variants)."""
    specs: dict[str, list[SkillSpec]] = {}
    for spec in _task_skills(bundle.task):
        specs.setdefault(spec.name, []).append(spec)
    missing = [name for name in bundle.skill_names if name not in specs]
    if missing:
        raise KeyError(f"skills {missing} of the {bundle.task} bundle are not in the task config ({sorted(specs)})")
    if variant_spec(bundle.variant).whole_scene_latent:
        return tuple(SkillSpec(name, 1, 1) for name in bundle.skill_names)
    return tuple(spec for name in bundle.skill_names for spec in specs[name])


def bundle_functions(bundle: TrainedModels, skills: Sequence[SkillSpec] | None = None, *, cost: str = "learned",
                     cost_points: int = 64, guard: str = "none", reach_softness: float = 0.02,
                     planar_skills: Collection[str] = (), reach_vertical: str = "absolute",
                     input_shape_guard: bool = False, input_shape_softness: float = 0.05) -> PlanningFunctions:
    """Feasibility and pair cost from the bundle's networks (on whatever device they are).

    Args:
        bundle: trained (or untrained) models.
        cost: ``"learned"``, the bundle's cost predictor, or ``"decoded"``, the Chamfer distance between
            the VAE's decoded clouds on ``cost_points`` points (:func:`pasta.plan.decoded_cost.decoded_chamfer_cost`).
        skills: entity counts per skill (one spec per arity) in ``bundle.skill_names`` order; default
            ``bundle_skills(bundle)``.
        guard: ``"reach"`` penalises each step by the bundle's reach (:func:`pasta.plan.reach.reach_penalty` with
            ``reach_softness``); ``"none"``: no penalty.
        planar_skills: the skills whose reach guard limits the horizontal distance as one (their tool moves
            along x and z); the others are limited along each axis.
        reach_vertical: ``"absolute"`` limits ``|d_y|`` by the reach; ``"signed"`` keeps ``d_y`` within the
            bundle's ``vertical_range``.
        input_shape_guard: also penalise inputs unlike the skill's training inputs
            (:func:`pasta.plan.input_shapes.input_shape_penalty` with ``input_shape_softness``).
    """
    specs = tuple(skills) if skills is not None else bundle_skills(bundle)
    names = tuple(dict.fromkeys(s.name for s in specs))
    if names != bundle.skill_names:
        raise ValueError(f"skills {list(names)} must match the bundle's {list(bundle.skill_names)}")
    networks = [bundle.feasibility(spec.name) for spec in specs]  # the arities of a skill share its network
    if cost not in COSTS:
        raise ValueError(f"cost must be one of {list(COSTS)}, got {cost!r}")
    pair_cost = bundle.cost if cost == "learned" else decoded_chamfer_cost(bundle.vae, cost_points)

    def feasibility(skill: int, inputs: torch.Tensor, outputs: torch.Tensor) -> torch.Tensor:
        return networks[skill](inputs, outputs)

    if guard not in GUARDS:
        raise ValueError(f"guard must be one of {list(GUARDS)}, got {guard!r}")
    penalty = None
    if guard == "reach":
        if bundle.reach is None:
            raise ValueError(f"plan.guard=reach needs the skills' reach, which this {bundle.task} bundle was trained "
                             "without; train it again (`pasta train` resumes and measures it) or plan with "
                             "plan.guard=none")
        if reach_vertical not in REACH_VERTICAL:
            raise ValueError(f"reach_vertical must be one of {list(REACH_VERTICAL)}, got {reach_vertical!r}")
        if reach_vertical == "signed" and bundle.vertical_range is None:
            raise ValueError(f"plan.reach_vertical=signed needs the skills' vertical range, which this {bundle.task} "
                             "bundle was trained without; train it again (`pasta train` resumes and measures it)")
        reach = [bundle.reach[bundle.skill_index(spec.name)] for spec in specs]
        vertical = None if reach_vertical == "absolute" else [
            bundle.vertical_range[bundle.skill_index(spec.name)] for spec in specs]  # type: ignore[index]
        penalty = reach_penalty(reach, bundle.prior.latent_dim, reach_softness,
                                [spec.name in planar_skills for spec in specs], vertical)
    shape_penalty = None
    if input_shape_guard:
        if bundle.input_shapes is None:
            raise ValueError(f"plan.input_shape_guard needs the skills' training input shapes, which this "
                             f"{bundle.task} bundle was trained without; train it again (`pasta train` resumes and "
                             "keeps them) or plan with plan.input_shape_guard=false")
        shapes = [torch.tensor(bundle.input_shapes[bundle.skill_index(spec.name)], dtype=torch.float32)
                  .reshape(-1, bundle.prior.latent_dim) for spec in specs]
        shape_penalty = input_shape_penalty(shapes, bundle.prior.latent_dim, input_shape_softness)
    return PlanningFunctions(specs, bundle.prior, feasibility, pair_cost, sum_penalties([penalty, shape_penalty]))


def settings_functions(bundle: TrainedModels, settings: PlanSettings) -> PlanningFunctions:
    """:func:`bundle_functions` with the cost and guard of ``settings``."""
    return bundle_functions(bundle, cost=settings.cost, cost_points=settings.cost_points, guard=settings.guard,
                            reach_softness=settings.reach_softness, planar_skills=settings.planar_skills,
                            reach_vertical=settings.reach_vertical, input_shape_guard=settings.input_shape_guard,
                            input_shape_softness=settings.input_shape_softness)


@contextmanager
def frozen_parameters(bundle: TrainedModels) -> Iterator[None]:
    """Eval mode and ``requires_grad=False`` on the feasibility and cost networks, restored afterwards.

    Autograd then computes only input gradients, about a third less work than with weight gradients.
    """
    modules = [bundle.cost, *(bundle.feasibility(name) for name in bundle.skill_names)]
    params = [p for m in modules for p in m.parameters()]
    flags = [p.requires_grad for p in params]
    modes = [m.training for m in modules]
    try:
        for p in params:
            p.requires_grad_(False)
        for m in modules:
            m.eval()
        yield
    finally:
        for p, flag in zip(params, flags, strict=True):
            p.requires_grad_(flag)
        for m, mode in zip(modules, modes, strict=True):
            m.train(mode)
