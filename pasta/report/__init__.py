"""Reports: the appendix's tables and figures rebuilt from MLflow runs, the paper's numbers beside.

``write_report(subject, runs, out_dir)`` writes ``<out_dir>/<subject>/report.md`` and its PNGs from a runs
DataFrame (``load_runs`` reads one from MLflow through ``pasta.tracking``); ``subject`` is a task name or
``"summary"`` (every task). ``write_reports(subjects, runs)`` writes several and ``results.csv`` (one row per
group of evaluation runs) into the git-ignored local folder, or into the ``out_dir`` it is given.
"""

from pasta.report.document import SUMMARY, Report, build_report, save_report, subject_tasks, write_report
from pasta.report.folder import write_reports
from pasta.report.results import RESULT_COLUMNS, RESULTS_FILE, results_csv, results_table, save_results
from pasta.report.runs import evaluation_runs, load_runs

__all__ = ["RESULTS_FILE", "RESULT_COLUMNS", "SUMMARY", "Report", "build_report", "evaluation_runs", "load_runs",
           "results_csv", "results_table", "save_report", "save_results", "subject_tasks", "write_report",
           "write_reports"]
