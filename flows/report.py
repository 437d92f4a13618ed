"""Prefect flow: rebuild the reports from MLflow alone, without rerunning anything.

    pasta report                      # every task with runs, plus summary/, into build/reports (git-ignored)
    pasta report --task CutRearrange  # that task's report, plus summary/
    pasta report --publish            # into the committed reports/ instead
    pasta report --out DIR            # into DIR

Each report is ``<out>/<task or summary>/report.md`` with its PNGs, beside ``<out>/results.csv`` for every
task (``pasta.report``). ``<out>`` is ``pasta.paths.reports_dir()`` unless the caller names one, so a local
rebuild never replaces the published reports. The same tables are published as Prefect table artifacts and
the whole report as a markdown artifact.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import mlflow
import pandas as pd
from mlflow.exceptions import MlflowException
from prefect import flow
from prefect.artifacts import create_markdown_artifact, create_table_artifact

from pasta import tracking
from pasta.config.schema import TASK_NAMES
from pasta.report import SUMMARY, Report, load_runs, subject_tasks, write_reports


def artifact_bytes(run_id: str, artifact_path: str) -> bytes | None:
    """One artifact file of an MLflow run, or None when the run has no such file."""
    tracking.configure()
    with tempfile.TemporaryDirectory() as folder:
        try:
            local = mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=artifact_path, dst_path=folder)
        except (MlflowException, OSError):
            return None
        return Path(local).read_bytes()


def artifact_key(*parts: str) -> str:
    """A Prefect artifact key (lowercase letters, digits and dashes) from name parts."""
    return "-".join(re.sub(r"[^a-z0-9]+", "-", part.lower()).strip("-") for part in parts if part)


def publish(report: Report) -> None:
    """The report as a Prefect markdown artifact and each of its tables as a table artifact."""
    create_markdown_artifact(markdown=report.markdown, key=artifact_key("report", report.subject),
                             description=f"PASTA report: {report.subject}")
    for profile, table in report.tables:
        create_table_artifact(table=table.records(), key=artifact_key(report.subject, profile or "", table.key),
                              description=table.title)


def subjects_with_runs(runs: pd.DataFrame) -> list[str]:
    """The tasks that have at least one run, in the order of ``TASK_NAMES``."""
    if runs.empty or "tags.pasta.task" not in runs.columns:
        return []
    present = set(runs["tags.pasta.task"].dropna())
    return [task for task in TASK_NAMES if task in present]


@flow(name="report", flow_run_name="report-{task}")
def report(task: str | None = None, out_dir: str | None = None) -> list[Path]:
    """Write the report of ``task`` (or of every task with runs), the summary and ``results.csv`` under
    ``out_dir`` (default: the git-ignored ``pasta.paths.reports_dir()``); returns the files written."""
    runs = load_runs(TASK_NAMES)  # all tasks: the summary needs them, and CRS-Twice plans with CRS's models
    subjects = [*([task] if task else subjects_with_runs(runs)), SUMMARY]
    reports, written = write_reports(subjects, runs, out_dir, artifact_bytes)
    for built in reports:
        publish(built)
    return written


def run(task: str | None = None, out_dir: str | None = None) -> list[Path]:
    """The CLI's entry point: refuse an unknown task before starting Prefect, then run :func:`report`."""
    if task is not None:
        subject_tasks(task)
    return report(task, out_dir)
