"""Configuration generators: counts, determinism, geometry, entities and tool placement (smoke profile)."""

from __future__ import annotations

import math
from collections import Counter
from functools import cache

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pasta import config
from pasta.config.schema import TASK_NAMES
from pasta.data.configurations import (
    CRS_FLAT_HEIGHT,
    CRS_FLAT_WIDTH,
    WORKSPACE,
    evaluation_problem,
    evaluation_problems,
    flat_height_range,
    floor_shift,
    generate_skill_problems,
    oracle_chain,
    skill_problem,
    skill_schedule,
    split_problems,
    tool_clearance,
)
from pasta.data.storage import split_by_configuration
from pasta.geometry.entities import PIECE_GAP, label_entities
from pasta.sim.shapes import floor_height
from pasta.sim.tool_points import world_sdf

# (initial, target) entity counts of a single-skill problem; None: any number (scattered dough).
EXPECTED_ENTITIES = {
    ("LiftSpread", "lift"): (1, 1),
    ("LiftSpread", "spread"): (1, 1),
    ("GatherMove", "gather"): (None, 1),
    ("GatherMove", "move"): (1, 1),
    ("CutRearrange", "cut"): (1, 2),
    ("CutRearrange", "rearrange"): (2, 2),  # both pieces present, as the official inits 3i+1, 3i+2
    ("CRS", "cut"): (1, 2),
    ("CRS", "push"): (1, 1),
    ("CRS", "spread"): (1, 1),
    ("CRS-Twice", "cut"): (1, 2),
    ("CRS-Twice", "push"): (1, 1),
    ("CRS-Twice", "spread"): (1, 1),
}
EVAL_SEQUENCES = {
    "LiftSpread": ("lift", "spread"),
    "GatherMove": ("gather", "move"),
    "CutRearrange": ("cut", "rearrange", "rearrange"),
    "CRS": ("cut", "push", "spread"),
    "CRS-Twice": ("cut", "push", "spread", "cut", "push", "spread"),
}
EVAL_TARGET_PIECES = {"LiftSpread": 1, "GatherMove": 1, "CutRearrange": 2, "CRS": 2, "CRS-Twice": 3}


@cache
def cfg_of(task: str, profile: str = "smoke"):
    return config.load(task, profile)


@cache
def problems_of(task: str, seed: int = 0):
    return tuple(generate_skill_problems(cfg_of(task), seed))


@cache
def eval_problems_of(task: str):
    return tuple(evaluation_problems(cfg_of(task)))


def entities(cfg, points: np.ndarray) -> np.ndarray:
    d = cfg.data
    return label_entities(points, eps=d.dbscan_eps, min_samples=d.dbscan_min_samples, min_points=d.dbscan_min_points)


def n_entities(cfg, points: np.ndarray) -> int:
    return len(np.unique(entities(cfg, points)))


def attended_points(cfg, problem) -> np.ndarray:
    obs = problem.initial.particles[: cfg.sim.observation_points]
    return obs[np.isin(entities(cfg, obs), problem.attention)]


def bbox_volume(points: np.ndarray) -> float:
    return float(np.prod(points.max(axis=0) - points.min(axis=0)))


def ellipsoid_volume(points: np.ndarray, iterations: int = 2000) -> float:
    """Volume of the smallest ellipsoid around ``points`` (Khachiyan's algorithm, then scaled to enclose them all).

    For points uniform in an ellipsoid this is its maximum-likelihood estimate: within 1 % at 1000 points,
    where the bounding box of a ball misses 5 to 10 % of its volume.
    """
    p = np.asarray(points, np.float64)
    n, d = p.shape
    q = np.hstack([p, np.ones((n, 1))])
    u = np.full(n, 1.0 / n)
    for _ in range(iterations):
        m = np.einsum("ij,ij->i", q @ np.linalg.inv(q.T @ (u[:, None] * q)), q)
        j = int(np.argmax(m))
        step = (m[j] - d - 1) / ((d + 1) * (m[j] - 1))
        new = (1 - step) * u
        new[j] += step
        converged = np.linalg.norm(new - u) < 1e-6
        u = new
        if converged:
            break
    centred = p - u @ p
    shape = np.linalg.inv(centred.T @ (u[:, None] * centred))
    scale = np.einsum("ij,jk,ik->i", centred, shape, centred).max()  # x^T (shape / scale) x <= 1 for every point
    return float(4.0 / 3.0 * np.pi * np.sqrt(scale**d / np.linalg.det(shape)))


# ------------------------------------------------------------------ counts
@pytest.mark.parametrize("task", TASK_NAMES)
def test_smoke_count_ids_and_every_skill(task):
    cfg = cfg_of(task)
    problems = problems_of(task)
    assert len(problems) == cfg.data.n_train_trajectories + cfg.data.n_test_trajectories
    assert [p.config_id for p in problems] == list(range(len(problems)))
    assert {p.skill for p in problems} == {s.name for s in cfg.skills}
    tools = {s.name: s.tool for s in cfg.skills}
    for p in problems:
        assert p.task == task and p.tool == tools[p.skill]
        assert p.target.shape == (cfg.sim.n_particles, 3) and p.target.dtype == np.float32
        assert p.initial.particles.shape == (cfg.sim.n_particles, 3)
        assert not p.target.flags.writeable
        assert set(p.initial.tool_poses) == {t.name for t in cfg.tools}
        np.testing.assert_array_equal(p.initial.target, p.target)
    assert [p.skill for p in problems] == list(skill_schedule(cfg))


@pytest.mark.parametrize("profile", ["smoke", "small", "paper"])
@pytest.mark.parametrize("task", TASK_NAMES)
def test_schedule_counts_at_every_profile(task, profile):
    cfg = cfg_of(task, profile)
    schedule = skill_schedule(cfg)
    assert len(schedule) == cfg.data.n_train_trajectories + cfg.data.n_test_trajectories
    assert set(schedule) == {s.name for s in cfg.skills}
    counts = Counter(schedule)
    if profile == "paper":
        expected_total = {"LiftSpread": 2000, "GatherMove": 2000, "CutRearrange": 1500, "CRS": 1200, "CRS-Twice": 1200}
        assert len(schedule) == expected_total[task]
        if task == "CutRearrange":  # official: knife for k mod 3 == 0, gripper otherwise
            assert counts == {"cut": 500, "rearrange": 1000}
        else:
            assert max(counts.values()) - min(counts.values()) <= 1


def test_small_profile_generates_its_count():
    cfg = cfg_of("CRS", "small")
    problems = generate_skill_problems(cfg)
    assert len(problems) == 120 and Counter(p.skill for p in problems) == {"cut": 40, "push": 40, "spread": 40}
    assert all(p.initial.particles.shape == (5000, 3) for p in problems)


# ------------------------------------------------------------ determinism
@pytest.mark.parametrize("task", TASK_NAMES)
def test_seeded_determinism_and_single_regeneration(task):
    cfg = cfg_of(task)
    problems = problems_of(task)
    again = generate_skill_problems(cfg, seed=0)
    other = problems_of(task, seed=1)
    for a, b, c in zip(problems, again, other, strict=True):
        np.testing.assert_array_equal(a.initial.particles, b.initial.particles)
        np.testing.assert_array_equal(a.target, b.target)
        assert dict(a.initial.tool_poses) == dict(b.initial.tool_poses)
        assert a.attention == b.attention
        assert not np.array_equal(a.initial.particles, c.initial.particles)
        assert not np.array_equal(a.target, c.target)
    for i in (len(problems) - 1, 0):
        alone = skill_problem(cfg, i, seed=0)
        ref = problems[i]
        assert (alone.config_id, alone.skill, alone.tool, alone.attention) == (ref.config_id, ref.skill, ref.tool,
                                                                                ref.attention)
        np.testing.assert_array_equal(alone.initial.particles, ref.initial.particles)
        np.testing.assert_array_equal(alone.initial.piece_labels, ref.initial.piece_labels)
        np.testing.assert_array_equal(alone.target, ref.target)
        assert dict(alone.initial.tool_poses) == dict(ref.initial.tool_poses)


def test_evaluation_draws_are_seeded_and_disjoint_from_training():
    cfg = cfg_of("CRS")
    a, b = eval_problems_of("CRS")[0], evaluation_problem(cfg, 0)
    np.testing.assert_array_equal(a.initial.particles, b.initial.particles)
    np.testing.assert_array_equal(a.target, b.target)
    assert not np.array_equal(evaluation_problem(cfg, 0, seed=1001).target, a.target)
    # the same seed value in the training stream draws something else
    assert not np.array_equal(evaluation_problem(cfg, 0, seed=0).initial.particles,
                              skill_problem(cfg, 0, seed=0).initial.particles)


# ---------------------------------------------------------------- geometry
def assert_in_workspace(cfg, points: np.ndarray, what: str) -> None:
    floor = floor_height(cfg.sim)
    assert np.isfinite(points).all(), what
    assert (points >= 0).all() and (points <= 1).all(), what
    assert points[:, 1].min() >= floor - 1e-6, f"{what}: below the floor {floor}"
    xz = points[:, [0, 2]]
    assert xz.min() >= WORKSPACE[0] - 1e-6 and xz.max() <= WORKSPACE[1] + 1e-6, what


def min_gap_between_pieces(points: np.ndarray, labels: np.ndarray) -> float:
    gaps = [np.inf]
    ids = np.unique(labels)
    for i, a in enumerate(ids):
        for b in ids[i + 1:]:
            dist, _ = cKDTree(points[labels == b]).query(points[labels == a], k=1)
            gaps.append(float(dist.min()))
    return min(gaps)


@pytest.mark.parametrize("task", TASK_NAMES)
def test_particles_inside_workspace_and_above_floor(task):
    cfg = cfg_of(task)
    for p in problems_of(task):
        assert_in_workspace(cfg, p.initial.particles, f"problem {p.config_id} initial")
        assert_in_workspace(cfg, p.target, f"problem {p.config_id} target")
        assert min_gap_between_pieces(p.initial.particles, p.initial.piece_labels) >= PIECE_GAP
    for e in eval_problems_of(task):
        assert_in_workspace(cfg, e.initial.particles, f"eval {e.config_id} initial")
        assert_in_workspace(cfg, e.target, f"eval {e.config_id} target")


@pytest.mark.parametrize("task", TASK_NAMES)
def test_entity_counts_and_attention(task):
    cfg = cfg_of(task)
    m = cfg.sim.observation_points
    for p in problems_of(task):
        n_init, n_target = EXPECTED_ENTITIES[(task, p.skill)]
        obs = p.initial.particles[:m]
        labels = entities(cfg, obs)
        found = len(np.unique(labels))
        if n_init is not None:
            assert found == n_entities(cfg, p.initial.particles) == n_init, (p.config_id, p.skill)
            assert len(p.attention) == 1
        else:
            assert found >= 1 and p.attention == tuple(range(found))
        assert n_entities(cfg, p.target) == n_entities(cfg, p.target[:m]) == n_target, (p.config_id, p.skill)
        assert all(0 <= a < found for a in p.attention)
        # the attended entities change; the others stay where they are
        moved = np.linalg.norm(p.target[:m] - obs, axis=1)
        for e in np.unique(labels):
            change = moved[labels == e].mean()
            if e in p.attention:
                assert change > 0.02, (p.config_id, p.skill, e)
            else:
                assert change == 0.0, (p.config_id, p.skill, e)


@pytest.mark.parametrize("task", TASK_NAMES)
def test_evaluation_problems(task):
    cfg = cfg_of(task)
    problems = eval_problems_of(task)
    assert len(problems) == cfg.data.n_eval_configs == 5
    assert [e.config_id for e in problems] == list(range(5))
    flat_max = flat_height_range(cfg, *CRS_FLAT_HEIGHT)[1]
    for e in problems:
        assert e.task == task and e.skill_sequence == EVAL_SEQUENCES[task]
        assert len(e.skill_sequence) == cfg.horizon
        assert e.target.shape == (cfg.sim.n_particles, 3)
        if task != "GatherMove":
            assert n_entities(cfg, e.initial.particles) == 1
        labels = entities(cfg, e.target)
        assert len(np.unique(labels)) == EVAL_TARGET_PIECES[task]
        if task.startswith("CRS"):
            pieces = [e.target[labels == k] for k in np.unique(labels)]
            heights = sorted(float(np.ptp(piece[:, 1])) for piece in pieces)
            n_flat = 1 if task == "CRS" else 2
            assert all(h <= flat_max + 1e-4 for h in heights[:n_flat]), heights
            assert heights[n_flat] == pytest.approx(0.08, abs=2e-3)  # the remaining piece keeps its height
            widths = sorted(float(np.ptp(piece[:, 2])) for piece in pieces)
            assert widths[-n_flat:] == pytest.approx([CRS_FLAT_WIDTH] * n_flat, abs=3e-3)


@pytest.mark.parametrize("task", TASK_NAMES)
def test_oracle_chain_reproduces_the_stored_problem(task):
    """The oracle's chain starts at the problem's particles, ends exactly at its target, runs its skill sequence,
    and each step moves acted particles only (CRS's cut acts on the whole piece and slides only its left part)."""
    cfg = cfg_of(task)
    for e in eval_problems_of(task)[:2]:
        chain = oracle_chain(cfg, e.config_id)
        assert tuple(step.skill for step in chain) == e.skill_sequence
        np.testing.assert_array_equal(chain[-1].subgoal, e.target)
        before = np.asarray(e.initial.particles, np.float64)
        for step in chain:
            assert step.acted.shape == (cfg.sim.n_particles,) and step.acted.any()
            assert not step.acted.flags.writeable and not step.subgoal.flags.writeable
            moved = np.linalg.norm(step.subgoal - before, axis=1) > 1e-6
            assert moved[step.acted].mean() > 0.2, (e.config_id, step.skill)
            assert not moved[~step.acted].any(), (e.config_id, step.skill)
            before = step.subgoal


@pytest.mark.parametrize("profile", ["smoke", "small", "paper"])
def test_flat_targets_are_two_cells_thick(profile):
    cfg = cfg_of("CRS", profile)
    low, high = flat_height_range(cfg, *CRS_FLAT_HEIGHT)
    assert low >= 2.0 / cfg.sim.n_grid - 1e-12 and high / low == pytest.approx(0.018 / 0.016)
    if profile == "smoke":
        spread = next(p for p in problems_of("CRS") if p.skill == "spread")
        assert low - 1e-4 <= float(np.ptp(spread.target[:, 1])) <= high + 1e-4


@pytest.mark.parametrize("task", ["LiftSpread", "CRS"])
def test_rolled_flat_targets_keep_the_piece_width_and_lengthen_along_x(task):
    """``data.flat_targets: rolled``: the flat target is as wide in z as the piece, keeps its volume in its
    length along x, and (LiftSpread) lies where the lift left the ball; "official" keeps the official width."""
    rolled = config.load(task, "smoke", ["data.flat_targets=rolled"])
    checked = 0
    for config_id, skill in enumerate(skill_schedule(rolled)):
        if skill != "spread":
            continue
        problem, official = skill_problem(rolled, config_id), skill_problem(cfg_of(task), config_id)
        piece, flat = attended_points(rolled, problem), np.asarray(problem.target)
        np.testing.assert_array_equal(problem.initial.particles, official.initial.particles)
        assert np.ptp(flat[:, 2]) == pytest.approx(np.ptp(piece[:, 2]), abs=0.01), config_id
        assert np.ptp(flat[:, 1]) == pytest.approx(np.ptp(official.target[:, 1]), rel=1e-3)  # same height draw
        # longer along the rolling direction, by as much as it is narrower in z
        widths = np.ptp(official.target[:, 2]) / np.ptp(flat[:, 2])
        assert widths > 1.1 and np.ptp(flat[:, 0]) == pytest.approx(np.ptp(official.target[:, 0]) * widths, rel=0.03)
        if task == "LiftSpread":
            assert flat[:, 0].mean() == pytest.approx(piece[:, 0].mean(), abs=3e-3)
            assert bbox_volume(flat) == pytest.approx(ellipsoid_volume(piece), rel=0.02)
            assert np.ptp(official.target[:, 2]) == pytest.approx(0.16, abs=3e-3)
        else:
            assert bbox_volume(flat) == pytest.approx(bbox_volume(piece), rel=0.02)
            assert np.ptp(official.target[:, 2]) == pytest.approx(CRS_FLAT_WIDTH, abs=3e-3)
        checked += 1
    assert checked >= 1


def test_flattening_and_reshaping_preserve_volume():
    checked = 0
    for task in ("LiftSpread", "GatherMove", "CRS", "CRS-Twice"):
        for p in problems_of(task):
            if p.skill not in ("spread", "move"):
                continue
            src = attended_points(cfg_of(task), p)
            # boxes (CRS pieces, every flat target): the bounding box; balls and piles: the enclosing ellipsoid
            source = bbox_volume(src) if task.startswith("CRS") else ellipsoid_volume(src)
            target = ellipsoid_volume(p.target) if p.skill == "move" else bbox_volume(p.target)
            assert target == pytest.approx(source, rel=0.02), (task, p.config_id)  # measured within 0.9 %
            checked += 1
    assert checked >= 4


def test_cut_targets_slide_the_pieces_apart():
    for task, slide in (("CutRearrange", (0.1, 0.13)), ("CRS", (0.1, 0.1))):
        cfg = cfg_of(task)
        for p in problems_of(task):
            if p.skill != "cut":
                continue
            labels = entities(cfg, p.target)
            pieces = sorted((p.target[labels == k] for k in np.unique(labels)), key=lambda q: q[:, 0].min())
            gap = pieces[1][:, 0].min() - pieces[0][:, 0].max()
            assert slide[0] - 0.005 <= gap <= slide[1] + 0.005
            assert len(p.target) == len(p.initial.particles)


# ------------------------------------------------------------ tool placement
@pytest.mark.parametrize("task", TASK_NAMES)
def test_tools_start_clear_of_the_dough_and_next_to_the_piece(task):
    cfg = cfg_of(task)
    tools = {t.name: t for t in cfg.tools}
    clearance = tool_clearance(cfg)
    assert clearance >= 1.5 / cfg.sim.n_grid
    for p in problems_of(task):
        x = p.initial.particles
        for name, pose in p.initial.tool_poses.items():
            sdf = world_sdf(tools[name], x, pose.pos, pose.rot, pose.gap)
            # supports (board, spatula) and the gripper around the dough may come close; the others
            # keep 1.5 cells, so no grid node inside them pushes the dough while it settles
            close = tools[name].static or name == "spatula" or (name == p.tool and tools[name].kind == "gripper")
            assert sdf.min() >= (-1e-5 if close else clearance - 1e-6), (p.config_id, p.skill, name, float(sdf.min()))
        tool, pose = tools[p.tool], p.initial.tool_poses[p.tool]
        piece = attended_points(cfg, p)
        com, lo, hi = piece.mean(axis=0), piece.min(axis=0), piece.max(axis=0)
        px, py, pz = pose.pos
        if tool.kind == "knife":
            assert abs(px - com[0]) < 0.01 and abs(pz - com[2]) < 0.01
            assert py - tool.blade_depth > hi[1]  # the edge is above the dough
        elif tool.kind == "rolling_pin":
            assert abs(px - com[0]) < 0.01 and abs(pz - com[2]) < 0.01
            assert py - tool.radius > hi[1]
        elif tool.kind == "gripper":
            assert abs(px - com[0]) < 0.02 and abs(pz - com[2]) < 0.02
            inner = 0.5 * pose.gap - tool.half_extents[0]  # fingers' inner faces, along world z
            assert lo[2] > pz - inner and hi[2] < pz + inner
        elif p.skill == "push":
            assert px - tool.half_extents[0] >= hi[0] + clearance and abs(pz - com[2]) < 0.01
            assert px - hi[0] < tool.half_extents[0] + clearance + 0.03  # but not far
            assert py - tool.half_extents[1] < lo[1] and py + tool.half_extents[1] > lo[1] + 0.05
        else:  # spatula under the dough
            top = py + tool.half_extents[1]
            assert abs(lo[1] - top) < 0.005
            assert abs(com[0] - px) < tool.half_extents[0] and abs(com[2] - pz) < tool.half_extents[2]


def test_supports_follow_the_floor():
    """Board and spatula are raised with the floor; the ball rests on the board top (LiftSpread)."""
    cfg = cfg_of("LiftSpread")
    board = next(t for t in cfg.tools if t.name == "board")
    shift = floor_shift(cfg)
    assert shift == pytest.approx(floor_height(cfg.sim) - 0.0269)
    for p in problems_of("LiftSpread"):
        pose = p.initial.tool_poses["board"]
        assert pose.pos[1] == pytest.approx(board.position[1] + shift)
        board_top = pose.pos[1] + board.half_extents[1]
        on_board = p.target if p.skill == "lift" else p.initial.particles
        assert on_board[:, 1].min() == pytest.approx(board_top, abs=5e-3)
        assert on_board[:, 0].min() >= board.position[0] - board.half_extents[0]
        assert on_board[:, 0].max() <= board.position[0] + board.half_extents[0]


# ------------------------------------------------------------------- split
def test_split_by_configuration_id():
    cfg = cfg_of("LiftSpread")
    problems = list(problems_of("LiftSpread"))
    train, test = split_problems(problems, cfg)
    assert len(train) == cfg.data.n_train_trajectories and len(test) == cfg.data.n_test_trajectories
    ids_train, ids_test = {p.config_id for p in train}, {p.config_id for p in test}
    assert not ids_train & ids_test and ids_train | ids_test == {p.config_id for p in problems}
    assert (sorted(ids_train), sorted(ids_test)) == split_by_configuration(range(5), 0.2, seed=42)
    again = split_problems(problems, cfg)
    assert [p.config_id for p in again[1]] == [p.config_id for p in test]
    other = {tuple(p.config_id for p in split_problems(problems, cfg, seed=s)[1]) for s in range(10)}
    assert len(other) > 1


def cut_faces(cfg, config_id: int) -> list[float]:
    """x of the cut face of the piece that stays put, for every cut of evaluation problem ``config_id``."""
    chain = oracle_chain(cfg, config_id)
    faces = []
    before = evaluation_problem(cfg, config_id).initial.particles
    for step in chain:
        if step.skill == "cut":
            kept = step.acted & np.all(np.isclose(step.subgoal, before, atol=1e-6), axis=1)
            moving = step.acted & ~kept
            right_stays = step.subgoal[kept, 0].mean() > step.subgoal[moving, 0].mean()
            faces.append(float(step.subgoal[kept, 0].min() if right_stays else step.subgoal[kept, 0].max()))
        before = step.subgoal
    return faces


@pytest.mark.parametrize("task", ["CutRearrange", "CRS", "CRS-Twice"])
def test_cell_middle_cut_planes_sit_mid_cell_and_the_cut_pieces_keep_their_volume(task):
    """``data.cut_planes: cell_middle`` (small): every cut plane moves by at most half a grid cell, to the
    middle of one (the staying piece's cut face lies there), and a flattened CRS piece keeps the volume of
    the piece actually cut off."""
    moved = config.load(task, "smoke", ["data.cut_planes=cell_middle"])
    dx = 1.0 / moved.sim.n_grid
    for config_id in range(3):
        for face, official in zip(cut_faces(moved, config_id), cut_faces(cfg_of(task), config_id), strict=True):
            assert abs(face - (math.floor(official / dx) + 0.5) * dx) < 0.004, (config_id, face, official)
    if task == "CRS":
        for problem in generate_skill_problems(moved):
            if problem.skill == "spread":
                assert bbox_volume(problem.target) == pytest.approx(
                    bbox_volume(attended_points(moved, problem)), rel=0.02)
        chain = oracle_chain(moved, 0)
        cut_off = chain[0].subgoal[chain[1].acted]
        assert bbox_volume(chain[2].subgoal[chain[2].acted]) == pytest.approx(bbox_volume(cut_off), rel=0.03)
