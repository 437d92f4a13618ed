"""Initial and target configurations: single-skill training problems and multi-skill evaluation problems.

Follows ``env_spec.md`` §1.7, §2 and §2.5 (the official ``core/traj_opt/gen_init_target/*_generator.py``).
Every target is synthetic (no simulation): rigid translations, cuts at an x plane with the pieces
slid apart, volume-preserving flattening and reshaping. Each problem is a *chain* of stages drawn
from one generator; a training problem is one step of a chain, an evaluation problem the whole chain:

=============  ====================================================  ==================================
task           training chain (skill: stage -> stage)                evaluation (horizon)
=============  ====================================================  ==================================
LiftSpread     lift: ball on the spatula -> same ball on the board;  lift, spread (ball on the table ->
               spread: ball on the board -> flat box on the board    flat box on the board)
GatherMove     gather: scattered dough -> pile on the spatula;       gather, move (scattered -> ball
               move: pile on the spatula -> ball on the board        on the board)
CutRearrange   cut: box -> two pieces slid 0.10-0.13 apart;          cut, rearrange, rearrange (box ->
               rearrange: piece A to a; then piece B to b            both pieces at a and b; ids 3i+2)
CRS            cut: box (right end at x 0.9) -> left 0.10-0.12       cut, push, spread (box -> left
               slid -0.1; push: box -> translated; spread: box ->    piece flat at its place, right
               flat box (official ids 0-599)                         piece stays; ids 600-609)
CRS-Twice      as CRS (one model for both)                           the 6-skill version (ids 610-619)
=============  ====================================================  ==================================

Problem ``i`` of ``generate_skill_problems`` has skill ``skill_schedule(cfg)[i]``: the task's cycle
(LiftSpread lift, spread; GatherMove gather, move; CutRearrange cut, rearrange A, rearrange B as
the official ``k mod 3``; CRS cut, push, spread) repeated, so every skill appears as soon as the
count allows.

Where this differs from the official generators, and why:

* **Heights follow our floor.** Our coarse grids rest the dough on ``floor_height(cfg.sim)``
  (0.094 at grid 32, 0.0625 at 48) instead of the official 0.0269. Every piece and target has its
  bottom on the floor (or on the spatula / board top), and tools the official code placed near its
  floor (configured ``y < 0.2``: boards, spatulas, grippers, and the pusher's start height 0.05)
  are raised by ``floor - 0.0269`` (:func:`floor_shift`). Parked tools (knife 0.3, rolling pins
  0.25) are raised only if they would otherwise touch the dough.
* **Flat targets are at least two grid cells thick**: the official height range (CRS
  U(0.016, 0.018), LiftSpread U(0.025, 0.04)) is scaled by ``max(1, 2 dx / low)``
  (:func:`flat_height_range`); the length keeps the volume. LiftSpread balls are then drawn with
  radius >= h / 1.5 so that spreading really flattens them. With ``data.flat_targets: rolled``
  (:func:`flat_width`, the `small` profile) the z-width is the piece's own, so the box lengthens along
  x, the pin's rolling direction, and LiftSpread's box is centred where the lift leaves the ball.
* **Volume-preserving LiftSpread and GatherMove targets** (the official ones were sampled with
  their own sizes and particle counts, env_spec §1.7, §2.2): every target has exactly
  ``cfg.sim.n_particles`` particles, the flat box keeps the ball's volume and the ball on the board
  keeps the pile's. The gathered pile (officially simulated) is an ellipsoid of semi-axes
  (a, 0.7 a, a) on the spatula with the volume of a ball of radius U(0.04, 0.055).
* **CutRearrange rearrange problems hold both pieces**, as the official inits 3i+1 / 3i+2 do: the
  skill acts on one of two entities (``attention``).
* **Sphere on the board rests on it** (the official case1 sphere dipped 0.02 into the board).
* **Tools start 1.5 grid cells clear of the dough** (:func:`tool_clearance`): the pusher's centre is
  ``max(0.02, half thickness + clearance)`` beyond the piece (official 0.02), the knife edge and the
  rolling pin at least that far above it, parked tools raised until clear. Closer, grid nodes
  inside the tool push the dough while it settles (measured: 0.03 slide at grid 32).

``attention`` indexes the entities that :func:`pasta.geometry.entities.label_entities` (with
``cfg.data.dbscan_*``) finds in the *observation* cloud, ``initial.particles[:cfg.sim.observation_points]``,
i.e. what the models see. Every stage is checked: particles inside ``[0.05, 0.95]`` in x and z, at
or above the floor, and different pieces at least 0.03 apart (so DBSCAN with eps 0.03 separates
them). Distractors (``cfg.distractors``) are small boxes on the floor placed clear of every stage of
the chain; they never move.

Randomness: problem ``i`` uses ``np.random.default_rng([seed, stream, i])`` (stream 0 for training,
1 for evaluation), so a problem can be regenerated alone (:func:`skill_problem`) and evaluation
draws never coincide with training ones.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from pasta.config.schema import TaskConfig, ToolConfig
from pasta.data.storage import split_by_configuration
from pasta.geometry.entities import PIECE_GAP, label_entities
from pasta.sim.envs.base import DoughConfiguration, ToolPose, occupied_tool_footprints
from pasta.sim.envs.cut_rearrange import DOUGH_HEIGHT, KNIFE_CLEARANCE, knife_pose_above
from pasta.sim.envs.gather_move import SEED_XZ_HIGH, SEED_XZ_LOW, SEED_Y_SPAN
from pasta.sim.shapes import (
    BoxPiece,
    ScatterPiece,
    SpherePiece,
    cell_middle,
    floor_height,
    place_distractors,
    sample_pieces,
    sample_sphere,
)
from pasta.sim.tool_points import world_sdf

__all__ = [
    "EllipsoidPiece",
    "EvaluationProblem",
    "OracleStep",
    "Stage",
    "SkillProblem",
    "evaluation_problem",
    "evaluation_problems",
    "flat_height_range",
    "knife_plane",
    "floor_shift",
    "generate_skill_problems",
    "oracle_chain",
    "skill_problem",
    "skill_schedule",
    "split_problems",
    "tool_clearance",
]

OFFICIAL_FLOOR_Y = 0.0269     # where the official dough rested (CRS box centre 0.0669 - 0.04)
FLOOR_RELATIVE_Y = 0.2        # configured tool heights below this were given relative to that floor
WORKSPACE = (0.05, 0.95)      # x and z range every particle stays in
MIN_FLAT_CELLS = 2            # flat targets are at least this many grid cells thick
TOOL_CLEARANCE = 0.01         # tools start at least this far from the dough ...
CLEARANCE_CELLS = 1.5         # ... and at least 1.5 cells, so no grid node inside a tool touches it
TRAIN_STREAM, EVAL_STREAM = 0, 1
CUT_LABEL = 100               # piece label of the part a cut creates (then 101, ...)
DISTRACTOR_LABEL = 1000       # piece labels of distractors while a chain is built

# LiftSpread (env_spec §2.1)
LS_RADII = np.linspace(0.04, 0.07, 10)
LS_TABLE_X = 0.65
LS_BOARD_X = (0.32, 0.38)
LS_FLAT_X = (0.25, 0.35)
LS_FLAT_HEIGHT = (0.025, 0.04)
LS_FLAT_WIDTH = 0.16
LS_MIN_FLATTENING = 1.5       # ball radius >= flat height / 1.5 (diameter >= 1.33 h)
# GatherMove (env_spec §2.2)
GM_PILE_RADIUS = (0.04, 0.055)
GM_PILE_SQUASH = 0.7
GM_PILE_XZ = (0.7, 0.5)
GM_BOARD_X = (0.36, 0.40)
# CutRearrange (env_spec §2.3)
CR_LENGTH = (0.2, 0.24)
CR_WIDTH = (0.04, 0.08)
CR_CUT_X = (0.48, 0.52)
CR_SLIDE = (0.10, 0.13)
CR_TARGET_X = (0.3, 0.7)
CR_TARGET_DZ = (0.3, 0.35)
CR_TARGET_MIN_DIST = 0.3
# CRS (env_spec §2.4)
CRS_RIGHT_END_X = 0.9
CRS_CUT_LENGTH = (0.2, 0.35)
CRS_TWICE_LENGTH = (0.34, 0.35)
CRS_WIDTH = (0.06, 0.08)
CRS_PIECE_LENGTH = (0.10, 0.12)
CRS_DZ = 0.2
CRS_TWICE_DZ = 0.15
CRS_SLIDE = 0.1
CRS_PUSH_X = (0.5, 0.65)
CRS_PUSH_TARGET_X = (0.25, 0.30)
CRS_SPREAD_X = (0.22, 0.32)
CRS_FLAT_HEIGHT = (0.016, 0.018)
CRS_FLAT_WIDTH = 0.13
CRS_TWICE_FIRST_CUT = (0.2, 0.24)
CRS_TWICE_SECOND_CUT = 0.11
CRS_TWICE_FLAT_DZ = (0.12, 0.2)  # w + 0.12 < |z1 - z2| < w + 0.2
PUSHER_START_Y = 0.05
PUSHER_OFFSET_X = 0.02        # official: pusher centre 0.02 beyond the dough (face 0.005 away)


# ------------------------------------------------------------------ problems
@dataclass(frozen=True, eq=False)
class SkillProblem:
    """One single-skill training configuration.

    ``initial`` holds the dough particles (P, 3) and every tool's pose, the acting ``tool`` placed
    where the skill starts (env_spec §2.5); its ``target`` is set to ``target``. ``target`` (P, 3)
    float32 read-only, P = ``cfg.sim.n_particles``. ``attention``: the entities of the observation
    cloud ``initial.particles[:cfg.sim.observation_points]``, in ``label_entities`` order, that the
    skill acts on.
    """

    config_id: int
    task: str
    skill: str
    tool: str
    initial: DoughConfiguration
    target: np.ndarray
    attention: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class EvaluationProblem:
    """One multi-skill evaluation configuration; ``skill_sequence`` is the intended solution, and
    ``oracle_chain(cfg, config_id, generator_seed)`` its subgoals."""

    config_id: int
    task: str
    initial: DoughConfiguration
    target: np.ndarray
    skill_sequence: tuple[str, ...]
    generator_seed: int = 1000


@dataclass(frozen=True, eq=False)
class OracleStep:
    """One skill of an evaluation problem's ground-truth chain (the generator's own subgoals).

    ``acted`` ``(N,)`` bool, read-only: the particles of the pieces the skill acts on, by identity (index
    into the initial configuration's particles, which the simulator keeps in order). ``subgoal`` ``(N, 3)``
    float32, read-only: every particle where the chain puts it after the skill.
    """

    skill: str
    acted: np.ndarray
    subgoal: np.ndarray


# --------------------------------------------------------------- geometry
@dataclass(frozen=True)
class EllipsoidPiece:
    """An axis-aligned ellipsoid of dough (the gathered pile): centre and semi-axes."""

    centre: tuple[float, float, float]
    semi_axes: tuple[float, float, float]

    @property
    def volume(self) -> float:
        a, b, c = self.semi_axes
        return 4.0 / 3.0 * math.pi * a * b * c

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.asarray(self.centre), np.asarray(self.semi_axes)
        return c - s, c + s

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        unit = sample_sphere(rng, n, (0.0, 0.0, 0.0), 1.0).astype(np.float64)
        return (np.asarray(self.centre) + unit * np.asarray(self.semi_axes)).astype(np.float32)


def floor_shift(cfg: TaskConfig) -> float:
    """How much higher our floor is than the official one: ``floor_height - 0.0269``."""
    return floor_height(cfg.sim) - OFFICIAL_FLOOR_Y


def flat_height_range(cfg: TaskConfig, low: float, high: float) -> tuple[float, float]:
    """The official flat-target height range ``[low, high]`` scaled by ``max(1, 2 dx / low)``."""
    scale = max(1.0, MIN_FLAT_CELLS / cfg.sim.n_grid / low)
    return low * scale, high * scale


def tool_clearance(cfg: TaskConfig) -> float:
    """How far a tool starts from the dough it should not yet touch: ``max(0.01, 1.5 dx)``.

    A particle reaches grid nodes up to 1.5 cells away; a tool face closer than that holds nodes
    that push the dough while it settles (at grid 32, the official pusher start 0.005 from the
    dough slid the whole piece by 0.03 in 5 zero-action steps).
    """
    return max(TOOL_CLEARANCE, CLEARANCE_CELLS / cfg.sim.n_grid)


class Stage(NamedTuple):
    """A scene: particle positions (N, 3) float64 and the piece label of each particle (N,)."""

    points: np.ndarray
    labels: np.ndarray


Transform = Callable[[Stage, np.random.Generator], Stage]


@dataclass
class _Chain:
    """Pieces of the first stage and the skills that turn each stage into the next.

    ``acted[k]`` are the piece labels (in stage k) that skill k acts on.
    """

    pieces: list
    skills: list[str]
    acted: list[tuple[int, ...]]
    transforms: list[Transform]


def _mask(stage: Stage, label: int) -> np.ndarray:
    mask = stage.labels == label
    if not mask.any():
        raise RuntimeError(f"no particle has piece label {label}")
    return mask


def _translate_to(label: int, x: float | None = None, z: float | None = None,
                  y_bottom: float | None = None) -> Transform:
    """Rigidly move piece ``label`` so its mean x / z (and its bottom y) land where given."""

    def apply(stage: Stage, rng: np.random.Generator) -> Stage:
        mask = _mask(stage, label)
        pts = stage.points.copy()
        piece = pts[mask]
        shift = np.zeros(3)
        if x is not None:
            shift[0] = x - piece[:, 0].mean()
        if z is not None:
            shift[2] = z - piece[:, 2].mean()
        if y_bottom is not None:
            shift[1] = y_bottom - piece[:, 1].min()
        pts[mask] += shift
        return Stage(pts, stage.labels)

    return apply


def _cut(label: int, x_plane: float, new_label: int, move_left: bool, slide: float) -> Transform:
    """Slice piece ``label`` at ``x_plane``: the part x > plane becomes ``new_label``; the left part
    slides by ``-slide`` in x (``move_left``) or the right part by ``+slide``."""

    def apply(stage: Stage, rng: np.random.Generator) -> Stage:
        mask = _mask(stage, label)
        right = mask & (stage.points[:, 0] > x_plane)
        left = mask & ~right
        if not right.any() or not left.any():
            raise RuntimeError(f"cut at x = {x_plane:.3f} leaves one side of piece {label} empty")
        pts, labels = stage.points.copy(), stage.labels.copy()
        labels[right] = new_label
        if move_left:
            pts[left, 0] -= slide
        else:
            pts[right, 0] += slide
        return Stage(pts, labels)

    return apply


def _relabel_left(label: int, x_plane: float, new_label: int, slide: float) -> Transform:
    """Cut piece ``label`` at ``x_plane``; its left part becomes ``new_label`` and slides by -slide."""

    def apply(stage: Stage, rng: np.random.Generator) -> Stage:
        mask = _mask(stage, label)
        left = mask & (stage.points[:, 0] <= x_plane)
        if not left.any() or left.sum() == mask.sum():
            raise RuntimeError(f"cut at x = {x_plane:.3f} leaves one side of piece {label} empty")
        pts, labels = stage.points.copy(), stage.labels.copy()
        labels[left] = new_label
        pts[left, 0] -= slide
        return Stage(pts, labels)

    return apply


def _reshape(label: int, make_piece: Callable[[Stage], object]) -> Transform:
    """Resample piece ``label`` (same particle count) in the piece ``make_piece(stage)`` returns."""

    def apply(stage: Stage, rng: np.random.Generator) -> Stage:
        mask = _mask(stage, label)
        pts = stage.points.copy()
        pts[mask] = make_piece(stage).sample(rng, int(mask.sum()))
        return Stage(pts, stage.labels)

    return apply


def _flat_box(volume: float, height: float, width: float, x: float, z: float, floor: float,
              x_range: tuple[float, float] | None = None) -> BoxPiece:
    """A volume-preserving flat box of ``height`` x ``width`` (z) resting on ``floor``, centred at
    x (clipped into ``x_range`` with a 0.01 margin if given) and z."""
    length = volume / (height * width)
    if x_range is not None:
        lo, hi = x_range[0] + 0.5 * length + 0.01, x_range[1] - 0.5 * length - 0.01
        if lo > hi:
            raise RuntimeError(f"a flat box {length:.3f} long does not fit into x in {x_range}")
        x = float(np.clip(x, lo, hi))
    return BoxPiece(centre=(x, floor + 0.5 * height, z), half_extents=(0.5 * length, 0.5 * height, 0.5 * width))


def _tool(cfg: TaskConfig, name: str) -> ToolConfig:
    return next(t for t in cfg.tools if t.name == name)


def _skill_tool(cfg: TaskConfig, skill: str) -> ToolConfig:
    for s in cfg.skills:
        if s.name == skill:
            return _tool(cfg, s.tool)
    raise ValueError(f"task {cfg.task} has no skill {skill!r}; skills are {[s.name for s in cfg.skills]}")


def _back_pose(cfg: TaskConfig, tool: ToolConfig) -> ToolPose:
    """The configured pose, raised by :func:`floor_shift` if the official code gave it relative to its floor."""
    x, y, z = tool.position
    if y < FLOOR_RELATIVE_Y:
        y += floor_shift(cfg)
    return ToolPose(pos=(x, y, z), rot=tool.rotation, gap=tool.gap)


def _top_y(cfg: TaskConfig, name: str) -> float:
    """Top of a box tool (board, spatula) at its shifted back pose."""
    tool = _tool(cfg, name)
    return _back_pose(cfg, tool).pos[1] + tool.half_extents[1]


# ------------------------------------------------------------------ chains
def _lift_spread_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    floor = floor_height(cfg.sim)
    board = _tool(cfg, "board")
    board_top = _top_y(cfg, "board")
    board_x = (board.position[0] - board.half_extents[0], board.position[0] + board.half_extents[0])
    spatula_top = _top_y(cfg, "spatula")
    h = float(rng.uniform(*flat_height_range(cfg, *LS_FLAT_HEIGHT)))
    radii = LS_RADII[LS_RADII >= h / LS_MIN_FLATTENING]
    r = float(rng.choice(radii if len(radii) else LS_RADII[-1:]))
    x_board = float(rng.uniform(*LS_BOARD_X))
    x_flat = float(rng.uniform(*LS_FLAT_X))
    if cfg.data.flat_targets == "rolled":  # a pin flattens the ball where it lies; it cannot carry it 0.1 along
        x_flat = x_board
    ball = SpherePiece(centre=(LS_TABLE_X, max(floor, spatula_top) + r, 0.5), radius=r)
    flat = _flat_box(ball.volume, h, flat_width(cfg, LS_FLAT_WIDTH, 2 * r), x_flat, 0.5, board_top, board_x)
    return _Chain(
        pieces=[ball],
        skills=["lift", "spread"],
        acted=[(0,), (0,)],
        transforms=[_translate_to(0, x=x_board, z=0.5, y_bottom=board_top), _reshape(0, lambda s: flat)],
    )


def _gather_move_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    floor = floor_height(cfg.sim)
    scatter = ScatterPiece(
        seed_low=(SEED_XZ_LOW[0], floor, SEED_XZ_LOW[1]),
        seed_high=(SEED_XZ_HIGH[0], floor + SEED_Y_SPAN, SEED_XZ_HIGH[1]),
    )
    r = float(rng.uniform(*GM_PILE_RADIUS))
    a = r / GM_PILE_SQUASH ** (1.0 / 3.0)
    b = GM_PILE_SQUASH * a
    pile_x = GM_PILE_XZ[0] + float(rng.uniform(-0.005, 0.005))
    pile_z = GM_PILE_XZ[1] + float(rng.uniform(-0.005, 0.005))
    pile = EllipsoidPiece(centre=(pile_x, _top_y(cfg, "spatula") + b, pile_z), semi_axes=(a, b, a))
    ball = SpherePiece(centre=(float(rng.uniform(*GM_BOARD_X)), _top_y(cfg, "board") + r, 0.5), radius=r)
    return _Chain(
        pieces=[scatter],
        skills=["gather", "move"],
        acted=[(0,), (0,)],
        transforms=[_reshape(0, lambda s: pile), _reshape(0, lambda s: ball)],
    )


def _cut_rearrange_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    floor = floor_height(cfg.sim)
    length, width = float(rng.uniform(*CR_LENGTH)), float(rng.uniform(*CR_WIDTH))
    box = BoxPiece(centre=(0.5, floor + 0.5 * DOUGH_HEIGHT, 0.5),
                   half_extents=(0.5 * length, 0.5 * DOUGH_HEIGHT, 0.5 * width))
    c = knife_plane(cfg, float(rng.uniform(*CR_CUT_X)))
    move_left = bool(rng.random() < 0.5)
    slide = float(rng.uniform(*CR_SLIDE))
    while True:
        xs = rng.uniform(*CR_TARGET_X, size=2)
        zs = 0.5 + rng.choice([-1.0, 1.0], size=2) * rng.uniform(*CR_TARGET_DZ, size=2)
        if math.hypot(xs[0] - xs[1], zs[0] - zs[1]) >= CR_TARGET_MIN_DIST:
            break
    return _Chain(
        pieces=[box],
        skills=["cut", "rearrange", "rearrange"],
        acted=[(0,), (0,), (CUT_LABEL,)],
        transforms=[
            _cut(0, c, CUT_LABEL, move_left, slide),
            _translate_to(0, x=float(xs[0]), z=float(zs[0])),
            _translate_to(CUT_LABEL, x=float(xs[1]), z=float(zs[1])),
        ],
    )


def _crs_box(cfg: TaskConfig, length: float, width: float, x: float, z: float) -> BoxPiece:
    floor = floor_height(cfg.sim)
    return BoxPiece(centre=(x, floor + 0.5 * DOUGH_HEIGHT, z),
                    half_extents=(0.5 * length, 0.5 * DOUGH_HEIGHT, 0.5 * width))


def flat_width(cfg: TaskConfig, official: float, piece: float) -> float:
    """z-width of a flat spread target: the official constant, or (``data.flat_targets: rolled``) the
    piece's own z-width, so that the length along x, the rolling direction, keeps the volume."""
    return official if cfg.data.flat_targets == "official" else piece


def knife_plane(cfg: TaskConfig, x: float) -> float:
    """A generated cut plane: at ``x`` (``data.cut_planes: official``) or in the middle of its grid cell
    (``cell_middle``). The knife separates the dough cleanly only with its mid-plane there (the scripted
    cut moves it there too, :mod:`pasta.data.skills.cut`), so a plane elsewhere puts up to half a cell of
    dough into the other piece of the target."""
    return x if cfg.data.cut_planes == "official" else cell_middle(x, cfg.sim.n_grid)


def _crs_flat(cfg: TaskConfig, rng: np.random.Generator, volume: float, x: float, z: float,
              piece_width: float) -> BoxPiece:
    h = float(rng.uniform(*flat_height_range(cfg, *CRS_FLAT_HEIGHT)))
    return _flat_box(volume, h, flat_width(cfg, CRS_FLAT_WIDTH, piece_width), x, z, floor_height(cfg.sim))


def _crs_cut_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    length, width = float(rng.uniform(*CRS_CUT_LENGTH)), float(rng.uniform(*CRS_WIDTH))
    z = 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    left_end = CRS_RIGHT_END_X - length
    c = knife_plane(cfg, left_end + float(rng.uniform(*CRS_PIECE_LENGTH)))
    return _Chain(
        pieces=[_crs_box(cfg, length, width, left_end + 0.5 * length, z)],
        skills=["cut"], acted=[(0,)],
        transforms=[_cut(0, c, CUT_LABEL, True, CRS_SLIDE)],
    )


def _crs_push_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    length, width = float(rng.uniform(*CRS_PIECE_LENGTH)), float(rng.uniform(*CRS_WIDTH))
    x, z = float(rng.uniform(*CRS_PUSH_X)), 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    xt, zt = float(rng.uniform(*CRS_PUSH_TARGET_X)), 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    return _Chain(pieces=[_crs_box(cfg, length, width, x, z)], skills=["push"], acted=[(0,)],
                  transforms=[_translate_to(0, x=xt, z=zt)])


def _crs_spread_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    length, width = float(rng.uniform(*CRS_PIECE_LENGTH)), float(rng.uniform(*CRS_WIDTH))
    x, z = float(rng.uniform(*CRS_SPREAD_X)), 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    flat = _crs_flat(cfg, rng, length * DOUGH_HEIGHT * width, x, z, width)
    return _Chain(pieces=[_crs_box(cfg, length, width, x, z)], skills=["spread"], acted=[(0,)],
                  transforms=[_reshape(0, lambda s: flat)])


def _crs_eval_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    """Official test ids 600-609: cut the left 0.10-0.12 off, push it to (U(0.22, 0.32), 0.5 +- 0.2)
    and flatten it there; the right piece stays."""
    length, width = float(rng.uniform(*CRS_CUT_LENGTH)), float(rng.uniform(*CRS_WIDTH))
    z = 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    left_end = CRS_RIGHT_END_X - length
    cut_x = knife_plane(cfg, left_end + float(rng.uniform(*CRS_PIECE_LENGTH)))
    xt, zt = float(rng.uniform(*CRS_SPREAD_X)), 0.5 + float(rng.uniform(-CRS_DZ, CRS_DZ))
    flat = _crs_flat(cfg, rng, (cut_x - left_end) * DOUGH_HEIGHT * width, xt, zt, width)
    return _Chain(
        pieces=[_crs_box(cfg, length, width, left_end + 0.5 * length, z)],
        skills=["cut", "push", "spread"],
        acted=[(0,), (0,), (0,)],
        transforms=[
            _cut(0, cut_x, CUT_LABEL, True, CRS_SLIDE),
            _translate_to(0, x=xt, z=zt),
            _reshape(0, lambda s: flat),
        ],
    )


def _crs_twice_eval_chain(cfg: TaskConfig, rng: np.random.Generator) -> _Chain:
    """Official test ids 610-619: a 0.34-0.35 long box; the left 0.11 (A) and the next part up to
    U(0.2, 0.24) from the left end (B) are each cut off, pushed and flattened at x = U(0.22, 0.32),
    z1, z2 in 0.5 +- 0.15 with w + 0.12 < |z1 - z2| < w + 0.2; the rest stays."""
    length, width = float(rng.uniform(*CRS_TWICE_LENGTH)), float(rng.uniform(*CRS_WIDTH))
    z = 0.5 + float(rng.uniform(-CRS_TWICE_DZ, CRS_TWICE_DZ))
    left_end = CRS_RIGHT_END_X - length
    first = knife_plane(cfg, left_end + float(rng.uniform(*CRS_TWICE_FIRST_CUT)))
    second = knife_plane(cfg, left_end + CRS_TWICE_SECOND_CUT)
    while True:
        z1, z2 = 0.5 + rng.uniform(-CRS_TWICE_DZ, CRS_TWICE_DZ, size=2)
        if CRS_FLAT_WIDTH + CRS_TWICE_FLAT_DZ[0] < abs(z1 - z2) < CRS_FLAT_WIDTH + CRS_TWICE_FLAT_DZ[1]:
            break
    x1, x2 = rng.uniform(*CRS_SPREAD_X, size=2)
    flat_a = _crs_flat(cfg, rng, (second - left_end) * DOUGH_HEIGHT * width, float(x1), float(z1), width)
    flat_b = _crs_flat(cfg, rng, (first - second) * DOUGH_HEIGHT * width, float(x2), float(z2), width)
    a, b = 0, CUT_LABEL + 1  # A keeps label 0; the first cut makes the rest CUT_LABEL, the second B
    return _Chain(
        pieces=[_crs_box(cfg, length, width, left_end + 0.5 * length, z)],
        skills=["cut", "push", "spread", "cut", "push", "spread"],
        acted=[(0,), (a,), (a,), (CUT_LABEL,), (b,), (b,)],
        transforms=[
            _cut(0, second, CUT_LABEL, True, CRS_SLIDE),
            _translate_to(a, x=float(x1), z=float(z1)),
            _reshape(a, lambda s: flat_a),
            _relabel_left(CUT_LABEL, first, b, CRS_SLIDE),
            _translate_to(b, x=float(x2), z=float(z2)),
            _reshape(b, lambda s: flat_b),
        ],
    )


# Training schedule per task: (skill, chain builder, step of the chain).
_ChainBuilder = Callable[[TaskConfig, np.random.Generator], _Chain]
_SCHEDULES: dict[str, tuple[tuple[str, _ChainBuilder, int], ...]] = {
    "LiftSpread": (("lift", _lift_spread_chain, 0), ("spread", _lift_spread_chain, 1)),
    "GatherMove": (("gather", _gather_move_chain, 0), ("move", _gather_move_chain, 1)),
    "CutRearrange": (("cut", _cut_rearrange_chain, 0), ("rearrange", _cut_rearrange_chain, 1),
                     ("rearrange", _cut_rearrange_chain, 2)),
    "CRS": (("cut", _crs_cut_chain, 0), ("push", _crs_push_chain, 0), ("spread", _crs_spread_chain, 0)),
}
_SCHEDULES["CRS-Twice"] = _SCHEDULES["CRS"]
_EVAL_CHAINS: dict[str, _ChainBuilder] = {
    "LiftSpread": _lift_spread_chain,
    "GatherMove": _gather_move_chain,
    "CutRearrange": _cut_rearrange_chain,
    "CRS": _crs_eval_chain,
    "CRS-Twice": _crs_twice_eval_chain,
}


def _schedule(cfg: TaskConfig) -> tuple[tuple[str, _ChainBuilder, int], ...]:
    try:
        schedule = _SCHEDULES[cfg.task]
    except KeyError:
        raise ValueError(f"no configuration generator for task {cfg.task!r}; known: {sorted(_SCHEDULES)}") from None
    names = {s.name for s in cfg.skills}
    missing = {skill for skill, _, _ in schedule} - names
    if missing:
        raise ValueError(f"task {cfg.task}: generator skills {sorted(missing)} are not in cfg.skills {sorted(names)}")
    return schedule


def skill_schedule(cfg: TaskConfig) -> tuple[str, ...]:
    """The skill of every training problem id, ``n_train_trajectories + n_test_trajectories`` of
    them (cheap: no particles are sampled)."""
    schedule = _schedule(cfg)
    n = cfg.data.n_train_trajectories + cfg.data.n_test_trajectories
    return tuple(schedule[i % len(schedule)][0] for i in range(n))


# --------------------------------------------------------------- realising
def _sample_stages(cfg: TaskConfig, rng: np.random.Generator, chain: _Chain, n_steps: int) -> list[Stage]:
    """Sample the first stage (main pieces plus distractors) and apply ``n_steps`` transforms."""
    n = cfg.sim.n_particles
    pieces = list(chain.pieces)
    transforms = chain.transforms[:n_steps]
    if cfg.distractors:
        pieces += _place_distractors(cfg, rng, chain.pieces, transforms)
    points, labels = sample_pieces(rng, pieces, n)
    labels = labels.astype(np.int64)
    labels[labels >= len(chain.pieces)] += DISTRACTOR_LABEL - len(chain.pieces)
    stages = [Stage(points.astype(np.float64), labels)]
    for transform in transforms:
        stages.append(transform(stages[-1], rng))
    return stages


def _place_distractors(cfg: TaskConfig, rng: np.random.Generator, main: list, transforms: list[Transform]) -> list:
    """Distractor boxes clear of every main piece at every stage (found on a proxy sample of the
    chain with its own generator) and of the tools near the floor."""
    proxy_rng = np.random.default_rng(0)
    points, labels = sample_pieces(proxy_rng, main, 256 * len(main))
    stages = [Stage(points.astype(np.float64), labels.astype(np.int64))]
    for transform in transforms:
        stages.append(transform(stages[-1], proxy_rng))
    grow = 0.05  # room for tools around a piece (pusher, gripper fingers)
    occupied = []
    for stage in stages:
        for label in np.unique(stage.labels):
            p = stage.points[stage.labels == label][:, [0, 2]]
            occupied.append((p.min(axis=0) - grow, p.max(axis=0) + grow))
    floor = floor_height(cfg.sim)
    poses = {t.name: _back_pose(cfg, t) for t in cfg.tools}
    occupied += occupied_tool_footprints(cfg, poses, below_y=floor + 0.1)
    wall = max(WORKSPACE[0], cfg.sim.boundary_cells / cfg.sim.n_grid) + 0.02
    return place_distractors(rng, cfg.distractors, occupied, floor, sum(p.volume for p in main),
                             region_xz=((wall, wall), (1.0 - wall, 1.0 - wall)))


def _check_stage(cfg: TaskConfig, stage: Stage, what: str) -> None:
    """Every particle inside the workspace and above the floor; different pieces >= 0.03 apart."""
    p = stage.points
    floor = floor_height(cfg.sim)
    lo, hi = WORKSPACE
    if (p[:, [0, 2]] < lo - 1e-9).any() or (p[:, [0, 2]] > hi + 1e-9).any():
        raise RuntimeError(f"{what}: particles leave the workspace [{lo}, {hi}] in x / z "
                           f"(x {p[:, 0].min():.3f}..{p[:, 0].max():.3f}, z {p[:, 2].min():.3f}..{p[:, 2].max():.3f})")
    if p[:, 1].min() < floor - 1e-6 or p[:, 1].max() > 1.0:
        raise RuntimeError(f"{what}: particles below the floor {floor:.4f} or above 1 "
                           f"(y {p[:, 1].min():.4f}..{p[:, 1].max():.4f})")
    labels = np.unique(stage.labels)
    trees = {int(k): cKDTree(p[stage.labels == k]) for k in labels}
    for i, a in enumerate(labels):
        for b in labels[i + 1:]:
            dist, _ = trees[int(b)].query(p[stage.labels == a], k=1, distance_upper_bound=PIECE_GAP)
            if np.isfinite(dist).any():
                raise RuntimeError(f"{what}: pieces {a} and {b} come closer than {PIECE_GAP}")


def _compact(labels: np.ndarray) -> np.ndarray:
    """Piece labels 0..K-1: main and cut pieces first (by label), distractors last."""
    return np.unique(labels, return_inverse=True)[1].astype(np.int32)


def _piece_stats(stage: Stage, labels: Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mask = np.isin(stage.labels, labels)
    piece = stage.points[mask]
    return piece.mean(axis=0), piece.min(axis=0), piece.max(axis=0)


def _start_pose(cfg: TaskConfig, skill: str, tool: ToolConfig, stage: Stage, acted: Sequence[int]) -> ToolPose:
    """Where the acting tool starts (env_spec §2.5)."""
    com, lo, hi = _piece_stats(stage, acted)
    back = _back_pose(cfg, tool)
    if tool.kind == "knife":
        clearance = max(KNIFE_CLEARANCE, tool_clearance(cfg))
        return knife_pose_above(tool, float(com[0]), float(com[2]), float(hi[1]), clearance)
    if tool.kind == "rolling_pin":
        y = max(back.pos[1], tool.lower_bound[1], float(hi[1]) + tool.radius + tool_clearance(cfg))
        return ToolPose(pos=(float(com[0]), y, float(com[2])), rot=tool.rotation)
    if tool.kind == "gripper":
        gap = float(np.clip(tool.gap, tool.min_gap, tool.max_gap))
        return ToolPose(pos=(float(com[0]), back.pos[1], float(com[2])), rot=tool.rotation, gap=gap)
    if skill == "push":
        y = PUSHER_START_Y + floor_shift(cfg)
        x = float(hi[0]) + max(PUSHER_OFFSET_X, tool.half_extents[0] + tool_clearance(cfg))
        return ToolPose(pos=(x, y, float(com[2])), rot=tool.rotation)
    return back  # spatula (lift, move): the dough rests on it at its back pose


def _clear_pose(tool: ToolConfig, pose: ToolPose, points: np.ndarray, clearance: float) -> ToolPose:
    """Raise a parked tool until it keeps ``clearance`` from every particle."""
    x, y, z = pose.pos
    for _ in range(100):
        if world_sdf(tool, points, (x, y, z), pose.rot, pose.gap).min() >= clearance:
            break
        y += 0.02
    else:
        raise RuntimeError(f"tool {tool.name!r} cannot be parked clear of the dough")
    return replace(pose, pos=(x, min(y, tool.upper_bound[1]), z))


def _tool_poses(cfg: TaskConfig, skill: str, stage: Stage, acted: Sequence[int]) -> dict[str, ToolPose]:
    acting = _skill_tool(cfg, skill)
    poses = {}
    for tool in cfg.tools:
        if tool.name == acting.name:
            poses[tool.name] = _start_pose(cfg, skill, tool, stage, acted)
        elif tool.static:
            poses[tool.name] = _back_pose(cfg, tool)
        else:
            poses[tool.name] = _clear_pose(tool, _back_pose(cfg, tool), stage.points, tool_clearance(cfg))
    return poses


def _attention(cfg: TaskConfig, stage: Stage, acted: Sequence[int]) -> tuple[int, ...]:
    """Entities of the observation cloud whose particles mostly belong to the acted pieces."""
    m = cfg.sim.observation_points
    d = cfg.data
    entities = label_entities(stage.points[:m], eps=d.dbscan_eps, min_samples=d.dbscan_min_samples,
                              min_points=d.dbscan_min_points)
    pieces = stage.labels[:m]
    attention = []
    for e in np.unique(entities):
        values, counts = np.unique(pieces[entities == e], return_counts=True)
        if values[np.argmax(counts)] in acted:
            attention.append(int(e))
    if not attention:
        raise RuntimeError(f"DBSCAN finds no entity of the acted pieces {tuple(acted)}")
    return tuple(attention)


def _configuration(stage: Stage, poses: dict[str, ToolPose], target: Stage) -> DoughConfiguration:
    return DoughConfiguration(particles=stage.points.astype(np.float32), tool_poses=poses,
                              target=target.points.astype(np.float32), piece_labels=_compact(stage.labels))


def _read_only(points: np.ndarray) -> np.ndarray:
    arr = np.array(points, dtype=np.float32)
    arr.flags.writeable = False
    return arr


def _rng(seed: int, stream: int, config_id: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), stream, int(config_id)])


# ------------------------------------------------------------------ public
def skill_problem(cfg: TaskConfig, config_id: int, seed: int = 0) -> SkillProblem:
    """Training problem ``config_id`` (0-based) alone; equal to ``generate_skill_problems(cfg, seed)[config_id]``."""
    schedule = _schedule(cfg)
    if config_id < 0:
        raise ValueError(f"config_id must be >= 0, got {config_id}")
    skill, build, step = schedule[config_id % len(schedule)]
    rng = _rng(seed, TRAIN_STREAM, config_id)
    chain = build(cfg, rng)
    stages = _sample_stages(cfg, rng, chain, step + 1)
    what = f"{cfg.task} problem {config_id} ({skill})"
    for k, stage in enumerate(stages):
        _check_stage(cfg, stage, f"{what}, stage {k}")
    initial, target = stages[step], stages[step + 1]
    acted = chain.acted[step]
    poses = _tool_poses(cfg, skill, initial, acted)
    return SkillProblem(
        config_id=int(config_id),
        task=cfg.task,
        skill=skill,
        tool=_skill_tool(cfg, skill).name,
        initial=_configuration(initial, poses, target),
        target=_read_only(target.points),
        attention=_attention(cfg, initial, acted),
    )


def generate_skill_problems(cfg: TaskConfig, seed: int = 0) -> list[SkillProblem]:
    """``n_train_trajectories + n_test_trajectories`` single-skill problems, skills as :func:`skill_schedule`."""
    return [skill_problem(cfg, i, seed) for i in range(len(skill_schedule(cfg)))]


def _evaluation_chain(cfg: TaskConfig, config_id: int, seed: int) -> tuple[_Chain, list[Stage]]:
    """Evaluation problem ``config_id``'s chain and its checked stages (stage 0 = initial, last = target)."""
    try:
        build = _EVAL_CHAINS[cfg.task]
    except KeyError:
        raise ValueError(f"no evaluation generator for task {cfg.task!r}; known: {sorted(_EVAL_CHAINS)}") from None
    rng = _rng(seed, EVAL_STREAM, config_id)
    chain = build(cfg, rng)
    if len(chain.skills) != cfg.horizon:
        raise ValueError(f"{cfg.task}: the evaluation chain has {len(chain.skills)} skills, horizon is {cfg.horizon}")
    stages = _sample_stages(cfg, rng, chain, len(chain.transforms))
    for k, stage in enumerate(stages):
        _check_stage(cfg, stage, f"{cfg.task} evaluation problem {config_id}, stage {k}")
    return chain, stages


def evaluation_problem(cfg: TaskConfig, config_id: int, seed: int = 1000) -> EvaluationProblem:
    """Evaluation problem ``config_id`` alone (a whole chain of ``cfg.horizon`` skills)."""
    chain, stages = _evaluation_chain(cfg, config_id, seed)
    poses = _tool_poses(cfg, chain.skills[0], stages[0], chain.acted[0])
    return EvaluationProblem(
        config_id=int(config_id),
        task=cfg.task,
        initial=_configuration(stages[0], poses, stages[-1]),
        target=_read_only(stages[-1].points),
        skill_sequence=tuple(chain.skills),
        generator_seed=int(seed),
    )


def oracle_chain(cfg: TaskConfig, config_id: int, seed: int = 1000) -> tuple[OracleStep, ...]:
    """The generator's own solution of evaluation problem ``config_id``: per skill, the pieces it acts on
    and the stage it must reach. The last step's ``subgoal`` equals ``evaluation_problem(...).target``."""
    chain, stages = _evaluation_chain(cfg, config_id, seed)
    return tuple(
        OracleStep(skill=skill, acted=_read_only_mask(np.isin(before.labels, acted)), subgoal=_read_only(after.points))
        for skill, acted, before, after in zip(chain.skills, chain.acted, stages[:-1], stages[1:], strict=True)
    )


def _read_only_mask(mask: np.ndarray) -> np.ndarray:
    arr = np.array(mask, dtype=bool)
    arr.flags.writeable = False
    return arr


def evaluation_problems(cfg: TaskConfig, seed: int = 1000) -> list[EvaluationProblem]:
    """``cfg.data.n_eval_configs`` multi-skill problems (draws disjoint from the training ones)."""
    return [evaluation_problem(cfg, i, seed) for i in range(cfg.data.n_eval_configs)]


def split_problems(problems: Sequence[SkillProblem], cfg: TaskConfig, seed: int = 42
                   ) -> tuple[list[SkillProblem], list[SkillProblem]]:
    """Train / test problems by configuration id (:func:`pasta.data.storage.split_by_configuration`,
    test fraction ``n_test / (n_train + n_test)``)."""
    d = cfg.data
    fraction = d.n_test_trajectories / (d.n_train_trajectories + d.n_test_trajectories)
    train_ids, test_ids = split_by_configuration([p.config_id for p in problems], fraction, seed)
    train, test = set(train_ids), set(test_ids)
    return [p for p in problems if p.config_id in train], [p for p in problems if p.config_id in test]
