"""Scores of an executed plan (env_spec §4, model_spec §7.1, appendix Table 7).

* ``emd_initial`` / ``emd_final``: exact EMD (optimal assignment, :func:`pasta.geometry.earth_movers_distance`)
  between the observation points and as many target points, as the demos are scored
  (:func:`pasta.data.demos.shape_distance`);
* normalised performance ``(emd_initial - emd_final) / emd_initial`` and success ``performance >
  cfg.eval.success_threshold``;
* ``emd_planned_goal``: EMD between the decoded final latent set (entities stacked, subsampled to the
  target's size) and the true goal; ``emd_reached_goal``: EMD between the reached observation and the true
  goal (the exact EMD does not use particle correspondence, so it equals ``emd_final``).

:func:`summary_metrics` turns per-configuration results into the metric names the report reads.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pasta.data.demos import shape_distance
from pasta.geometry.distances import earth_movers_distance

__all__ = ["AGGREGATED", "PER_CONFIGURATION", "planned_goal_distance", "shape_distance", "summary_metrics"]

# Aggregated metric -> the per-configuration field it averages.
AGGREGATED: Mapping[str, str] = {
    "performance": "performance",
    "success_rate": "success",
    "planning_time_s": "planning_time_s",
    "emd_planned_goal": "emd_planned_goal",
    "emd_reached_goal": "emd_reached_goal",
    "emd_initial": "emd_initial",
}
# Per-configuration metric prefix -> field; logged as ``<prefix>_config_<config_id>``.
PER_CONFIGURATION: Mapping[str, str] = {
    "performance": "performance",
    "success": "success",
    "planning_time_s": "planning_time_s",
}


def planned_goal_distance(decoded_final: np.ndarray, target_points: np.ndarray, seed: int) -> float:
    """Exact EMD between the decoded final set ``(K, M, 3)`` (stacked, subsampled) and the goal ``(P, 3)``."""
    planned = np.asarray(decoded_final, dtype=np.float64).reshape(-1, 3)
    return earth_movers_distance(planned, target_points, rng=np.random.default_rng(seed))


def _mean_of_known(values: Sequence[float]) -> float:
    """The mean of the finite values (a configuration that was not planned has no planned-goal EMD); NaN if none."""
    known = [v for v in values if np.isfinite(v)]
    return float(np.mean(known)) if known else float("nan")


def summary_metrics(rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Means over configurations and per-configuration values, under the contract's metric names.

    Each row needs ``config_id`` and the fields of ``AGGREGATED``; ``success`` counts as 0/1.
    ``failed_configs`` counts the rows whose execution stopped early or never started (a ``failure`` that is
    not None). Means skip values that are NaN.
    """
    if not rows:
        raise ValueError("no evaluation results to summarise")
    metrics = {name: _mean_of_known([float(r[field]) for r in rows]) for name, field in AGGREGATED.items()}
    metrics["failed_configs"] = float(sum(r.get("failure") is not None for r in rows))
    for row in rows:
        for prefix, field in PER_CONFIGURATION.items():
            metrics[f"{prefix}_config_{int(row['config_id'])}"] = float(row[field])
    return metrics
