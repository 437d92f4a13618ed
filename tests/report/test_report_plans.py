"""The plan x executor matrix and the plan-quality table, from synthetic run rows (as ``mlflow.search_runs`` gives)."""

from __future__ import annotations

import pandas as pd

from pasta.report import build_report, evaluation_runs, tables
from pasta.report.runs import CELL_KEYS

# (experiment, variant, sweep value, plan, executor, seed, performance, plan-quality metrics or None)
QUALITY = {"plan_sequence_match_rate": 0.6, "plan_attention_match_rate": 0.4, "plan_subgoal_emd": 0.05,
           "plan_optimiser_failure_rate": 0.2}
RUNS = [
    ("oracle_plan", "pasta", "", "oracle", "scripted", 0, 0.7, None),
    ("oracle_plan", "pasta", "", "oracle", "scripted", 1, 0.8, None),
    ("oracle_plan", "pasta", "", "oracle", "scripted", 2, 0.9, None),
    ("main", "pasta", "", "learned", "policy", 0, 0.02, QUALITY),
    ("main", "pasta", "", "learned", "policy", 1, 0.04, {**QUALITY, "plan_sequence_match_rate": 0.8}),
    ("scripted_executor", "pasta", "", "learned", "scripted", 1, -5.0, None),  # superseded by the next
    ("scripted_executor", "pasta", "", "learned", "scripted", 1, 0.3, None),
    ("main", "pasta", "", "learned", "scripted", 0, 0.1, None),  # main, seed 0, with the other executor
    ("decoded_cost", "pasta", "", "learned", "scripted", 0, 0.95, {**QUALITY, "plan_subgoal_emd": 0.02}),
    ("main", "flat3d", "", "learned", "policy", 0, 0.5, None),
    ("sweep_samples", "pasta", "10", "learned", "policy", 0, 0.6, None),
    ("sweep_data", "pasta", "150", "learned", "scripted", 0, 0.5, QUALITY),
    ("sweep_data", "pasta", "30", "learned", "scripted", 0, 0.2, {**QUALITY, "plan_sequence_match_rate": 0.4}),
    ("sweep_data", "pasta", "30", "learned", "scripted", 1, 0.4, QUALITY),
]


def _rows(task: str = "CutRearrange") -> pd.DataFrame:
    rows = []
    for index, (experiment, variant, sweep, plan, executor, seed, performance, quality) in enumerate(RUNS):
        row = {"run_id": f"run{index:03d}", "status": "FINISHED",
               "start_time": pd.Timestamp("2026-01-01", tz="UTC") + pd.Timedelta(seconds=index),
               "tags.pasta.stage": "evaluate", "tags.pasta.task": task, "tags.pasta.profile": "small",
               "tags.pasta.variant": variant, "tags.pasta.seed": str(seed), "tags.pasta.sweep_value": sweep,
               "tags.pasta.experiment": experiment, "tags.pasta.plan": plan, "tags.pasta.executor": executor,
               "metrics.performance": performance, "metrics.success_rate": 0.0,
               "metrics.emd_planned_goal": 0.1 if plan == "learned" else 0.0}
        row.update({f"metrics.{name}": value for name, value in (quality or {}).items()})
        rows.append(row)
    return pd.DataFrame(rows)


def _cells(table: tables.Table, task: str) -> dict[str, dict[str, str]]:
    frame = table.frame[table.frame["task"] == task].set_index("plan")
    return {plan: frame.loc[plan].drop("task").to_dict() for plan in frame.index}


def test_the_matrix_has_one_cell_per_plan_source_and_executor():
    cells = evaluation_runs(_rows(), keys=CELL_KEYS)
    table = tables.matrix_table(cells, ["CutRearrange", "CRS"])
    assert list(table.frame.columns) == ["task", "plan", "scripted skills", "learned policies"]
    # oracle scripted 0.7, 0.8, 0.9; learned policy 0.02, 0.04 (flat3d and the sweep left out); learned scripted
    # the main seed 0 (0.1) and scripted_executor's newest seed 1 (0.3), not decoded_cost's 0.95.
    assert _cells(table, "CutRearrange") == {
        "oracle plan": {"scripted skills": "0.800 ± 0.100 (3 seeds)", "learned policies": tables.NO_VALUE},
        "learned plan": {"scripted skills": "0.200 ± 0.141 (2 seeds)", "learned policies": "0.030 ± 0.014 (2 seeds)"},
    }
    assert set(table.frame[table.frame["task"] == "CRS"][["scripted skills", "learned policies"]].stack()) == {
        tables.NO_VALUE}


def test_one_seed_of_a_cell_shows_its_value_alone():
    rows = _rows()
    only_seed_0 = rows[rows["tags.pasta.seed"] == "0"]
    table = tables.matrix_table(evaluation_runs(only_seed_0, keys=CELL_KEYS), ["CutRearrange"])
    assert _cells(table, "CutRearrange")["oracle plan"]["scripted skills"] == "0.700 (1 seed)"


def test_plan_quality_rows_are_the_learned_plans_with_diagnostics():
    table = tables.plan_quality_table(evaluation_runs(_rows()), ["CutRearrange", "GatherMove"])
    frame = table.frame.set_index(["task", "experiment"])
    # main: the newest run of each seed (seed 0's is the scripted one, without diagnostics; seed 1's has them);
    # decoded_cost has diagnostics; oracle_plan and scripted_executor (none logged) have no row.
    assert list(frame.index) == [("CutRearrange", "main"), ("CutRearrange", "decoded_cost"), ("GatherMove", "main")]
    main = frame.loc[("CutRearrange", "main")].to_dict()
    assert main == {"seeds": "2", "skills = truth": "80%", "attention = truth": "40%", "EMD(subgoal, truth)": "0.0500",
                    "EMD(planned, goal)": "0.1000 ± 0.0000", "optimiser failed": "20%"}
    assert frame.loc[("CutRearrange", "decoded_cost"), "EMD(subgoal, truth)"] == "0.0200"
    assert frame.loc[("GatherMove", "main"), "skills = truth"] == tables.NOT_RUN


def test_each_task_report_shows_the_matrix_and_the_plan_quality():
    markdown = build_report("CutRearrange", _rows()).markdown
    assert "### Plan x executor: which half of the system loses the score" in markdown
    assert "| CutRearrange | oracle plan | 0.800 ± 0.100 (3 seeds) | — |" in markdown
    assert "| CutRearrange | learned plan | 0.200 ± 0.141 (2 seeds) | 0.030 ± 0.014 (2 seeds) |" in markdown
    assert "### Plan quality: the planner's plans against the ground-truth chain" in markdown
    assert "| CutRearrange | decoded_cost | 1 | 60% | 40% | 0.0200 | 0.1000 | 20% |" in markdown


def test_the_data_scale_table_has_one_row_per_number_of_demonstrations():
    table = tables.data_scale_table(evaluation_runs(_rows()))
    frame = table.frame.set_index("demonstrations")
    assert list(frame.index) == ["30", "150"]  # numeric order, not the runs' order or the strings'
    assert frame.loc["30"].to_dict() == {"seeds": "2", "performance": "0.300 ± 0.141", "success": "0% ± 0%",
                                         "skills = truth": "50% ± 14%", "EMD(subgoal, truth)": "0.0500 ± 0.0000",
                                         "EMD(planned, goal)": "0.1000 ± 0.0000"}
    assert frame.loc["150", "performance"] == "0.500"
    assert "### Plans against the number of demonstrations (CutRearrange)" in build_report("CutRearrange",
                                                                                            _rows()).markdown
    empty = tables.data_scale_table(evaluation_runs(_rows("CRS")), "CutRearrange")
    assert empty.frame.iloc[0]["performance"] == tables.NOT_RUN
