"""Metrics against slow, obviously correct references."""

import numpy as np
import pytest

from pasta.train.metrics import action_mse, r_squared, roc_auc


def pairwise_auc(pos: np.ndarray, neg: np.ndarray) -> float:
    wins = sum(1.0 if p > n else 0.5 if p == n else 0.0 for p in pos for n in neg)
    return wins / (len(pos) * len(neg))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_roc_auc_matches_pairwise_counting_with_ties(seed):
    rng = np.random.default_rng(seed)
    pos = rng.integers(0, 6, size=37).astype(float)  # few distinct values: many ties
    neg = rng.integers(0, 5, size=23).astype(float)
    assert roc_auc(pos, neg) == pytest.approx(pairwise_auc(pos, neg), abs=1e-12)


def test_roc_auc_extremes_and_errors():
    assert roc_auc(np.array([2.0, 3.0]), np.array([0.0, 1.0])) == 1.0
    assert roc_auc(np.array([0.0]), np.array([1.0, 2.0])) == 0.0
    with pytest.raises(ValueError, match="positives and negatives"):
        roc_auc(np.array([]), np.array([1.0]))


def test_r_squared_matches_definition():
    rng = np.random.default_rng(3)
    target = rng.normal(size=50)
    prediction = target + 0.3 * rng.normal(size=50)
    reference = 1 - sum((t - p) ** 2 for t, p in zip(target, prediction, strict=True)) / sum(
        (t - target.mean()) ** 2 for t in target)
    assert r_squared(prediction, target) == pytest.approx(reference)
    assert r_squared(target, target) == 1.0
    assert r_squared(np.full(50, target.mean()), target) == pytest.approx(0.0, abs=1e-12)


def test_action_mse_sums_dimensions_and_averages_samples():
    pred = np.array([[0.0, 1.0], [1.0, 1.0]])
    true = np.array([[1.0, 1.0], [0.0, -1.0]])
    assert action_mse(pred, true) == pytest.approx((1.0 + (1.0 + 4.0)) / 2)
    assert action_mse(np.zeros_like(true), true) == pytest.approx((1 + 1 + 0 + 1) / 2)
