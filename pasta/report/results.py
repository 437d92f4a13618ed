"""``results.csv``: the evaluation numbers of every report as one machine-readable table.

One row per group of evaluation runs that share task, profile, experiment, variant, sweep value, plan and
executor; within a group the newest finished run of each seed counts, as in the tables. Aggregates are the
tables' own (:func:`pasta.report.tables.mean_std`: mean and sample std over seeds, no std below two seeds).
Rows are sorted by the group columns and floats printed with :data:`FLOAT_FORMAT`, so the same runs always
give the same bytes; an empty cell is a value no run recorded (or a std of a single seed).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from pasta.data.storage import atomic_write_bytes
from pasta.report.runs import evaluation_runs
from pasta.report.tables import mean_std

RESULTS_FILE = "results.csv"
GROUP_COLUMNS = ("task", "profile", "experiment", "variant", "sweep_value", "plan", "executor")
STAT_COLUMNS = ("n_seeds", "performance_mean", "performance_std", "success_mean", "success_std", "planning_time_s",
                "emd_planned", "emd_reached")
RESULT_COLUMNS = (*GROUP_COLUMNS, *STAT_COLUMNS)
FLOAT_FORMAT = "%.6g"


def _aggregate(group: pd.DataFrame) -> dict[str, float | int]:
    """The :data:`STAT_COLUMNS` of one group's runs (one row per seed); planning time and EMDs are means."""
    performance_mean, performance_std, _ = mean_std(group["performance"])
    success_mean, success_std, _ = mean_std(group["success_rate"])
    return {"n_seeds": len(group), "performance_mean": performance_mean, "performance_std": performance_std,
            "success_mean": success_mean, "success_std": success_std,
            "planning_time_s": mean_std(group["planning_time_s"])[0],
            "emd_planned": mean_std(group["emd_planned_goal"])[0],
            "emd_reached": mean_std(group["emd_reached_goal"])[0]}


def results_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per evaluation group of ``runs`` (as ``mlflow.search_runs`` returns them), columns
    :data:`RESULT_COLUMNS`, sorted by :data:`GROUP_COLUMNS`."""
    ev = evaluation_runs(runs, keys=(*GROUP_COLUMNS, "seed"))
    rows = [{**dict(zip(GROUP_COLUMNS, key, strict=True)), **_aggregate(group)}
            for key, group in ev.groupby(list(GROUP_COLUMNS), sort=True)]
    return pd.DataFrame(rows, columns=list(RESULT_COLUMNS))


def results_csv(runs: pd.DataFrame) -> bytes:
    """:func:`results_table` as CSV bytes (``\\n`` line ends, :data:`FLOAT_FORMAT`, NaN as an empty cell)."""
    text = results_table(runs).to_csv(index=False, float_format=FLOAT_FORMAT, na_rep="", lineterminator="\n")
    return text.encode()


def save_results(runs: pd.DataFrame, out_dir: str | Path) -> Path:
    """Write ``<out_dir>/results.csv`` atomically; returns its path."""
    data = results_csv(runs)
    return atomic_write_bytes(Path(out_dir) / RESULTS_FILE, lambda handle: handle.write(data))
