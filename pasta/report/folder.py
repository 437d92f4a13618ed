"""A report folder: the report of each subject and ``results.csv``, all from one runs DataFrame.

A rebuild writes to the git-ignored local folder (:func:`pasta.paths.reports_dir`) unless it is handed
another one: the published reports in ``reports/`` came from a store that may no longer exist, so only an
explicit ``out_dir`` (``pasta report --publish``) replaces them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from pasta.paths import reports_dir
from pasta.report.document import FetchArtifact, Report, build_report, save_report
from pasta.report.results import save_results


def write_reports(subjects: Sequence[str], runs: pd.DataFrame, out_dir: str | Path | None = None,
                  fetch_artifact: FetchArtifact | None = None) -> tuple[list[Report], list[Path]]:
    """Build and save the report of each subject, then ``results.csv``, under ``out_dir``.

    ``out_dir`` defaults to :func:`pasta.paths.reports_dir`. Returns the reports and the written paths (each
    report's ``report.md`` before its PNGs, ``results.csv`` last). Only ``out_dir`` is touched: stale PNGs are
    removed from its subject folders, never from another report folder.
    """
    folder = Path(out_dir) if out_dir is not None else reports_dir()
    reports = [build_report(subject, runs, fetch_artifact) for subject in subjects]
    written = [path for report in reports for path in save_report(report, folder)]
    return reports, [*written, save_results(runs, folder)]
