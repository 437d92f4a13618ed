"""``PlanSettings``: the optimiser's knobs, from the task config or by hand."""

from __future__ import annotations

from dataclasses import dataclass

from pasta.config.schema import PLAN_COSTS as COSTS
from pasta.config.schema import PLAN_GUARDS as GUARDS
from pasta.config.schema import REACH_VERTICAL, TaskConfig
from pasta.plan.reach import planar_skills

__all__ = ["COSTS", "DEFAULT_HALVING", "GUARDS", "REACH_VERTICAL", "PlanSettings"]

# Fractions of the iterations after which the worse half of the surviving samples is dropped
# (successive halving; see docs/planning.md for the measurements behind this choice).
DEFAULT_HALVING = (0.03, 0.06, 0.12, 0.25, 0.5)


@dataclass(frozen=True)
class PlanSettings:
    """How the latent planner optimises.

    Attributes:
        lr: Adam learning rate (Table 3: 0.01).
        iterations: objective evaluations per sample; Adam steps after all but the last.
        samples: samples (attention structure + initialisation) per skill sequence.
        alpha: weight of the predicted set cost in the objective (model_spec §5.4: 10 CutRearrange, else 100).
        feasibility_floor: feasibilities below this count as this (keeps the log finite).
        seed: seeds the attention structures and the initial latents.
        halving: fractions of ``iterations`` after which the worse half of the surviving samples is dropped;
            ``()`` optimises every sample to the end (the exhaustive planner).
        min_survivors: halving never leaves fewer samples than this (or than there are).
        chunk_samples: samples evaluated per forward/backward pass (bounds memory; results do not depend on it
            beyond floating-point summation order).
        cost: ``"learned"`` (the bundle's cost predictor, the appendix's choice) or ``"decoded"`` (Chamfer
            distance between decoded entity clouds, :mod:`pasta.plan.decoded_cost`).
        cost_points: points per decoded entity with the decoded cost.
        guard: ``"none"`` or ``"reach"`` (each skill's outputs kept within its training reach,
            :mod:`pasta.plan.reach`).
        reach_softness: how far beyond the reach the guard's factor falls to ``exp(-1)``.
        planar_skills: the skills whose reach guard limits the horizontal distance as one, not x and z apart
            (:func:`pasta.plan.reach.planar_skills`).
        reach_vertical: ``"absolute"`` or ``"signed"`` (:func:`pasta.plan.reach.reach_penalty`).
        goal_init_share: the share of samples whose new vectors start on paths from the observed entities to
            the goal's (:mod:`pasta.plan.goal_init`); the rest are drawn from the prior (the appendix: 0).
        input_shape_guard: whether each skill's inputs are kept within its training inputs' shapes
            (:mod:`pasta.plan.input_shapes`), with ``input_shape_softness``.
    """

    lr: float
    iterations: int
    samples: int
    alpha: float
    feasibility_floor: float = 0.01
    seed: int = 0
    halving: tuple[float, ...] = ()
    min_survivors: int = 64
    chunk_samples: int = 8192
    cost: str = "learned"
    cost_points: int = 64
    guard: str = "none"
    reach_softness: float = 0.02
    planar_skills: frozenset[str] = frozenset()
    reach_vertical: str = "absolute"
    goal_init_share: float = 0.0
    input_shape_guard: bool = False
    input_shape_softness: float = 0.05

    def __post_init__(self) -> None:
        if self.lr <= 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {self.iterations}")
        if self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples}")
        if self.alpha < 0:
            raise ValueError(f"alpha must be >= 0, got {self.alpha}")
        if not 0 < self.feasibility_floor < 1:
            raise ValueError(f"feasibility_floor must be in (0, 1), got {self.feasibility_floor}")
        if any(not 0 < f < 1 for f in self.halving) or list(self.halving) != sorted(set(self.halving)):
            raise ValueError(f"halving must be increasing fractions in (0, 1), got {self.halving}")
        if self.min_survivors < 1:
            raise ValueError(f"min_survivors must be >= 1, got {self.min_survivors}")
        if self.chunk_samples < 1:
            raise ValueError(f"chunk_samples must be >= 1, got {self.chunk_samples}")
        if self.cost not in COSTS:
            raise ValueError(f"cost must be one of {list(COSTS)}, got {self.cost!r}")
        if self.cost_points < 1:
            raise ValueError(f"cost_points must be >= 1, got {self.cost_points}")
        if self.guard not in GUARDS:
            raise ValueError(f"guard must be one of {list(GUARDS)}, got {self.guard!r}")
        if self.reach_softness <= 0:
            raise ValueError(f"reach_softness must be > 0, got {self.reach_softness}")
        if self.input_shape_softness <= 0:
            raise ValueError(f"input_shape_softness must be > 0, got {self.input_shape_softness}")
        if not 0 <= self.goal_init_share <= 1:
            raise ValueError(f"goal_init_share must be in [0, 1], got {self.goal_init_share}")
        if self.reach_vertical not in REACH_VERTICAL:
            raise ValueError(f"reach_vertical must be one of {list(REACH_VERTICAL)}, got {self.reach_vertical!r}")

    @classmethod
    def from_config(cls, cfg: TaskConfig, *, halving: tuple[float, ...] = DEFAULT_HALVING, seed: int = 0
                    ) -> PlanSettings:
        """Table 3's lr, iterations, samples and ``cfg.plan``'s cost and feasibility floor; ``cfg.plan.alpha``, by
        default the official code's 10 for CutRearrange and 100 otherwise; with ``cfg.plan.reach_frame`` ``"tool"``,
        the skills whose tool moves along x and z are guarded in the horizontal plane."""
        alpha = cfg.plan.alpha if cfg.plan.alpha is not None else 10.0 if cfg.task == "CutRearrange" else 100.0
        return cls(lr=cfg.plan.lr, iterations=cfg.plan.iterations, samples=cfg.plan.samples,
                   alpha=alpha, seed=seed, halving=halving, feasibility_floor=cfg.plan.feasibility_floor,
                   cost=cfg.plan.cost, cost_points=cfg.plan.cost_points, guard=cfg.plan.guard,
                   reach_softness=cfg.plan.reach_softness, reach_vertical=cfg.plan.reach_vertical,
                   goal_init_share=cfg.plan.goal_init_share, input_shape_guard=cfg.plan.input_shape_guard,
                   input_shape_softness=cfg.plan.input_shape_softness,
                   planar_skills=planar_skills(cfg) if cfg.plan.reach_frame == "tool" else frozenset())

    def halving_iterations(self) -> frozenset[int]:
        """Iterations (0-based) after whose step the worse half is dropped; never the last one."""
        steps = {max(1, round(f * self.iterations)) for f in self.halving}
        return frozenset(i - 1 for i in steps if i < self.iterations - 1)
