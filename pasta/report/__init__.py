"""Reports: the appendix's tables and figures rebuilt from MLflow runs, the paper's numbers beside.

``write_report(subject, runs, out_dir)`` writes ``<out_dir>/<subject>/report.md`` and its PNGs from a runs
DataFrame (``load_runs`` reads one from MLflow through ``pasta.tracking``); ``subject`` is a task name or
``"summary"`` (every task).
"""

from pasta.report.document import SUMMARY, Report, build_report, save_report, subject_tasks, write_report
from pasta.report.runs import evaluation_runs, load_runs

__all__ = ["SUMMARY", "Report", "build_report", "evaluation_runs", "load_runs", "save_report", "subject_tasks",
           "write_report"]
