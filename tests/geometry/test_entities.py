"""DBSCAN entity labels (env_spec §6), splitting, resampling and matching (model_spec §0.4)."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from pasta.geometry import label_entities, match_entities, resample, split_entities


def blob(center, n: int, rng: np.random.Generator, radius: float = 0.02) -> np.ndarray:
    """``n`` points uniform in a ball: dense enough that DBSCAN(0.03, 6) sees one cluster."""
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    r = radius * rng.random((n, 1)) ** (1 / 3)
    return np.asarray(center) + direction * r


def isolated_points(centers, rng: np.random.Generator) -> np.ndarray:
    """Points on a 0.1 grid away from the blobs: every one is DBSCAN noise."""
    grid = np.stack(np.meshgrid(*[np.arange(5) * 0.1 - 0.2] * 3), -1).reshape(-1, 3) + 0.003
    far = np.min(np.linalg.norm(grid[:, None] - np.asarray(centers)[None], axis=-1), axis=1) > 0.08
    picked = grid[far]
    return picked[rng.choice(len(picked), 12, replace=False)]


def nearest_kept_label_reference(points, labels, orphan):
    """Brute-force loop: label of the nearest non-orphan point."""
    expected = labels.copy()
    kept = np.flatnonzero(~orphan)
    for i in np.flatnonzero(orphan):
        best, best_label = np.inf, None
        for j in kept:
            d = float(np.sqrt(((points[i] - points[j]) ** 2).sum()))
            if d < best:
                best, best_label = d, labels[j]
        expected[i] = best_label
    return expected


@pytest.mark.parametrize("n_blobs", [1, 2, 3])
def test_blobs_with_noise_labels_and_reassignment(n_blobs):
    rng = np.random.default_rng(n_blobs)
    centers = [(-0.15, 0.0, 0.0), (0.15, 0.0, 0.0), (0.0, 0.15, 0.15)][:n_blobs]
    parts = [blob(c, 60, rng) for c in centers]
    noise = isolated_points(centers, rng)
    points = np.concatenate([*parts, noise])
    raw = DBSCAN(eps=0.03, min_samples=6).fit_predict(points)
    noise_mask = raw == -1
    assert noise_mask[-len(noise) :].all() and not noise_mask[: -len(noise)].any()  # the fixture works

    labels = label_entities(points)
    assert labels.shape == (len(points),) and labels.dtype == np.int64
    assert sorted(set(labels.tolist())) == list(range(n_blobs))
    for k in range(n_blobs):  # clusters keep DBSCAN's order: blob k (found k-th) gets label k
        assert (labels[60 * k : 60 * (k + 1)] == k).all()
    expected = nearest_kept_label_reference(points, labels, noise_mask)
    np.testing.assert_array_equal(labels, expected)


def test_too_small_cluster_merged_into_nearest_cluster_and_labels_ordered():
    rng = np.random.default_rng(7)
    big0 = blob((-0.2, 0.0, 0.0), 50, rng)
    small = blob((0.12, 0.0, 0.0), 10, rng, radius=0.01)  # a DBSCAN cluster, but not > 10 points
    big2 = blob((0.2, 0.0, 0.0), 50, rng)
    points = np.concatenate([big0, small, big2])
    raw = DBSCAN(eps=0.03, min_samples=6).fit_predict(points)
    assert len(set(raw[raw >= 0].tolist())) == 3 and (raw[50:60] == raw[50]).all() and raw[50] >= 0

    labels = label_entities(points, min_points=10)
    assert (labels[:50] == 0).all() and (labels[60:] == 1).all()  # relabelled 0, 1 skipping the dropped one
    assert (labels[50:60] == 1).all()  # the small cluster is closer to the right blob
    dropped = np.zeros(len(points), dtype=bool)
    dropped[50:60] = True
    np.testing.assert_array_equal(labels, nearest_kept_label_reference(points, labels, dropped))
    # with a lower min_points the small cluster survives, in DBSCAN order between the two blobs
    labels3 = label_entities(points, min_points=9)
    assert labels3[0] == 0 and (labels3[50:60] == 1).all() and (labels3[60:] == 2).all()


def test_error_when_no_cluster_survives():
    sparse = np.stack(np.meshgrid(*[np.arange(4) * 0.1] * 3), -1).reshape(-1, 3)
    with pytest.raises(ValueError, match=r"eps=0\.03.*min_samples=6"):
        label_entities(sparse)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="min_points=100"):
        label_entities(blob((0, 0, 0), 60, rng), min_points=100)
    with pytest.raises(ValueError, match="shape"):
        label_entities(np.zeros((5, 2)))


def test_split_and_resample():
    rng = np.random.default_rng(1)
    points = rng.random((30, 3))
    labels = np.array([0] * 10 + [2] * 5 + [1] * 15)
    parts = split_entities(points, labels)
    assert [len(p) for p in parts] == [10, 15, 5]
    np.testing.assert_array_equal(parts[2], points[10:15])
    with pytest.raises(ValueError, match="non-negative"):
        split_entities(points, np.full(30, -1))

    few = resample(points[:7], 20, np.random.default_rng(2))
    assert few.shape == (20, 3)
    np.testing.assert_array_equal(few[:7], points[:7])  # every point kept, then duplicates
    assert {tuple(p) for p in few} == {tuple(p) for p in points[:7]}
    many = resample(points, 12, np.random.default_rng(2))
    assert many.shape == (12, 3) and len({tuple(p) for p in many}) == 12  # without replacement
    np.testing.assert_array_equal(many, resample(points, 12, 2))  # a seed works like a generator


def grid_cloud(offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """125 points with spacing 0.05: a shift below 0.025 keeps every nearest neighbour, CD = 2|d|^2."""
    return np.stack(np.meshgrid(*[np.arange(5) * 0.05] * 3), -1).reshape(-1, 3) + np.asarray(offset)


@pytest.mark.parametrize("n_points", [None, 50])
def test_match_entities_greedy_one_to_one(n_points):
    goal = [grid_cloud(), grid_cloud((0.004, 0, 0)), grid_cloud((1.0, 1.0, 1.0))]
    obs = [grid_cloud((0.001, 0, 0)), grid_cloud((0.006, 0, 0))]
    # distances: obs0-goal0 2e-6, obs0-goal1 1.8e-5, obs1-goal0 7.2e-5, obs1-goal1 8e-6
    matches = match_entities(obs, goal, threshold=1e-4, n_points=n_points, rng=0)
    assert [(m.obs_index, m.goal_index) for m in matches] == [(0, 0), (1, 1)]
    assert matches[0].chamfer == pytest.approx(2e-6, rel=1e-6)
    assert matches[1].chamfer == pytest.approx(8e-6, rel=1e-6)
    only_first = match_entities(obs, goal, threshold=5e-6, n_points=n_points, rng=0)
    assert [(m.obs_index, m.goal_index) for m in only_first] == [(0, 0)]
    assert match_entities(obs, goal, threshold=0.0, n_points=n_points) == []  # threshold 0: no filtering
    at_threshold = match_entities(obs, goal, threshold=matches[1].chamfer, n_points=n_points, rng=0)
    assert [(m.obs_index, m.goal_index) for m in at_threshold] == [(0, 0)]  # strictly below
    # each goal used once: two observations near the same single goal give one match, the closer one
    single = match_entities([grid_cloud((0.002, 0, 0)), grid_cloud((0.001, 0, 0))], [grid_cloud()], 1e-4)
    assert [(m.obs_index, m.goal_index) for m in single] == [(1, 0)]
    assert match_entities([], goal, 1e-4) == []
