"""Typed, frozen configuration models.

Every model forbids unknown keys and is immutable once built. Values carry their
units in their names where it matters (``dt_s``, ``yield_stress_pa``). The
numbers of the appendix's Tables 1-3 live in ``conf/tasks/*.yaml``; profiles in
``conf/profiles/*.yaml`` rescale them.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

TASK_NAMES = ("LiftSpread", "GatherMove", "CutRearrange", "CRS", "CRS-Twice")
PROFILE_NAMES = ("smoke", "small", "paper")
# PASTA, its ablations and Flat3D (their switches: pasta/models/variants.py); here so the CLI checks them light.
VARIANT_NAMES = (
    "pasta",
    "no_smoothing_feasibility",
    "shared_encoder_policy",
    "tool_concat_policy",
    "set_without_filtering",
    "flat3d",
)
DEMO_METHODS = ("gbto", "scripted")  # how demonstrations are made (pasta/data/demos.py)
TOOL_KINDS = ("box", "knife", "gripper", "rolling_pin")
PLAN_COSTS = ("learned", "decoded")  # the planner's set cost (PlanConfig.cost)
PLAN_GUARDS = ("none", "reach")  # what keeps planned latents where the networks were trained (PlanConfig.guard)
REACH_VERTICAL = ("absolute", "signed")  # how the reach guard limits vertical displacement (PlanConfig.reach_vertical)
POLICY_ENCODERS = ("pointnet2", "pointnet")  # the policies' point encoder (PolicyNetConfig.encoder)
POLICY_FRAMES = ("world", "dough")  # where the policies' clouds are expressed (PolicyNetConfig.frame)

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


class Frozen(BaseModel):
    """Base: unknown keys are refused and instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class MaterialConfig(Frozen):
    """Dough material (appendix Table 2)."""

    youngs_modulus_pa: float = Field(gt=0)
    poisson_ratio: float = Field(ge=0, lt=0.5)
    yield_stress_pa: float = Field(gt=0)
    ground_friction: float = Field(ge=0)
    density: float = Field(default=1.0, gt=0)


class SimConfig(Frozen):
    """MLS-MPM discretisation.

    ``gravity_m_s2`` is the effective acceleration in unit-cube lengths per s^2.
    The official code multiplied its configured gravity by a hidden factor of
    30 (-20 became -600); here the effective value is written out.
    """

    n_grid: int = Field(ge=8, le=256)
    dt_s: float = Field(gt=0, le=1e-3)
    substeps_per_step: int = Field(ge=1, le=200)
    n_particles: int = Field(ge=16, le=200_000)
    gravity_m_s2: Vec3
    boundary_cells: int = Field(default=3, ge=1, le=8)
    particle_lower_bound_cells: int = Field(default=0, ge=0, le=8)
    contact_softness: float = Field(default=0.0, ge=0)
    optimisation_contact_softness: float = Field(default=666.0, ge=0)
    # Grid nodes inside a tool leave it at this fraction of their depth per substep (each tool may set
    # its own, `tools[].expel_rate`: the spatulas and grippers hold dough only with 0). The official
    # simulator had none (0); at our grids the dough then leaks into the 0.05-thick knife and a cut
    # never separates (docs/simulator.md).
    tool_expel_rate: float = Field(default=0.1, ge=0, le=1)
    # A knife's V edge stops this far below the floor (a cutting board under the dough): the knife's y
    # lower bound becomes floor + blade_depth - this (pasta.sim.engine.stopped_knife). None: no stop.
    knife_floor_depth: float | None = Field(default=None, ge=0)
    arch: Literal["cpu", "cuda", "auto"] = "cpu"
    # How P2G scatters to the grid: "serial" (no float atomics: fixed chunks of particles, each scattered
    # serially into its own grid, the chunks in parallel and summed in a fixed order: bit-reproducible at
    # any thread count), "parallel" (one grid, atomic adds: for a GPU), or "auto": serial on the CPU,
    # parallel on CUDA (docs/simulator.md).
    p2g: Literal["auto", "serial", "parallel"] = "auto"
    # The per-particle 3x3 SVD of every substep: "taichi" (the built-in iterative ti.svd) or "fast"
    # (pasta.sim.svd3: closed-form, about a third of the cost on the CPU). Both share one convention, and
    # the adjoint (MPMSimulator.svd_grad) serves both.
    svd: Literal["taichi", "fast"] = "taichi"
    # Host memory (MiB) a differentiable episode (GBTO) keeps for its backward pass: the substep frames and
    # SVDs of its first steps, as many as fit (about 18 MiB a step at 5000 particles and 15 substeps), so
    # the backward pass restores them instead of recomputing those steps; 0 recomputes every step from its
    # checkpoint (least memory). The gradients are the same bit for bit (pasta.sim.autodiff). Measured on the
    # CPU only: on CUDA the kept frames cross to host memory and back every step, which may cost more
    # than recomputing them there.
    adjoint_memory_mb: float = Field(default=1024, ge=0)
    steps_per_skill: int = Field(default=50, ge=1)
    settle_steps: int = Field(default=10, ge=0)
    observation_points: int = Field(default=1000, ge=1)
    tool_points: int = Field(default=100, ge=1)

    @model_validator(mode="after")
    def _check_observation_points(self) -> SimConfig:
        if self.observation_points > self.n_particles:
            raise ValueError(
                f"observation_points ({self.observation_points}) must be <= n_particles ({self.n_particles})"
            )
        return self


class ToolConfig(Frozen):
    """A rigid tool: an SDF primitive with a pose and an action space.

    Geometry by ``kind``:
      * ``box``: ``half_extents`` (spatula, pusher, static board).
      * ``knife``: ``half_extents`` = (half thickness, top above origin, half width in z),
        ``blade_depth`` = how far the V edge reaches below the origin, ``blade_angle_deg``.
      * ``gripper``: ``half_extents`` of one finger; ``gap``, ``min_gap``, ``max_gap``.
      * ``rolling_pin``: ``radius`` and ``half_length`` of a capsule along its local z.
    ``action_scales`` has one entry per action dimension of the tool (box 6, knife 3,
    gripper 7, rolling_pin 6); actions in [-1, 1] times scale give the per-step motion.
    ``rotation`` is a unit quaternion, w first. ``collides_with`` names the tools this one may not
    pass through (tool-tool collision projection, e.g. spatula vs. cutting board).
    """

    name: str
    kind: Literal["box", "knife", "gripper", "rolling_pin"]
    position: Vec3
    rotation: Quat = (1.0, 0.0, 0.0, 0.0)
    half_extents: Vec3 = (0.0, 0.0, 0.0)
    radius: float = Field(default=0.0, ge=0)
    half_length: float = Field(default=0.0, ge=0)
    blade_depth: float = Field(default=0.0, ge=0)
    blade_angle_deg: float = Field(default=60.0, gt=0, lt=180)
    gap: float = Field(default=0.0, ge=0)
    min_gap: float = Field(default=0.0, ge=0)
    max_gap: float = Field(default=1.0, ge=0)
    action_scales: tuple[float, ...] = ()
    friction: float = Field(default=0.0, ge=0)
    lower_bound: Vec3 = (0.0, 0.0, 0.0)
    upper_bound: Vec3 = (1.0, 1.0, 1.0)
    static: bool = False
    collides_with: tuple[str, ...] = ()
    # Grid nodes inside this tool leave it at this fraction of their depth per substep; None takes
    # ``sim.tool_expel_rate``. The knife needs it to separate dough at coarse grids; a spatula or a
    # gripper with it cannot hold dough (it rides on a frictionless cushion), so theirs is 0.
    expel_rate: float | None = Field(default=None, ge=0, le=1)

    @model_validator(mode="after")
    def _check_geometry(self) -> ToolConfig:
        norm = math.sqrt(sum(c * c for c in self.rotation))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(
                f"tool {self.name!r}: rotation {self.rotation} is not a unit quaternion (norm {norm:.4f})"
            )
        if any(lo > hi for lo, hi in zip(self.lower_bound, self.upper_bound, strict=True)):
            raise ValueError(
                f"tool {self.name!r}: lower_bound {self.lower_bound} exceeds upper_bound {self.upper_bound}"
            )
        if self.kind == "gripper" and not self.min_gap <= self.gap <= self.max_gap:
            raise ValueError(
                f"tool {self.name!r}: gripper gap must satisfy min_gap <= gap <= max_gap, "
                f"got {self.min_gap} <= {self.gap} <= {self.max_gap}"
            )
        return self

    @model_validator(mode="after")
    def _check_action_dims(self) -> ToolConfig:
        expected = {"box": 6, "knife": 3, "gripper": 7, "rolling_pin": 6}[self.kind]
        if self.static:
            if any(self.action_scales):
                raise ValueError(f"tool {self.name!r} is static but has action_scales {self.action_scales}")
        elif len(self.action_scales) != expected:
            raise ValueError(
                f"tool {self.name!r} of kind {self.kind!r} needs {expected} action_scales, "
                f"got {len(self.action_scales)}: {self.action_scales}"
            )
        return self


class SkillConfig(Frozen):
    """A skill: the tool it uses and how many entities it takes and gives.

    ``entities_in`` is one count, or several for a skill that takes any of them (GatherMove's ``gather``
    squeezes however many pieces the scattered dough falls into, ``[1, 2, 3]``, into one). The planner
    and the training data treat each count as its own arity of the same skill: one policy and one set
    feasibility network serve them all.
    """

    name: str
    tool: str
    entities_in: int | tuple[int, ...]
    entities_out: int = Field(ge=1)

    @model_validator(mode="after")
    def _check_counts(self) -> SkillConfig:
        counts = self.input_counts
        if not counts or min(counts) < 1 or list(counts) != sorted(set(counts)):
            raise ValueError(f"skill {self.name!r}: entities_in must be a count >= 1 or increasing distinct "
                             f"counts >= 1, got {self.entities_in}")
        return self

    @property
    def input_counts(self) -> tuple[int, ...]:
        """Every entity count the skill takes, increasing."""
        return (self.entities_in,) if isinstance(self.entities_in, int) else self.entities_in


class DataConfig(Frozen):
    """Dataset sizes (appendix Table 1) at the profile's scale."""

    n_initial_configs: int = Field(ge=1)
    n_target_configs: int = Field(ge=1)
    n_train_trajectories: int = Field(ge=1)
    n_test_trajectories: int = Field(ge=1)
    n_eval_configs: int = Field(default=5, ge=1)
    gbto_iterations: int = Field(ge=0)
    gbto_lr: float = Field(gt=0)
    gbto_velocity_weight: float = Field(ge=0)
    dbscan_eps: float = Field(default=0.03, gt=0)
    dbscan_min_samples: int = Field(default=6, ge=1)
    dbscan_min_points: int = Field(default=10, ge=0)
    # Flat spread targets (LiftSpread, CRS, CRS-Twice): "official" keeps the official z-width (0.16,
    # 0.13); "rolled" takes the piece's own z-width, so the length along x (the rolling direction)
    # keeps the volume (pasta.data.configurations.flat_width).
    flat_targets: Literal["official", "rolled"] = "official"
    # Cut planes of the generated targets (CutRearrange, CRS, CRS-Twice): "official" where drawn;
    # "cell_middle" moved to the middle of their grid cell, the only place a knife cuts cleanly on the
    # simulator's grid (pasta.data.configurations.knife_plane).
    cut_planes: Literal["official", "cell_middle"] = "official"
    # Where a cut's knife is placed before the skill (pasta.data.skills.cut.cut_start), in demonstrations and
    # evaluation alike: "centre" over the attended dough's centre of mass (the official reset pose); "cut"
    # over the subgoal's split, so the skill, scripted or learned, starts by going down.
    knife_start: Literal["centre", "cut"] = "centre"
    # Rollouts of each scripted demonstration's aim search (pasta.data.aim_search): the skill is run with up
    # to this many aims of its destination from the same state, and the one ending nearest its subgoal is
    # recorded. 1: the script alone, as the official heuristics.
    aim_search_rollouts: int = Field(default=1, ge=1)


class TrainConfig(Frozen):
    """Training values (appendix Table 3 and section 1.5)."""

    vae_lr: float = Field(gt=0)
    latent_dim: int = Field(ge=1)
    # Whether the VAE's decoder also reads the entity centre's height (pasta.models.vae.VAEConfig.height_input):
    # dough rests on the floor, so a piece's centre height tells its thickness. False (the appendix's): the
    # decoder reads z alone.
    vae_height_input: bool = False
    feasibility_lr: float = Field(gt=0)
    feasibility_batch_size: int = Field(ge=1)
    feasibility_sigma_z: float = Field(ge=0)
    feasibility_sigma_t: float = Field(ge=0)
    cost_lr: float = Field(gt=0)
    cost_batch_size: int = Field(ge=1)
    policy_lr: float = Field(gt=0)
    policy_batch_size: int = Field(ge=1)
    policy_point_noise: float = Field(ge=0)
    lambda_policy: float = Field(default=1.0, ge=0)
    lambda_feasibility: float = Field(default=10.0, ge=0)
    lambda_cost: float = Field(default=1.0, ge=0)
    vae_epochs: int = Field(ge=1)
    epochs: int = Field(ge=1)
    # The policies train in a loop of their own (pasta/train/policy_loop.py), not in the feasibility and
    # cost epochs: policy_steps gradient steps per skill (batches of policy_batch_size), the learning rate
    # following policy_lr_schedule from policy_lr, the held-out action MSE measured every
    # policy_eval_every steps (the best weights are kept) and a skill stopped after policy_patience
    # evaluations in a row without a new best (None: never early).
    policy_steps: int = Field(ge=1)
    policy_lr_schedule: Literal["cosine", "constant"] = "cosine"
    policy_eval_every: int = Field(ge=1)
    policy_patience: int | None = Field(default=None, ge=1)
    # Mirror augmentation of the point-cloud set policy's training samples (pasta/train/mirror.py): "x": each
    # sample reflected at random in the vertical plane x = c_x through the observed dough's centre, or not;
    # "xz": at random in x, in z, in both or not at all; its actions' signs flipped to match. The tools are
    # symmetric and the skills act alike on a mirrored scene, so a reflected demonstration is another one.
    # "none" (the appendix's training): no reflection.
    policy_mirror: Literal["none", "x", "xz"] = "none"
    # How many times as often as any other step each demonstration's first step is drawn for the policies'
    # batches. A skill's first step holds its approach (the knife's move to the cut's x is one step of 50),
    # which decides where the skill acts; drawn uniformly it is one sample in 50. 1: uniform (the appendix's).
    policy_first_step_weight: int = Field(default=1, ge=1)
    # Share of policy samples (training and held-out) whose goal is a later state of the same demonstration
    # (hindsight relabelling) instead of its target. Official 0.5 (model_spec §4); a hindsight goal taken
    # before a cut separates the pieces does not show where the cut goes, so the first steps' labels are
    # unpredictable from it.
    policy_hindsight_ratio: float = Field(default=0.5, ge=0.0, le=1.0)
    # Share of the feasibility positives whose goal is the demonstration's target instead of a later state of the
    # same demonstration. The planner plans towards targets (the test goal is one, as is every stage of the
    # generator's chain), but the official positives pair observed states only (model_spec §2.3) and a scripted
    # skill stops short of its target: trained for 60 epochs, CRS's networks scored the generator's own chain at
    # 0.003-0.09 per step (docs/planning.md, "Feasibility that knows the targets"). 0: hindsight goals only.
    feasibility_target_share: float = Field(default=0.0, ge=0.0, le=1.0)
    # Entity filtering (appendix 1.5) drops every observed entity within the filter's Chamfer of a goal entity.
    # A skill that changes its one entity a little (a spread whose target is 0.0002 in squared Chamfer from its
    # start, 9 of LiftSpread's 20 small spreads) then leaves nothing, and the sample is dropped from the
    # feasibility positives and the policy samples alike. True: keep the observed entity farthest from its
    # nearest goal entity, and that goal entity. False (the official): drop the sample.
    filter_keeps_acted: bool = False
    # Share of the policies' training samples whose goal cloud is the VAE's reconstruction of the goal entities
    # (each entity encoded and decoded, as many points per entity) instead of their observed points. A learned
    # plan hands the policy executor decoded subgoals, smoother and weighted per entity rather than per mass;
    # the held-out samples keep the observed goals. 0: observed goals only (the appendix's training).
    policy_decoded_goal_share: float = Field(default=0.0, ge=0.0, le=1.0)
    # DAgger rounds after the policies' own loop (pasta/train/dagger.py; 0: none, the appendix's behaviour
    # cloning alone): each runs the oracle chains of dagger_problems fresh problems with the current policies
    # (the expert's action chunk instead at a share dagger_expert_share of the calls), labels every visited
    # step with the scripted skill tracked from the tool's pose, and trains the policies dagger_steps more
    # steps from dagger_lr (policy_lr_schedule) on the demonstrations and all visits so far.
    dagger_rounds: int = Field(default=0, ge=0)
    dagger_problems: int = Field(default=20, ge=1)
    dagger_expert_share: float = Field(default=0.3, ge=0, le=1)
    dagger_steps: int = Field(default=200, ge=1)
    dagger_lr: float = Field(default=5e-4, gt=0)
    # The forward passes of VAE and policy training: "fp32", or "bf16" autocast (float32 weights, bfloat16
    # matrix products; pasta/train/precision.py). The heads are small enough that fp32 costs nothing.
    precision: Literal["fp32", "bf16"] = "fp32"


class PlanConfig(Frozen):
    """Planning values (appendix Table 3)."""

    lr: float = Field(gt=0)
    iterations: int = Field(ge=1)
    samples: int = Field(ge=1)
    receding_horizon: int | None = Field(default=None, ge=1)
    # Receding-horizon planning only: one sample of each window after the first continues the previous window's
    # best plan (pasta.plan.receding). The official code starts every window afresh.
    receding_warm_start: bool = False
    # Planning horizon when it differs from the task's (the CRS horizon sweep, appendix Table 8);
    # the evaluation problems keep the task's own horizon.
    horizon: int | None = Field(default=None, ge=1, le=8)
    # The set cost of the objective: "learned" is the appendix's cost predictor; "decoded" is the Chamfer
    # distance between the entities' decoded clouds, on cost_points points each (pasta.plan.decoded_cost).
    cost: Literal[PLAN_COSTS] = "learned"
    cost_points: int = Field(default=64, ge=1)
    # Weight of the set cost in the objective; None: the official code's (10 for CutRearrange, 100 otherwise,
    # model_spec §5.4).
    alpha: float | None = Field(default=None, ge=0)
    # A step's feasibility counts as at least this in the objective's log (keeps it finite). Below it the step
    # has no gradient: with networks trained to sharp verdicts most of the planner's random samples start there
    # and never move (CRS at small with 60 head epochs: the ground truth scored above the chosen plan in 13 of 15
    # evaluations, docs/planning.md "Feasibility that knows the targets"). The feasibility is a sigmoid, so a tiny
    # floor keeps the gradient out of infeasible regions. 0.01: the earlier planner's.
    feasibility_floor: float = Field(default=0.01, gt=0, lt=1)
    # "reach": each skill's outputs are kept within the displacement from its inputs, per axis, that its training
    # transitions span (pasta.plan.reach), the factor falling to exp(-1) at reach_softness beyond it; "none": the
    # appendix.
    guard: Literal[PLAN_GUARDS] = "none"
    reach_softness: float = Field(default=0.02, gt=0)
    # "tool": a skill whose tool moves along x and z is limited in horizontal distance (by the larger of its x and
    # z reach) and in y; the others per axis. "axes": every skill per axis.
    reach_frame: Literal["axes", "tool"] = "tool"
    # "absolute": |d_y| limited by the largest |d_y| of the training transitions; "signed": d_y kept between their
    # lowest and highest d_y (a spread must lower its piece as its demonstrations did: pasta.plan.reach).
    reach_vertical: Literal[REACH_VERTICAL] = "absolute"
    # The share of planner samples whose new vectors start on paths from the observed entities to the goal's
    # (pasta.plan.goal_init); the appendix draws every sample from the prior (0).
    goal_init_share: float = Field(default=0.0, ge=0, le=1)
    # True: each skill's input entities are kept within the shapes (VAE z) its training transitions started
    # from, the factor falling to exp(-1) at input_shape_softness beyond them (pasta.plan.input_shapes); the
    # appendix has no such guard (False).
    input_shape_guard: bool = False
    input_shape_softness: float = Field(default=0.05, gt=0)


class PolicyNetConfig(Frozen):
    """The policies' architecture (their sizes: ``pasta.models.PolicyConfig``; docs/models.md).

    ``encoder``: ``pointnet2``, the appendix's PointNet++ over the role-tagged union of the observation, tool
    and goal clouds; or ``pointnet``, a compact PointNet per cloud, max-pooled and concatenated, about 25x
    fewer operations per training step. The tool-concat ablation follows the choice; the latent-set policy
    has no point encoder. ``frame``, ``phase_input``, ``previous_action``, ``chunk``, ``shape_quantiles`` and
    ``gap_features`` shape the set policy (PASTA's) only: the two policy ablations of Table 5 keep the appendix's
    inputs and one action per call. ``members`` applies to every variant's policies alike.
    """

    encoder: Literal[POLICY_ENCODERS] = "pointnet2"
    # Where the clouds are expressed: "world" (the appendix's), or "dough": shifted so that the observed
    # dough's horizontal centre is the origin, with the tool's and the goal's centre offsets from it given to
    # the action head (pasta.models.policy.dough_frame).
    frame: Literal[POLICY_FRAMES] = "world"
    # Whether the set policy also reads the skill's phase, step / steps_per_skill (the appendix's does not).
    phase_input: bool = False
    # Whether the set policy also reads the action applied at the previous step (zeros at a skill's first step):
    # the direction a tool is travelling in, which its clouds do not show (a rolling pin mid-stroke). False
    # (the appendix's): not given.
    previous_action: bool = False
    # Actions the set policy predicts per call (action chunking): the executor acts the chunk out and asks
    # again after that many steps; training fits every step of the chunk. 1 (the appendix's): one per step.
    chunk: int = Field(default=1, ge=1)
    # How the executor acts chunks out: "open" acts each chunk to its end before asking again; "ensemble"
    # asks at every step and acts the weighted mean of every chunk's prediction for that step (temporal
    # ensembling: Zhao et al., 2023), a prediction made k steps ago weighted exp(-ensemble_decay k).
    chunk_execution: Literal["open", "ensemble"] = "open"
    ensemble_decay: float = 0.0
    # Coordinate quantiles per axis of the observation and goal clouds (in the policy's frame) given to the
    # set policy's action head beside the pooled features: where a piece begins and ends, and where the
    # goal's gap lies, as numbers rather than as max-pooled features. 0 (the appendix's): none; otherwise at
    # least 2 (the minimum and the maximum, and evenly spaced levels between).
    shape_quantiles: int = Field(default=0, ge=0)
    # The widest gap per axis of the observation and goal clouds (its two ends relative to the tool's centre,
    # and whether it is at least DBSCAN's 0.03 wide) given to the set policy's action head: where a cut's goal
    # splits, as numbers (pasta.models.policy.cloud_gaps). False (the appendix's): not given.
    gap_features: bool = False
    # Points of the observation and goal clouds a policy sees, in training and in execution (each cloud
    # resampled to this many; the tool keeps its surface points). [S] §3.1: 1000.
    points: int = Field(default=1000, ge=8)
    # Skills whose set policy works in its goal's heading frame: the clouds turned about the vertical axis so
    # that the goal lies along +x from the observed dough, the tool's horizontal action vectors turned back
    # (pasta.models.policy.SetPolicy), so that a push in any direction is one push. Only skills whose tool is
    # a box or a gripper moving along x and z; a named skill the task does not have is left alone (profiles
    # serve every task). Empty (the appendix's): none.
    heading_skills: tuple[Literal["cut", "push", "rearrange", "spread", "lift", "move", "gather"], ...] = ()
    # Policies per skill (every variant's kind), each trained on its own loss from its own initial weights,
    # executed as the mean of their actions (pasta.models.policy_ensemble). 1 (the appendix's): one per skill.
    members: int = Field(default=1, ge=1)

    @model_validator(mode="after")
    def _check_quantiles(self) -> PolicyNetConfig:
        if self.shape_quantiles == 1:
            raise ValueError("policy.shape_quantiles = 1: give 0 (none) or at least 2 (the minimum and the maximum)")
        return self


DecodedEntityWeights = Literal["volume", "carried", "equal"]
PolicyActionRange = Literal["unit", "demonstrated"]
FinalSubgoals = Literal["planned", "goal"]


class EvalConfig(Frozen):
    """Evaluation values."""

    success_threshold: float = Field(gt=0, lt=1)
    seeds: tuple[int, ...] = (0, 1, 2)
    # Skills the policy executor leaves to the scripted skills (a diagnostic: with the oracle plan, which
    # skill's policy loses the score); empty: every skill runs its policy.
    scripted_skills: tuple[str, ...] = ()
    # Rollouts of each scripted skill's aim search when the scripted skills execute a plan (pasta.data.aim_search;
    # with the oracle plan each rollout is followed by the plan's remaining skills and scored on the goal).
    # 1: the scripts alone.
    aim_search_rollouts: int = Field(default=1, ge=1)
    # How a decoded latent set becomes one cloud for the EMDs of planned goals and subgoals: "volume", each
    # entity holding its convex hull's share of the points (the dough's particles all weigh the same);
    # "carried", each holding the mass the plan carried to it from the observation (a step hands its attended
    # entities' mass to its new ones, split by decoded volume only where it makes several: pasta.evaluate.plan_masses);
    # "equal", the entities stacked at the decoder's M points each, as the official decoding stacks them,
    # which on CRS's uneven cuts alone puts the goal's own pieces 0.013-0.099 from the goal.
    decoded_entity_weights: DecodedEntityWeights = "volume"
    # The box a policy's actions are clipped to: "unit", the environment's [-1, 1] (the official executor);
    # "demonstrated", also the lowest and highest value of each action dimension over the skill's training
    # demonstrations (pasta.train.action_range; kept in the bundle), so a policy cannot ask for a motion no
    # demonstration made.
    policy_action_range: PolicyActionRange = "unit"
    # What a learned plan hands a step's new entities that no later step attends: "planned", their decoded
    # latents (the official executor); "goal", the observed goal piece their planned centre is matched to
    # (points and latent; pasta.evaluate.goal_subgoals), so the entities the plan finishes aim at the goal itself
    # rather than at the VAE's decoding of it; a step's other new entities then share the dough those pieces leave.
    final_subgoals: FinalSubgoals = "planned"


class TaskConfig(Frozen):
    """One task at one profile: everything a run needs, logged whole to MLflow."""

    task: Literal["LiftSpread", "GatherMove", "CutRearrange", "CRS", "CRS-Twice"]
    profile: Literal["smoke", "small", "paper"]
    horizon: int = Field(ge=1)
    distractors: int = Field(default=0, ge=0, le=8)
    material: MaterialConfig
    sim: SimConfig
    tools: tuple[ToolConfig, ...]
    skills: tuple[SkillConfig, ...]
    data: DataConfig
    train: TrainConfig
    policy: PolicyNetConfig = PolicyNetConfig()
    plan: PlanConfig
    eval: EvalConfig

    @model_validator(mode="after")
    def _check_references(self) -> TaskConfig:
        tool_names = [t.name for t in self.tools]
        if len(set(tool_names)) != len(tool_names):
            raise ValueError(f"tool names must be unique, got {tool_names}")
        static = {t.name for t in self.tools if t.static}
        for skill in self.skills:
            if skill.tool not in tool_names:
                raise ValueError(f"skill {skill.name!r} names tool {skill.tool!r}; tools are {tool_names}")
            if skill.tool in static:
                raise ValueError(f"skill {skill.name!r} uses static tool {skill.tool!r}; it cannot move")
        tools = {t.name: t for t in self.tools}
        for skill in self.skills:
            tool = tools[skill.tool]
            if skill.name in self.policy.heading_skills and not (
                    tool.kind in ("box", "gripper") and tool.action_scales[0] > 0 and tool.action_scales[2] > 0):
                raise ValueError(f"policy.heading_skills names {skill.name!r}, whose tool {tool.name!r} ({tool.kind}, "
                                 f"action scales {tool.action_scales}) does not move along x and z as a box or a "
                                 f"gripper does")
        unknown = sorted(set(self.eval.scripted_skills) - {s.name for s in self.skills})
        if unknown:
            raise ValueError(f"eval.scripted_skills names {unknown}; the task's skills are "
                             f"{[s.name for s in self.skills]}")
        for tool in self.tools:
            for other in tool.collides_with:
                if other not in tool_names or other == tool.name:
                    raise ValueError(
                        f"tool {tool.name!r} collides_with {other!r}; must be another tool of {tool_names}"
                    )
        if self.plan.receding_horizon is not None and self.plan.receding_horizon > self.horizon:
            raise ValueError(
                f"plan.receding_horizon ({self.plan.receding_horizon}) must be <= horizon ({self.horizon})"
            )
        return self
