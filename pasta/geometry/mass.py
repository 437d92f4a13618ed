"""One cloud from several entity clouds, each holding its share of the mass.

A decoded latent set is ``K`` entity clouds of ``M`` points each, whatever the entities' sizes; stacked as they
are, a small piece carries as much mass as a large one, and the EMD to a real scene (whose particles all weigh
the same) charges that imbalance to the plan. For a CRS goal cut 0.34 / 0.66, the goal's own pieces stacked at
1000 points each lie 0.074 from the goal. ``merge_by_volume`` gives each entity a number of points proportional
to the volume of its convex hull instead (the dough's density is uniform and its pieces are close to convex):
the same pieces then lie 0.004-0.018 from their goals (``docs/evaluation.md``, "Planned goals").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from pasta.geometry.distances import RandomLike, as_generator

__all__ = ["apportion", "hull_volume", "merge_by_shares", "merge_by_volume"]


def hull_volume(points: np.ndarray) -> float:
    """Volume of the convex hull of ``(N, 3)`` points; 0 when they span less than three dimensions."""
    cloud = np.asarray(points, dtype=np.float64)
    if cloud.ndim != 2 or cloud.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {cloud.shape}")
    if not np.isfinite(cloud).all():
        raise ValueError("points must be finite")
    if len(cloud) < 4:
        return 0.0
    try:
        return float(ConvexHull(cloud).volume)
    except QhullError:  # coplanar or collinear points
        return 0.0


def apportion(weights: np.ndarray, total: int) -> np.ndarray:
    """Split ``total`` into integer counts proportional to ``weights`` (largest remainders); ``(K,)`` int64.

    All-zero weights share equally.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or len(w) == 0 or (w < 0).any() or not np.isfinite(w).all():
        raise ValueError(f"weights must be a non-empty vector of finite values >= 0, got {w}")
    if total < 0:
        raise ValueError(f"total must be >= 0, got {total}")
    share = w / w.sum() if w.sum() > 0 else np.full(len(w), 1.0 / len(w))
    exact = share * total
    counts = np.floor(exact).astype(np.int64)
    order = np.argsort(-(exact - counts), kind="stable")
    counts[order[: total - int(counts.sum())]] += 1
    return counts


def merge_by_volume(clouds: np.ndarray, n_points: int, rng: RandomLike) -> np.ndarray:
    """``(K, M, 3)`` entity clouds -> one ``(n_points, 3)`` cloud, entity ``k`` holding a share of the points
    equal to its hull volume's share of the total (:func:`merge_by_shares`)."""
    stack = _entity_stack(clouds)
    return merge_by_shares(stack, np.array([hull_volume(cloud) for cloud in stack]), n_points, rng)


def merge_by_shares(clouds: np.ndarray, shares: np.ndarray, n_points: int, rng: RandomLike) -> np.ndarray:
    """``(K, M, 3)`` entity clouds -> one ``(n_points, 3)`` cloud, entity ``k`` holding ``shares[k] / sum(shares)``
    of the points (``shares`` ``(K,)``, >= 0; all zero share equally).

    Each entity's points are drawn from its own without replacement (with replacement when it needs more than
    ``M``), with ``rng``.
    """
    stack = _entity_stack(clouds)
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    weights = np.asarray(shares, dtype=np.float64)
    if weights.shape != (len(stack),):
        raise ValueError(f"shares must have shape ({len(stack)},), one per entity, got {weights.shape}")
    gen = as_generator(rng)
    counts = apportion(weights, n_points)
    parts = [cloud[gen.choice(len(cloud), int(count), replace=int(count) > len(cloud))]
             for cloud, count in zip(stack, counts, strict=True) if count > 0]
    return np.concatenate(parts, axis=0)


def _entity_stack(clouds: np.ndarray) -> np.ndarray:
    stack = np.asarray(clouds, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[2] != 3 or stack.shape[0] == 0 or stack.shape[1] == 0:
        raise ValueError(f"clouds must have shape (K, M, 3) with K, M >= 1, got {stack.shape}")
    return stack
