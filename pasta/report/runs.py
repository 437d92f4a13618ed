"""MLflow runs (as ``mlflow.search_runs`` returns them) -> tidy pandas frames for the report.

The report never talks to MLflow except through :func:`load_runs` (``pasta.tracking.search_runs``);
everything else takes a DataFrame, so tests can hand it synthetic runs.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

# The metrics an evaluate run logs (contract of flows/evaluate.py) that the report reads; the plan_* ones are
# a learned plan's diagnostics (pasta.evaluate.metrics.PLAN_QUALITY).
EVAL_METRICS = ("performance", "success_rate", "planning_time_s", "emd_planned_goal", "emd_reached_goal",
                "plan_sequence_match_rate", "plan_attention_match_rate", "plan_subgoal_emd",
                "plan_optimiser_failure_rate")
# The tags that tell evaluation runs apart; the newest finished run of each combination counts.
EVAL_KEYS = ("task", "profile", "experiment", "variant", "sweep_value", "seed")
# Tags carried beside the keys: how the run planned (learned, oracle) and executed (policy, scripted).
EVAL_LABELS = ("plan", "executor")
# Keys that keep the runs of one experiment and seed apart when they planned or executed differently.
CELL_KEYS = (*EVAL_KEYS, *EVAL_LABELS)
# Tasks that are planned with another task's models (their train runs live in that task's experiment).
MODELS_FROM = {"CRS-Twice": "CRS"}


def load_runs(tasks: Iterable[str]) -> pd.DataFrame:
    """Every run of the experiments ``pasta/<task>``, concatenated (an empty frame when there are none)."""
    from pasta import tracking

    frames = [tracking.search_runs(task) for task in tasks]
    frames = [frame for frame in frames if not frame.empty]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _column(runs: pd.DataFrame, name: str, default: object = "") -> pd.Series:
    if name in runs.columns:
        return runs[name]
    return pd.Series([default] * len(runs), index=runs.index, dtype=object)


def _tag(runs: pd.DataFrame, tag: str) -> pd.Series:
    return _column(runs, f"tags.pasta.{tag}").fillna("").astype(str)


def _finished(runs: pd.DataFrame, stage: str) -> pd.DataFrame:
    if runs.empty:
        return runs
    keep = (_tag(runs, "stage") == stage) & (_column(runs, "status") == "FINISHED")
    return runs[keep]


def evaluation_runs(runs: pd.DataFrame, keys: Sequence[str] = EVAL_KEYS) -> pd.DataFrame:
    """Finished evaluate runs as one row per combination of ``keys`` (the newest run of each).

    Returns columns ``EVAL_KEYS + EVAL_LABELS + ("run_id", "start_time") + EVAL_METRICS`` sorted by ``keys``
    (any of those tag columns; they must name the seed). A run without ``pasta.experiment`` counts as ``main``,
    one without ``pasta.plan`` (older than the oracle plan) as ``learned``. Missing metrics are NaN.
    """
    columns = [*EVAL_KEYS, *EVAL_LABELS, "run_id", "start_time", *EVAL_METRICS]
    done = _finished(runs, "evaluate")
    if done.empty:
        return pd.DataFrame({c: pd.Series(dtype=float if c in EVAL_METRICS else object) for c in columns})
    tidy = pd.DataFrame({tag: _tag(done, tag) for tag in (*EVAL_KEYS, *EVAL_LABELS)})
    tidy["experiment"] = tidy["experiment"].replace("", "main")
    tidy["plan"] = tidy["plan"].replace("", "learned")
    tidy["run_id"] = done["run_id"].astype(str)
    tidy["start_time"] = pd.to_datetime(done["start_time"], utc=True)
    for metric in EVAL_METRICS:
        tidy[metric] = pd.to_numeric(_column(done, f"metrics.{metric}", np.nan), errors="coerce").astype(float)
    tidy = tidy.sort_values([*keys, "start_time", "run_id"], kind="mergesort")
    newest = tidy.drop_duplicates(list(keys), keep="last")
    return newest[columns].reset_index(drop=True)


def newest_train_run(runs: pd.DataFrame, task: str, profile: str, variant: str) -> str | None:
    """The run id of the newest finished train run of ``task``'s models at ``profile`` and ``variant``."""
    done = _finished(runs, "train")
    if done.empty:
        return None
    source = MODELS_FROM.get(task, task)
    match = done[(_tag(done, "task") == source) & (_tag(done, "profile") == profile)
                 & (_tag(done, "variant") == variant)]
    if match.empty:
        return None
    order = match.assign(_start=pd.to_datetime(match["start_time"], utc=True)).sort_values(
        ["_start", "run_id"], kind="mergesort")
    return str(order.iloc[-1]["run_id"])


def profiles(runs: pd.DataFrame, tasks: Iterable[str], order: Iterable[str]) -> list[str]:
    """Profiles with evaluate or train runs of ``tasks`` (or their model tasks), in ``order`` then by name."""
    if runs.empty:
        return []
    wanted = set(tasks) | {MODELS_FROM.get(t, t) for t in tasks}
    relevant = runs[_tag(runs, "task").isin(wanted) & _tag(runs, "stage").isin(["evaluate", "train"])
                    & (_column(runs, "status") == "FINISHED")]
    present = set(_tag(relevant, "profile")) - {""}
    ranked = [p for p in order if p in present]
    return ranked + sorted(present - set(ranked))
