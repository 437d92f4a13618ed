"""Spatial abstraction: DBSCAN entity labels, splitting, resampling and entity matching.

Follows ``env_spec.md`` §6 and ``model_spec.md`` §0.2-0.4 (the official
``core/pasta/generate_dbscan_label.py::dbscan_cluster`` and ``core/utils/pasta_utils.py::match_set``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from scipy.spatial import cKDTree
from sklearn.cluster import DBSCAN

from pasta.geometry.distances import RandomLike, as_generator, chamfer_distance

__all__ = ["EntityMatch", "label_entities", "match_entities", "resample", "split_entities"]


def _as_points(points, name: str = "points") -> np.ndarray:
    if isinstance(points, torch.Tensor):
        points = points.detach().cpu().numpy()
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr


PIECE_GAP = 0.03  # DBSCAN's eps (env_spec §6): pieces closer than this are one entity


def label_entities(
    points: np.ndarray, eps: float = PIECE_GAP, min_samples: int = 6, min_points: int = 10
) -> np.ndarray:
    """Entity label of every point, by DBSCAN and the official post-filter (env_spec §6).

    1. ``sklearn.cluster.DBSCAN(eps, min_samples)`` on the cloud.
    2. Clusters with **strictly more** than ``min_points`` points are kept and relabelled ``0..K-1`` in
       increasing order of their DBSCAN label.
    3. Every noise point and every point of a dropped cluster takes the label of its nearest kept
       point (Euclidean nearest neighbour, not nearest centroid).

    Training labels use ``min_points=10``; the official planner and executor used the function
    default ``50`` (env_spec §6). DBSCAN is deterministic, so no seed is needed.

    Args:
        points: ``(N, 3)`` finite points.

    Returns:
        ``(N,)`` int64 labels in ``0..K-1``, every label used.

    Raises:
        ValueError: when no cluster has more than ``min_points`` points (the message names
            ``eps``, ``min_samples`` and ``min_points``; a caller may retry with other values).
    """
    pts = _as_points(points).astype(np.float64, copy=False)
    if len(pts) == 0:
        raise ValueError("points is an empty point cloud")
    if not np.isfinite(pts).all():
        raise ValueError("points has non-finite coordinates")
    raw = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(pts)
    cluster_ids, counts = np.unique(raw[raw >= 0], return_counts=True)
    kept_ids = cluster_ids[counts > min_points]  # np.unique sorts, so relabelling keeps DBSCAN order
    if len(kept_ids) == 0:
        raise ValueError(
            f"no DBSCAN cluster with more than min_points={min_points} points "
            f"(eps={eps}, min_samples={min_samples}, {len(pts)} points, "
            f"{len(cluster_ids)} raw clusters of sizes {counts.tolist()})"
        )
    relabel = np.full(raw.max() + 2, -1, dtype=np.int64)  # index raw + 1 so that noise (-1) maps via 0
    relabel[kept_ids + 1] = np.arange(len(kept_ids))
    labels = relabel[raw + 1]
    orphan = labels < 0
    if orphan.any():
        kept = ~orphan
        _, nearest = cKDTree(pts[kept]).query(pts[orphan], k=1)
        labels[orphan] = labels[kept][nearest]
    return labels


def split_entities(points: np.ndarray, labels: np.ndarray) -> list[np.ndarray]:
    """The points of each entity, in increasing label order: ``[(n_0, 3), (n_1, 3), ...]``.

    Labels must be non-negative integers; missing labels are skipped.
    """
    pts = _as_points(points)
    lab = np.asarray(labels)
    if lab.shape != (len(pts),):
        raise ValueError(f"labels must have shape ({len(pts)},), got {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be integers, got dtype {lab.dtype}")
    if (lab < 0).any():
        raise ValueError("labels must be non-negative (relabel noise with label_entities first)")
    return [pts[lab == k] for k in np.unique(lab)]


def resample(points: np.ndarray, n: int, rng: RandomLike) -> np.ndarray:
    """Resample a cloud to exactly ``n`` points.

    More than ``n`` points: ``n`` distinct points drawn at random (without replacement). Fewer: every
    point once plus ``n - len`` random duplicates (with replacement), as ``resample_pc`` pads.
    The official code also draws *with* replacement when there are more points (model_spec §0.2);
    drawing without replacement keeps more of the shape and is otherwise equivalent.

    Args:
        points: ``(N, 3)`` with ``N >= 1``.
        n: target size.
        rng: numpy Generator or seed.

    Returns:
        ``(n, 3)`` array of the input dtype.
    """
    pts = _as_points(points)
    if len(pts) == 0:
        raise ValueError("cannot resample an empty point cloud")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    gen = as_generator(rng)
    if len(pts) >= n:
        return pts[gen.choice(len(pts), n, replace=False)]
    extra = gen.choice(len(pts), n - len(pts), replace=True)
    return np.concatenate([pts, pts[extra]], axis=0)


class EntityMatch(NamedTuple):
    """One matched (observation entity, goal entity) pair and its Chamfer distance."""

    obs_index: int
    goal_index: int
    chamfer: float


def _subsample_all(clouds: list[np.ndarray], n_points: int, gen: np.random.Generator) -> list[np.ndarray]:
    sizes = {len(c) for c in clouds}
    if len(sizes) == 1 and next(iter(sizes)) >= n_points:
        # One shared index set for every entity, as the official chamfer_downsample does.
        idx = gen.choice(next(iter(sizes)), n_points, replace=False)
        return [c[idx] for c in clouds]
    return [resample(c, n_points, gen) for c in clouds]


def match_entities(
    obs_list: list[np.ndarray],
    goal_list: list[np.ndarray],
    threshold: float = 5e-4,
    *,
    n_points: int | None = 200,
    rng: RandomLike = None,
) -> list[EntityMatch]:
    """Pairs of observation and goal entities that already agree (model_spec §0.4).

    Computes the Chamfer distance (``chamfer_distance`` units, squared) between every observation and
    every goal entity, then greedily takes pairs in increasing distance while the distance is strictly
    below ``threshold``, each entity used at most once. A threshold of 0 matches nothing (no filtering).

    Args:
        obs_list: observation entities, each ``(n_i, 3)``.
        goal_list: goal entities, each ``(m_j, 3)``.
        threshold: the matching threshold ``epsilon`` (official 5e-4).
        n_points: entities are first subsampled to this many points (official 200; one shared index set
            when all entities have the same size); ``None`` uses every point.
        rng: generator or seed for the subsampling.

    Returns:
        Matches in increasing order of distance.
    """
    if not obs_list or not goal_list:
        return []
    obs = [_as_points(c, "observation entity").astype(np.float64) for c in obs_list]
    goal = [_as_points(c, "goal entity").astype(np.float64) for c in goal_list]
    if n_points is not None:
        sub = _subsample_all(obs + goal, n_points, as_generator(rng))
        obs, goal = sub[: len(obs)], sub[len(obs) :]
    n_obs, n_goal = len(obs), len(goal)
    with torch.no_grad():
        if n_points is not None:
            a = torch.from_numpy(np.stack(obs)).repeat_interleave(n_goal, dim=0)
            b = torch.from_numpy(np.stack(goal)).repeat(n_obs, 1, 1)
            dist = chamfer_distance(a, b).numpy().reshape(n_obs, n_goal)
        else:
            dist = np.array(
                [
                    [float(chamfer_distance(torch.from_numpy(o), torch.from_numpy(g))) for g in goal]
                    for o in obs
                ],
            )
    matches: list[EntityMatch] = []
    used_obs: set[int] = set()
    used_goal: set[int] = set()
    for flat in np.argsort(dist, axis=None, kind="stable"):
        i, j = divmod(int(flat), n_goal)
        if not dist[i, j] < threshold:
            break
        if i in used_obs or j in used_goal:
            continue
        used_obs.add(i)
        used_goal.add(j)
        matches.append(EntityMatch(i, j, float(dist[i, j])))
    return matches
