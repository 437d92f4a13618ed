"""Scores of an executed plan (env_spec §4, model_spec §7.1, appendix Table 7).

* ``emd_initial`` / ``emd_final``: exact EMD (optimal assignment, :func:`pasta.geometry.earth_movers_distance`)
  between the observation points and as many target points, as the demos are scored
  (:func:`pasta.data.demos.shape_distance`);
* normalised performance ``(emd_initial - emd_final) / emd_initial`` and success ``performance >
  cfg.eval.success_threshold``;
* ``emd_planned_goal``: EMD between the decoded final latent set (made one cloud of the target's size, each
  entity holding its share of the points by ``cfg.eval.decoded_entity_weights``) and the true
  goal; ``emd_reached_goal``: EMD between the reached observation and the true goal (the exact EMD does not
  use particle correspondence, so it equals ``emd_final``).

:func:`summary_metrics` turns per-configuration results into the metric names the report reads, and
:func:`plan_quality_metrics` a learned plan's diagnostics (:mod:`pasta.evaluate.plan_diagnostics`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pasta.config.schema import DecodedEntityWeights
from pasta.data.demos import shape_distance
from pasta.geometry.distances import earth_movers_distance
from pasta.geometry.mass import merge_by_shares, merge_by_volume

__all__ = ["AGGREGATED", "PER_CONFIGURATION", "PLAN_QUALITY", "PLAN_QUALITY_PER_CONFIGURATION", "plan_quality_metrics",
           "planned_goal_distance", "shape_distance", "summary_metrics"]

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

# Aggregated plan-quality metric -> the per-configuration diagnostic it averages (learned plans only).
PLAN_QUALITY: Mapping[str, str] = {
    "plan_sequence_match_rate": "sequence_match",
    "plan_attention_match_rate": "attention_match",
    "plan_subgoal_emd": "subgoal_emd_mean",
    "plan_optimiser_failure_rate": "optimiser_failed",
}
# Per-configuration plan-quality metric prefix -> field; logged as ``<prefix>_config_<config_id>``.
PLAN_QUALITY_PER_CONFIGURATION: Mapping[str, str] = {
    "plan_sequence_match": "sequence_match",
    "plan_attention_match": "attention_match",
    "plan_subgoal_emd": "subgoal_emd_mean",
    "plan_score": "plan_score",
    "plan_ground_truth_score": "ground_truth_score",
    "plan_optimiser_failed": "optimiser_failed",
    "emd_planned_goal": "emd_planned_goal",
}


def planned_goal_distance(decoded_final: np.ndarray, target_points: np.ndarray, seed: int,
                          weights: DecodedEntityWeights = "volume", masses: np.ndarray | None = None) -> float:
    """Exact EMD between a decoded set ``(K, M, 3)``, made one cloud of the goal's size, and the goal ``(P, 3)``.

    ``weights="volume"``: each entity holds a share of the ``P`` points equal to its convex hull's share of the
    volume (:func:`pasta.geometry.mass.merge_by_volume`). ``"carried"``: each holds its share of ``masses``
    ``(K,)``, the masses the plan carried to it (:mod:`pasta.evaluate.plan_masses`). ``"equal"``: the ``K``
    entities stacked, ``M`` points each, then subsampled (the official decoding's stack), which weighs a small
    piece as much as a large one.
    """
    rng = np.random.default_rng(seed)
    decoded = np.asarray(decoded_final, dtype=np.float64)
    target = np.asarray(target_points, dtype=np.float64)
    if weights == "equal":
        return earth_movers_distance(decoded.reshape(-1, 3), target, rng=rng)
    if weights == "volume":
        return earth_movers_distance(merge_by_volume(decoded, len(target), rng), target, rng=rng)
    if weights == "carried":
        if masses is None:
            raise ValueError("weights 'carried' needs the plan's masses")
        return earth_movers_distance(merge_by_shares(decoded, masses, len(target), rng), target, rng=rng)
    raise ValueError(f"weights must be 'volume', 'carried' or 'equal', got {weights!r}")


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


def plan_quality_metrics(rows: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """Means over configurations and per-configuration values of a learned plan's diagnostics.

    Each row needs ``config_id`` and the fields of ``PLAN_QUALITY_PER_CONFIGURATION``
    (:func:`pasta.evaluate.plan_diagnostics.diagnostics_row`); booleans count as 0/1. A configuration without a
    plan counts as a mismatch in the match rates; its NaN EMD and scores are skipped by the means.
    """
    if not rows:
        raise ValueError("no evaluation results to summarise")
    metrics = {name: _mean_of_known([float(r[field]) for r in rows]) for name, field in PLAN_QUALITY.items()}
    for row in rows:
        for prefix, field in PLAN_QUALITY_PER_CONFIGURATION.items():
            metrics[f"{prefix}_config_{int(row['config_id'])}"] = float(row[field])
    return metrics
