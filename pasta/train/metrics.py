"""Held-out metrics of the trained models: ROC-AUC, R^2, and the policy's MSE against a zero-action baseline."""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

__all__ = ["action_mse", "r_squared", "roc_auc"]


def roc_auc(positive_scores: np.ndarray, negative_scores: np.ndarray) -> float:
    """Area under the ROC curve: the probability that a random positive scores above a random negative.

    Rank-based (Mann-Whitney U with mid-ranks, so ties count one half); ``O(n log n)``.

    Raises:
        ValueError: when either side is empty.
    """
    pos = np.asarray(positive_scores, dtype=np.float64).ravel()
    neg = np.asarray(negative_scores, dtype=np.float64).ravel()
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError(f"need positives and negatives, got {len(pos)} and {len(neg)}")
    ranks = rankdata(np.concatenate([pos, neg]))
    u = ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2
    return float(u / (len(pos) * len(neg)))


def r_squared(prediction: np.ndarray, target: np.ndarray) -> float:
    """Coefficient of determination ``1 - SS_res / SS_tot`` (``nan`` when the target is constant)."""
    pred = np.asarray(prediction, dtype=np.float64).ravel()
    true = np.asarray(target, dtype=np.float64).ravel()
    if pred.shape != true.shape or len(true) == 0:
        raise ValueError(f"need equal, non-empty shapes, got {pred.shape} and {true.shape}")
    total = np.square(true - true.mean()).sum()
    return float(1.0 - np.square(true - pred).sum() / total) if total > 0 else float("nan")


def action_mse(prediction: np.ndarray, actions: np.ndarray) -> float:
    """Squared error summed over action dimensions, averaged over samples (the policy loss of model_spec §4.4).

    ``action_mse(zeros, actions)`` is the zero-action baseline.
    """
    pred = np.asarray(prediction, dtype=np.float64)
    true = np.asarray(actions, dtype=np.float64)
    if pred.shape != true.shape or true.ndim != 2:
        raise ValueError(f"need equal (B, A) shapes, got {pred.shape} and {true.shape}")
    return float(np.square(pred - true).sum(axis=1).mean())
