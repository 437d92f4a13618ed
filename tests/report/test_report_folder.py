"""The report folder: a local rebuild leaves the published reports alone; results.csv against a slow recount."""

from __future__ import annotations

import csv
import io
import math
import statistics
from collections import defaultdict

import pandas as pd
import pytest

from pasta import paths
from pasta.report import RESULT_COLUMNS, RESULTS_FILE, SUMMARY, results_csv, save_results, write_reports

METRICS = ("performance", "success_rate", "planning_time_s", "emd_planned_goal", "emd_reached_goal")
# (task, profile, experiment, variant, sweep value, plan, executor, seeds); "" for experiment and plan is a run
# without that tag (main, learned).
GROUPS = [
    ("CutRearrange", "smoke", "main", "pasta", "", "learned", "policy", (0, 1, 2)),
    ("CutRearrange", "smoke", "main", "pasta", "", "learned", "scripted", (0, 1)),
    ("CutRearrange", "smoke", "ablation", "flat3d", "", "learned", "policy", (0, 1, 2)),
    ("CutRearrange", "small", "oracle_plan", "pasta", "", "oracle", "scripted", (0,)),
    ("CRS", "small", "sweep_horizon", "pasta", "3", "learned", "policy", (0, 1)),
    ("CRS", "small", "sweep_horizon", "pasta", "4", "learned", "policy", (0, 1, 2, 3)),
    ("GatherMove", "smoke", "", "pasta", "", "", "policy", (0, 1)),
]


def _run(index: int, group: tuple, seed: int, status: str = "FINISHED", stage: str = "evaluate") -> dict:
    """One row as ``mlflow.search_runs`` returns it; metric values vary with the row, some are missing."""
    task, profile, experiment, variant, sweep_value, plan, executor, _ = group
    row = {"run_id": f"run{index:03d}", "status": status,
           "start_time": pd.Timestamp("2026-01-01", tz="UTC") + pd.Timedelta(seconds=index),
           "tags.pasta.stage": stage, "tags.pasta.task": task, "tags.pasta.profile": profile,
           "tags.pasta.variant": variant, "tags.pasta.seed": str(seed), "tags.pasta.sweep_value": sweep_value,
           "tags.pasta.executor": executor}
    if experiment:
        row["tags.pasta.experiment"] = experiment
    if plan:
        row["tags.pasta.plan"] = plan
    for k, metric in enumerate(METRICS):
        if (index + k) % 7 != 3:  # now and then a metric was not logged
            row[f"metrics.{metric}"] = math.sin(1.0 + index * 0.37 + k * 1.3) * (10.0 if k == 2 else 1.0)
    return row


def synthetic_runs() -> list[dict]:
    """Every group's seeds, each once superseded by a newer run, plus a failed and a train run to ignore."""
    rows = []
    for group in GROUPS:
        for seed in group[-1]:
            rows.append(_run(len(rows), group, seed))  # superseded by the next
            rows.append(_run(len(rows), group, seed))
        rows.append(_run(len(rows), group, 9, status="FAILED"))
    rows.append(_run(len(rows), GROUPS[0], 0, stage="train"))
    return rows


def slow_results(rows: list[dict]) -> list[dict]:
    """results.csv's rows recounted with plain Python: newest finished run per seed, then mean and stdev."""
    newest: dict[tuple, dict] = {}
    for row in rows:
        if row["status"] != "FINISHED" or row["tags.pasta.stage"] != "evaluate":
            continue
        group = (row["tags.pasta.task"], row["tags.pasta.profile"], row.get("tags.pasta.experiment", "main"),
                 row["tags.pasta.variant"], row["tags.pasta.sweep_value"], row.get("tags.pasta.plan", "learned"),
                 row["tags.pasta.executor"])
        key = (group, row["tags.pasta.seed"])
        if key not in newest or row["start_time"] > newest[key]["start_time"]:
            newest[key] = row
    seeds = defaultdict(list)
    for (group, _), row in newest.items():
        seeds[group].append(row)

    def values(group_rows: list[dict], metric: str) -> list[float]:
        return [r[f"metrics.{metric}"] for r in group_rows if f"metrics.{metric}" in r]

    def mean(xs: list[float]) -> float | None:
        return statistics.mean(xs) if xs else None

    def stdev(xs: list[float]) -> float | None:
        return statistics.stdev(xs) if len(xs) > 1 else None

    expected = []
    for group in sorted(seeds):
        runs = seeds[group]
        expected.append({**dict(zip(RESULT_COLUMNS[:7], group, strict=True)), "n_seeds": len(runs),
                         "performance_mean": mean(values(runs, "performance")),
                         "performance_std": stdev(values(runs, "performance")),
                         "success_mean": mean(values(runs, "success_rate")),
                         "success_std": stdev(values(runs, "success_rate")),
                         "planning_time_s": mean(values(runs, "planning_time_s")),
                         "emd_planned": mean(values(runs, "emd_planned_goal")),
                         "emd_reached": mean(values(runs, "emd_reached_goal"))})
    return expected


def test_results_csv_has_one_row_per_group_with_the_tables_aggregates():
    rows = synthetic_runs()
    text = results_csv(pd.DataFrame(rows)).decode()
    assert text.splitlines()[0] == ",".join(RESULT_COLUMNS) == (
        "task,profile,experiment,variant,sweep_value,plan,executor,n_seeds,performance_mean,performance_std,"
        "success_mean,success_std,planning_time_s,emd_planned,emd_reached")
    got = list(csv.DictReader(io.StringIO(text)))
    expected = slow_results(rows)
    assert len(got) == len(expected) == len(GROUPS)
    assert any(row["experiment"] == "main" and row["plan"] == "learned" and row["task"] == "GatherMove"
               for row in got)  # untagged runs count as main, learned
    for row, want in zip(got, expected, strict=True):
        for column in RESULT_COLUMNS[:7]:
            assert row[column] == want[column], (column, row)
        assert int(row["n_seeds"]) == want["n_seeds"]
        for column in RESULT_COLUMNS[8:]:
            if want[column] is None:
                assert row[column] == "", (column, row)
            else:
                assert float(row[column]) == pytest.approx(want[column], rel=1e-5, abs=1e-9), (column, row)


def test_results_csv_is_the_same_bytes_for_the_same_runs(tmp_path):
    runs = pd.DataFrame(synthetic_runs())
    first = save_results(runs, tmp_path).read_bytes()
    again = save_results(runs.sample(frac=1.0, random_state=1), tmp_path).read_bytes()  # rows in another order
    assert first == again == results_csv(runs)
    assert sorted(p.name for p in tmp_path.iterdir()) == [RESULTS_FILE]  # no temp file left
    assert results_csv(pd.DataFrame()).decode() == ",".join(RESULT_COLUMNS) + "\n"


def test_a_local_rebuild_leaves_the_published_reports_untouched(tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path)
    monkeypatch.delenv("PASTA_REPORTS_DIR", raising=False)
    published = paths.published_reports_dir()
    committed = {published / "CutRearrange" / "report.md": b"# the committed small report\n",
                 published / "CutRearrange" / "latent_space_pasta_small.png": b"\x89PNG committed small figure",
                 published / "summary" / "report.md": b"# the committed summary\n",
                 published / RESULTS_FILE: b"task\nCutRearrange\n"}
    for path, data in committed.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    stale = paths.reports_dir() / "CutRearrange" / "latent_space_pasta_small.png"  # an earlier local rebuild's
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"\x89PNG stale local figure")

    reports, written = write_reports(["CutRearrange", SUMMARY], pd.DataFrame(synthetic_runs()))

    local = tmp_path / "build" / "reports"
    assert [r.subject for r in reports] == ["CutRearrange", SUMMARY]
    assert written[-1] == local / RESULTS_FILE and (local / "CutRearrange" / "report.md") in written
    assert all(path.is_relative_to(local) for path in written)
    assert not stale.exists()  # stale figures go from the folder written, and only from it
    assert {path: path.read_bytes() for path in published.rglob("*") if path.is_file()} == committed
