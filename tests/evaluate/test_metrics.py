"""Scores against slow references: EMD by enumerating assignments, means by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pasta.evaluate.metrics import planned_goal_distance, shape_distance, summary_metrics


def brute_force_emd(a: np.ndarray, b: np.ndarray) -> float:
    """Mean matched distance, minimised over every one-to-one assignment."""
    return min(float(np.mean([np.linalg.norm(a[i] - b[j]) for i, j in enumerate(perm)]))
               for perm in itertools.permutations(range(len(b))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_planned_goal_distance_stacks_the_entities_and_matches_the_slow_emd(seed):
    rng = np.random.default_rng(seed)
    decoded = rng.uniform(size=(2, 3, 3))  # two decoded entities of 3 points
    goal = rng.uniform(size=(6, 3))
    expected = brute_force_emd(decoded.reshape(-1, 3), goal)
    assert planned_goal_distance(decoded, goal, seed, weights="equal") == pytest.approx(expected, rel=1e-9)


def test_planned_goal_distance_subsamples_the_larger_cloud():
    rng = np.random.default_rng(4)
    goal = rng.uniform(size=(5, 3))
    decoded = np.stack([goal, goal + 10.0])  # 10 points, 5 of them exactly on the goal
    distance = planned_goal_distance(decoded, goal, seed=0, weights="equal")
    reference = np.random.default_rng(0).choice(10, 5, replace=False)
    assert distance == pytest.approx(brute_force_emd(decoded.reshape(-1, 3)[reference], goal), rel=1e-9)


def _box(rng: np.random.Generator, low, size, n: int) -> np.ndarray:
    return np.asarray(low) + rng.uniform(size=(n, 3)) * np.asarray(size)


def _block_and_sheet(sheet_height: float) -> tuple[np.ndarray, np.ndarray]:
    """A CRS-like goal ``(1000, 3)``: a block and a flat sheet with a quarter of its volume, particles of equal
    mass; and its two pieces decoded ``(2, 1000, 3)``, the sheet ``sheet_height`` thick."""
    rng = np.random.default_rng(0)
    block = _box(rng, (0.2, 0.0, 0.4), (0.1, 0.08, 0.1), 800)
    sheet = _box(rng, (0.6, 0.0, 0.4), (0.2, 0.01, 0.1), 200)
    decoded = np.stack([_box(rng, (0.2, 0.0, 0.4), (0.1, 0.08, 0.1), 1000),
                        _box(rng, (0.6, 0.0, 0.4), (0.2, sheet_height, 0.1), 1000)])
    return np.concatenate([block, sheet]), decoded


def test_a_goal_of_uneven_pieces_comes_back_close_only_when_each_piece_keeps_its_share_of_the_mass():
    goal, decoded = _block_and_sheet(0.01)
    weighted = planned_goal_distance(decoded, goal, seed=0)
    stacked = planned_goal_distance(decoded, goal, seed=0, weights="equal")
    assert stacked > 0.1  # 30 % of the mass sent 0.45 across
    assert weighted < 0.02


def test_carried_masses_put_the_flat_sheet_back_to_its_share_where_its_volume_would_not():
    # The decoder made the sheet as thick as the block: its hull holds 2 / 3 of the volume instead of 1 / 5.
    goal, decoded = _block_and_sheet(0.08)
    by_volume = planned_goal_distance(decoded, goal, seed=0)
    carried = planned_goal_distance(decoded, goal, seed=0, weights="carried", masses=np.array([0.8, 0.2]))
    assert by_volume > 0.1
    assert carried < by_volume / 2
    with pytest.raises(ValueError, match="masses"):
        planned_goal_distance(decoded, goal, seed=0, weights="carried")


def test_planned_goal_distance_rejects_an_unknown_weighting():
    with pytest.raises(ValueError, match="'mass'"):
        planned_goal_distance(np.zeros((1, 4, 3)), np.zeros((4, 3)), seed=0, weights="mass")


def test_shape_distance_is_the_slow_emd_against_the_first_target_points():
    rng = np.random.default_rng(5)
    points = rng.uniform(size=(6, 3))
    target = rng.uniform(size=(9, 3))  # the target holds every particle; the first 6 are compared
    assert shape_distance(points, target, 0) == pytest.approx(brute_force_emd(points, target[:6]), rel=1e-9)


def test_summary_metrics_uses_the_contract_names():
    rows = [
        {"config_id": 0, "performance": 0.9, "success": True, "planning_time_s": 2.0, "emd_planned_goal": 0.1,
         "emd_reached_goal": 0.02, "emd_initial": 0.3},
        {"config_id": 1, "performance": 0.5, "success": False, "planning_time_s": 4.0, "emd_planned_goal": 0.3,
         "emd_reached_goal": 0.12, "emd_initial": 0.2, "failure": "plan step 2 (cut): simulation blew up"},
    ]
    metrics = summary_metrics(rows)
    assert metrics["failed_configs"] == 1.0
    assert metrics["performance"] == pytest.approx(0.7)
    assert metrics["success_rate"] == pytest.approx(0.5)
    assert metrics["planning_time_s"] == pytest.approx(3.0)
    assert metrics["emd_planned_goal"] == pytest.approx(0.2)
    assert metrics["emd_reached_goal"] == pytest.approx(0.07)
    assert metrics["emd_initial"] == pytest.approx(0.25)
    assert metrics["performance_config_1"] == 0.5 and metrics["success_config_0"] == 1.0
    assert metrics["planning_time_s_config_0"] == 2.0


def test_summary_means_skip_the_planned_goal_of_an_unplanned_configuration():
    rows = [
        {"config_id": 0, "performance": 0.4, "success": False, "planning_time_s": 2.0, "emd_planned_goal": 0.1,
         "emd_reached_goal": 0.02, "emd_initial": 0.3},
        {"config_id": 1, "performance": 0.0, "success": False, "planning_time_s": 0.0,
         "emd_planned_goal": float("nan"), "emd_reached_goal": 0.2, "emd_initial": 0.2,
         "failure": "planning: no skill sequence of horizon 2 takes 2 entities to 1"},
    ]
    metrics = summary_metrics(rows)
    assert metrics["emd_planned_goal"] == pytest.approx(0.1)
    assert metrics["performance"] == pytest.approx(0.2) and metrics["failed_configs"] == 1.0
    only_unplanned = summary_metrics(rows[1:])
    assert np.isnan(only_unplanned["emd_planned_goal"])
    with pytest.raises(ValueError, match="no evaluation results"):
        summary_metrics([])
