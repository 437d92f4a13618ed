"""One report: markdown tables and PNG figures for a task (or the summary of all tasks), from runs alone.

A report is a pure function of the runs DataFrame (and the latent-space and plan-strip artifacts it
names), with no time stamps, so a report rebuilt from MLflow equals the one written when the runs finished. Files are
written atomically (temp file, rename) and figures of an earlier report that no longer belong are removed.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from pasta.config.schema import PROFILE_NAMES, TASK_NAMES
from pasta.data.storage import atomic_write_bytes
from pasta.report import figures, tables
from pasta.report.runs import CELL_KEYS, evaluation_runs, newest_train_run, profiles

SUMMARY = "summary"  # the subject of the report over every task
REPORT_FILE = "report.md"
PROFILE_ORDER = tuple(reversed(PROFILE_NAMES))  # paper, small, smoke: the largest first
# (variant, figure label) of the latent-space figures: Fig. 3 is PASTA's, Fig. 4 Flat3D's.
LATENT_FIGURES = (("pasta", "Fig. 3"), ("flat3d", "Fig. 4"))
EVALUATION_TABLE = "tables/evaluation.json"  # logged by the evaluate flow, one row per configuration

FetchArtifact = Callable[[str, str], bytes | None]  # (run_id, artifact path) -> file bytes or None


@dataclass(frozen=True, eq=False)
class Report:
    """``markdown`` refers to ``figures`` by file name; ``tables`` are ``(profile, table)`` pairs."""

    subject: str
    markdown: str
    tables: tuple[tuple[str | None, tables.Table], ...]
    figures: dict[str, bytes] = field(default_factory=dict)


def subject_tasks(subject: str) -> tuple[str, ...]:
    """The tasks a report covers: one task, or all of them for :data:`SUMMARY`."""
    if subject == SUMMARY:
        return TASK_NAMES
    if subject not in TASK_NAMES:
        raise ValueError(f"unknown report subject {subject!r}; known: {', '.join((*TASK_NAMES, SUMMARY))}")
    return (subject,)


def _profile_tables(ev: pd.DataFrame, cells: pd.DataFrame, tasks: tuple[str, ...]) -> list[tables.Table]:
    found = [tables.main_table(ev, tasks), tables.matrix_table(cells, tasks), tables.plan_quality_table(ev, tasks),
             tables.planning_time_table(ev, tasks), tables.emd_table(ev, tasks)]
    if "CutRearrange" in tasks:
        found += [tables.ablation_table(ev), tables.samples_table(ev), tables.data_scale_table(ev)]
    if "CRS" in tasks:
        found += [tables.horizon_table(ev), tables.distractor_table(ev)]
    if tables.other_experiments(ev, tasks):
        found.append(tables.experiments_table(ev, tasks))
    return found


def _latent_section(runs: pd.DataFrame, task: str, profile: str, fetch: FetchArtifact | None
                    ) -> tuple[list[str], dict[str, bytes]]:
    lines, pngs = [], {}
    for variant, label in LATENT_FIGURES:
        lines += [f"### {label}: latent space of `{variant}` ({task})", ""]
        run_id = newest_train_run(runs, task, profile, variant)
        data = fetch(run_id, figures.LATENT_ARTIFACT) if run_id and fetch else None
        if data is None:
            lines.append(f"{tables.NOT_RUN}: no finished `{variant}` train run with `{figures.LATENT_ARTIFACT}`.")
        else:
            name = f"latent_space_{variant}_{profile}.png"
            pngs[name] = data
            lines.append(f"![{label}: latent space of {variant}]({name})\n\nFrom train run `{run_id}`.")
        lines.append("")
    return lines, pngs


def best_executed_plan(ev: pd.DataFrame, task: str, fetch: FetchArtifact) -> tuple[str, dict, bytes] | None:
    """The image strip of the best-scoring configuration of ``task``'s main PASTA evaluation, lowest seed.

    ``ev``: one profile's rows of :func:`evaluation_runs`. Returns (run id, that configuration's table row,
    the PNG), or None where there is no such run or its artifacts are missing.
    """
    rows = ev[(ev["task"] == task) & (ev["variant"] == "pasta") & (ev["experiment"] == "main")
              & (ev["sweep_value"] == "")]
    if rows.empty:
        return None
    first = rows.assign(_seed=pd.to_numeric(rows["seed"], errors="coerce")).sort_values(["_seed", "run_id"]).iloc[0]
    table = fetch(first["run_id"], EVALUATION_TABLE)
    if table is None:
        return None
    configurations = json.loads(table)
    if not configurations:
        return None
    best = max(configurations, key=lambda row: (row["performance"], -row["config_id"]))
    strip = fetch(first["run_id"], f"figures/plan_config_{best['config_id']}.png")
    return None if strip is None else (str(first["run_id"]), best, strip)


def _plan_section(ev: pd.DataFrame, task: str, profile: str, fetch: FetchArtifact | None
                  ) -> tuple[list[str], dict[str, bytes]]:
    lines = [f"### An executed plan ({task})", ""]
    found = best_executed_plan(ev, task, fetch) if fetch else None
    if found is None:
        return [*lines, f"{tables.NOT_RUN}: no finished main `pasta` evaluation of {task} with its strips.", ""], {}
    run_id, row, strip = found
    name = f"executed_plan_{task}_{profile}.png"
    caption = (f"Initial state, the decoded subgoals of `{' -> '.join(row['skills'])}`, the reached state over "
               f"the target, and the target: configuration {row['config_id']}, the best of its seed "
               f"(performance {row['performance']:.3f}), evaluate run `{run_id}`.")
    return [*lines, f"![executed plan of {task}]({name})", "", caption, ""], {name: strip}


def build_report(subject: str, runs: pd.DataFrame, fetch_artifact: FetchArtifact | None = None) -> Report:
    """The report of ``subject`` (a task name or :data:`SUMMARY`) from MLflow runs of any stages.

    ``runs``: rows as ``mlflow.search_runs`` returns them (tags ``tags.pasta.*``, ``metrics.*``, ``status``,
    ``start_time``, ``run_id``). ``fetch_artifact(run_id, path)`` supplies artifacts: the latent-space PNG of a
    train run, the table and plan strips of an evaluate run (an executed plan; CRS's in the summary).
    """
    tasks = subject_tasks(subject)
    ev_all = evaluation_runs(runs)
    ev_all = ev_all[ev_all["task"].isin(tasks)]
    cells_all = evaluation_runs(runs, keys=CELL_KEYS)
    cells_all = cells_all[cells_all["task"].isin(tasks)]
    command = "pasta report" + ("" if subject == SUMMARY else f" --task {subject}")
    lines = [f"# PASTA report: {'all tasks' if subject == SUMMARY else subject}", "",
             f"Built from MLflow runs alone (`{command}` rebuilds it). Cells are mean ± std over evaluation "
             "seeds (the newest finished run of each seed); success is the share of the 5 test configurations "
             f"within the task's threshold. `{tables.NOT_RUN}`: no finished run yet. The appendix's numbers "
             "are beside ours.", ""]
    found: list[tuple[str | None, tables.Table]] = []
    pngs: dict[str, bytes] = {}
    for profile in profiles(runs, tasks, PROFILE_ORDER) or [None]:
        ev = ev_all[ev_all["profile"] == profile]
        cells = cells_all[cells_all["profile"] == profile]
        lines += [f"## Profile `{profile}`" if profile else "## No finished runs yet", ""]
        for table in _profile_tables(ev, cells, tasks):
            found.append((profile, table))
            lines += [f"### {table.title}", "", table.markdown(), ""]
            if table.note:
                lines += [table.note, ""]
            if table.key == "fig2" and profile:
                for name, png in figures.fig2_pngs(tables.samples_stats(ev)).items():
                    pngs[f"{name}_{profile}.png"] = png
                    lines += [f"![{name}]({name}_{profile}.png)", ""]
        if profile:
            plan_task = "CRS" if subject == SUMMARY else subject
            plan_lines, plan_pngs = _plan_section(ev, plan_task, profile, fetch_artifact)
            lines += plan_lines
            pngs.update(plan_pngs)
            latent_task = "CutRearrange" if subject == SUMMARY else subject
            latent_lines, latent_pngs = _latent_section(runs, latent_task, profile, fetch_artifact)
            lines += latent_lines
            pngs.update(latent_pngs)
    return Report(subject, "\n".join(lines).rstrip() + "\n", tuple(found), pngs)


def save_report(report: Report, out_dir: str | Path) -> list[Path]:
    """Write ``<out_dir>/<subject>/report.md`` and its PNGs atomically; returns the paths, report first.

    PNGs left from an earlier report of the same subject that this one no longer has are removed.
    """
    folder = Path(out_dir) / report.subject
    folder.mkdir(parents=True, exist_ok=True)
    written = [atomic_write_bytes(folder / name, lambda handle, data=data: handle.write(data))
               for name, data in sorted(report.figures.items())]
    for stale in sorted(set(folder.glob("*.png")) - set(written)):
        stale.unlink()
    markdown = atomic_write_bytes(folder / REPORT_FILE, lambda handle: handle.write(report.markdown.encode()))
    return [markdown, *written]


def write_report(subject: str, runs: pd.DataFrame, out_dir: str | Path,
                 fetch_artifact: FetchArtifact | None = None) -> list[Path]:
    """:func:`build_report` then :func:`save_report`; returns the written paths, ``report.md`` first."""
    return save_report(build_report(subject, runs, fetch_artifact), out_dir)
