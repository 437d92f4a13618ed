"""The appendix's tables rebuilt from evaluation runs: mean ± std over seeds, the paper's numbers beside; and
two of our own, the plan x executor matrix and the learned plans' quality against the ground truth.

Every builder takes the tidy frame of :func:`pasta.report.runs.evaluation_runs` restricted to one
profile and returns a :class:`Table` of strings. A row the paper has but no run produced says
``not run``; nothing raises on missing runs. The std is the sample std over seeds (``ddof=1``); a
single seed shows its value alone.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import pandas as pd

from pasta.report import paper_numbers as paper

NOT_RUN = "not run"
NO_VALUE = "—"
PAPER_VARIANT = "pasta"


@dataclass(frozen=True, eq=False)
class Table:
    """One report table: ``frame`` holds display strings, one row per item."""

    key: str
    title: str
    frame: pd.DataFrame
    note: str = ""

    def markdown(self) -> str:
        header = list(self.frame.columns)
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in self.frame.itertuples(index=False)]
        return "\n".join(lines)

    def records(self) -> list[dict[str, str]]:
        return [{str(k): str(v) for k, v in row.items()} for row in self.frame.to_dict(orient="records")]


def mean_std(values: pd.Series) -> tuple[float, float, int]:
    """``(mean, sample std, n)`` of the non-NaN values; std is NaN below 2 values, both NaN at 0."""
    v = pd.to_numeric(values, errors="coerce").dropna()
    n = len(v)
    if n == 0:
        return math.nan, math.nan, 0
    return float(v.mean()), float(v.std(ddof=1)) if n > 1 else math.nan, n


def cell(values: pd.Series, digits: int = 3, percent: bool = False) -> str:
    """``"mean ± std"`` of the values (``"80% ± 14%"`` with ``percent``); ``not run`` when there are none."""
    mean, std, n = mean_std(values)
    if n == 0:
        return NOT_RUN if len(values) == 0 else NO_VALUE
    scale, unit, places = (100.0, "%", 0) if percent else (1.0, "", digits)
    text = f"{mean * scale:.{places}f}{unit}"
    if n > 1:
        text += f" ± {std * scale:.{places}f}{unit}"
    return text


def _score_row(group: pd.DataFrame) -> dict[str, str]:
    return {"seeds": str(len(group)), "performance": cell(group["performance"]),
            "success": cell(group["success_rate"], percent=True)}


def _select(ev: pd.DataFrame, experiment: str, task: str | None = None, variant: str | None = None,
            sweep_value: str | None = None) -> pd.DataFrame:
    keep = ev["experiment"] == experiment
    if task is not None:
        keep &= ev["task"] == task
    if variant is not None:
        keep &= ev["variant"] == variant
    if sweep_value is not None:
        keep &= ev["sweep_value"] == sweep_value
    return ev[keep]


def _numeric_order(values: Iterable[str]) -> list[str]:
    """Sweep values sorted as numbers (non-numbers last, by name)."""
    def key(v: str) -> tuple[int, float, str]:
        try:
            return 0, float(v), v
        except ValueError:
            return 1, 0.0, v
    return sorted(set(values), key=key)


def _as_int(value: str) -> int | None:
    try:
        number = float(value)
    except ValueError:
        return None
    return int(number) if number.is_integer() else None


def main_table(ev: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """Per task (and variant) performance and success of the ``main`` experiment."""
    rows = []
    for task in tasks:
        runs = _select(ev, "main", task)
        variants = [PAPER_VARIANT] + sorted(set(runs["variant"]) - {PAPER_VARIANT})
        for variant in variants:
            score = paper.MAIN.get(task) if variant == PAPER_VARIANT else None
            rows.append({"task": task, "variant": variant, **_score_row(runs[runs["variant"] == variant]),
                         "paper": score.cell() if score else NO_VALUE})
    return Table("main", "Main results: normalised performance and success rate per task",
                 pd.DataFrame(rows, columns=["task", "variant", "seeds", "performance", "success", "paper"]),
                 "Paper: PASTA's result where the appendix states it (CutRearrange: Table 5; CRS: §4.5 and Table 8 "
                 "at horizon 3); "
                 "the main paper's per-task table is not in the appendix.")


def ablation_table(ev: pd.DataFrame, task: str = "CutRearrange") -> Table:
    """Appendix Table 5: the ablations (and Flat3D) of the ``ablation`` experiment."""
    runs = _select(ev, "ablation", task)
    variants = [*paper.TABLE5, "flat3d"]
    variants += sorted(set(runs["variant"]) - set(variants))
    rows = [{"variant": v, **_score_row(runs[runs["variant"] == v]),
             "paper (Table 5)": paper.TABLE5[v].cell() if v in paper.TABLE5 else NO_VALUE} for v in variants]
    return Table("table5", f"Table 5: ablations on {task} (performance / success)",
                 pd.DataFrame(rows, columns=["variant", "seeds", "performance", "success", "paper (Table 5)"]),
                 "Flat3D is a baseline of the main paper, not a row of Table 5.")


def _planning_runs(ev: pd.DataFrame, task: str) -> pd.DataFrame:
    """Planning-time runs of ``task``: the ``planning_time`` experiment if it ran, else ``main``."""
    dedicated = _select(ev, "planning_time", task, PAPER_VARIANT)
    return dedicated if not dedicated.empty else _select(ev, "main", task, PAPER_VARIANT)


def planning_time_table(ev: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """Appendix Table 6: planning time per task, seconds per test configuration."""
    rows = []
    for task in tasks:
        runs = _planning_runs(ev, task)
        seconds = paper.TABLE6_PLANNING_TIME_S.get(task)
        rows.append({"task": task, "seeds": str(len(runs)), "planning time (s)": cell(runs["planning_time_s"], 2),
                     "paper (s)": f"{seconds:g}" if seconds is not None else NO_VALUE})
    return Table("table6", "Table 6: planning time of PASTA per task",
                 pd.DataFrame(rows, columns=["task", "seeds", "planning time (s)", "paper (s)"]),
                 "Ours plan with the profile's number of samples and iterations on this machine; the paper's "
                 "used the full counts of Table 3 on a GPU.")


def emd_table(ev: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """Appendix Table 7: EMD of the planned and of the reached goal to the target."""
    rows = []
    for task in tasks:
        runs = _select(ev, "main", task, PAPER_VARIANT)
        planned, reached = paper.TABLE7_EMD_PLANNED.get(task), paper.TABLE7_EMD_REACHED.get(task)
        rows.append({"task": task, "seeds": str(len(runs)),
                     "EMD(planned, goal)": cell(runs["emd_planned_goal"], 4),
                     "EMD(reached, goal)": cell(runs["emd_reached_goal"], 4),
                     "paper planned": planned.cell() if planned else NO_VALUE,
                     "paper reached": reached.cell() if reached else NO_VALUE})
    columns = ["task", "seeds", "EMD(planned, goal)", "EMD(reached, goal)", "paper planned", "paper reached"]
    return Table("table7", "Table 7: EMD of the planned and the reached goal to the ground-truth goal",
                 pd.DataFrame(rows, columns=columns),
                 "The paper's values are from 4 real-world trajectories per task; ours are simulated.")


# PASTA's runs that differ from the main ones only in plan source and executor: the matrix's cells.
MATRIX_EXPERIMENTS = ("main", "scripted_executor", "oracle_plan")
MATRIX_PLANS = (("oracle", "oracle plan"), ("learned", "learned plan"))  # (pasta.plan tag, row label)
MATRIX_EXECUTORS = (("scripted", "scripted skills"), ("policy", "learned policies"))  # (pasta.executor, column)


def _matrix_cell(runs: pd.DataFrame) -> str:
    """Performance over the newest run of each seed, with the seed count; :data:`NO_VALUE` without runs."""
    newest = runs.sort_values(["start_time", "run_id"], kind="mergesort").drop_duplicates("seed", keep="last")
    if newest.empty:
        return NO_VALUE
    seeds = len(newest)
    return f"{cell(newest['performance'])} ({seeds} seed{'s' if seeds > 1 else ''})"


def matrix_table(cells: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """The plan x executor matrix (``docs/evaluation.md``): per task, performance with the oracle's or the
    planner's plan, run by the scripted skills or the learned policies.

    ``cells``: :func:`pasta.report.runs.evaluation_runs` with ``keys=CELL_KEYS``, so that runs of one experiment
    and seed with different executors both count. A cell takes PASTA's runs of :data:`MATRIX_EXPERIMENTS`.
    """
    pool = cells[cells["experiment"].isin(MATRIX_EXPERIMENTS) & (cells["variant"] == PAPER_VARIANT)
                 & (cells["sweep_value"] == "")]
    rows = []
    for task in tasks:
        for plan, plan_label in MATRIX_PLANS:
            row = {"task": task, "plan": plan_label}
            for executor, label in MATRIX_EXECUTORS:
                row[label] = _matrix_cell(pool[(pool["task"] == task) & (pool["plan"] == plan)
                                               & (pool["executor"] == executor)])
            rows.append(row)
    columns = ["task", "plan", *(label for _, label in MATRIX_EXECUTORS)]
    return Table("matrix", "Plan x executor: which half of the system loses the score",
                 pd.DataFrame(rows, columns=columns),
                 "Normalised performance, mean ± std over seeds. The oracle plan is the generator's own chain of "
                 "subgoals and attention; oracle plan with scripted skills is the physics ceiling, learned plan with "
                 f"learned policies is PASTA. Runs of the experiments {', '.join(MATRIX_EXPERIMENTS)}; "
                 f"{NO_VALUE}: no finished run of that cell.")


def plan_quality_table(ev: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """Learned plans against the generator's ground-truth chain (:mod:`pasta.evaluate.plan_diagnostics`): PASTA's
    main runs and every other experiment whose learned plans logged diagnostics."""
    rows = []
    for task in tasks:
        for experiment in ["main", *other_experiments(ev, [task])]:
            runs = _select(ev, experiment, task, PAPER_VARIANT)
            runs = runs[runs["plan"] == "learned"]
            if experiment != "main" and runs["plan_sequence_match_rate"].isna().all():
                continue
            rows.append({"task": task, "experiment": experiment, "seeds": str(len(runs)),
                         "skills = truth": cell(runs["plan_sequence_match_rate"], percent=True),
                         "attention = truth": cell(runs["plan_attention_match_rate"], percent=True),
                         "EMD(subgoal, truth)": cell(runs["plan_subgoal_emd"], 4),
                         "EMD(planned, goal)": cell(runs["emd_planned_goal"], 4),
                         "optimiser failed": cell(runs["plan_optimiser_failure_rate"], percent=True)})
    columns = ["task", "experiment", "seeds", "skills = truth", "attention = truth", "EMD(subgoal, truth)",
               "EMD(planned, goal)", "optimiser failed"]
    return Table("plan_quality", "Plan quality: the planner's plans against the ground-truth chain",
                 pd.DataFrame(rows, columns=columns),
                 "Per seed, over the test configurations: the share whose planned skills are the chain's, and whose "
                 "every step acts on the chain's pieces (a configuration without a plan counts as neither); the mean "
                 "EMD of each decoded subgoal to the chain's stage; and the share of planned configurations where "
                 "the planner's own objective scores the ground truth above its plan (the optimiser missed it; "
                 "otherwise the networks prefer the wrong plan). Mean ± std over seeds.")


# Experiments with their own table; every other ``pasta.experiment`` tag goes to ``experiments_table``.
TABULATED_EXPERIMENTS = ("main", "ablation", "planning_time", "sweep_samples", "sweep_horizon", "sweep_distractors",
                         "sweep_data")


def other_experiments(ev: pd.DataFrame, tasks: Sequence[str]) -> list[str]:
    """The experiment tags of ``tasks``' PASTA runs that no appendix table covers, sorted."""
    runs = ev[ev["task"].isin(list(tasks)) & (ev["variant"] == PAPER_VARIANT)]
    return sorted(set(runs["experiment"]) - set(TABULATED_EXPERIMENTS))


def experiments_table(ev: pd.DataFrame, tasks: Sequence[str]) -> Table:
    """The ``main`` PASTA runs beside every other experiment of the same task (a planner or executor option,
    e.g. ``decoded_cost`` or ``scripted_executor``): performance, success and EMD of the planned goal."""
    rows = []
    for task in tasks:
        for experiment in ["main", *other_experiments(ev, [task])]:
            runs = _select(ev, experiment, task, PAPER_VARIANT)
            if experiment != "main" or not runs.empty:
                rows.append({"task": task, "experiment": experiment, **_score_row(runs),
                             "EMD(planned, goal)": cell(runs["emd_planned_goal"], 4)})
    columns = ["task", "experiment", "seeds", "performance", "success", "EMD(planned, goal)"]
    return Table("experiments", "PASTA's main runs beside the other experiments of each task",
                 pd.DataFrame(rows, columns=columns),
                 "An experiment here changes one option of the main runs (its runs' parameters say which), e.g. "
                 "decoded_cost: plan.cost=decoded; scripted_executor: --executor scripted.")


def horizon_table(ev: pd.DataFrame, task: str = "CRS") -> Table:
    """Appendix Table 8: performance against the planning horizon (``sweep_horizon``)."""
    runs = _select(ev, "sweep_horizon", task, PAPER_VARIANT)
    horizons = _numeric_order([*(str(h) for h in paper.TABLE8_HORIZON), *runs["sweep_value"]])
    rows = []
    for h in horizons:
        score = paper.TABLE8_HORIZON.get(_as_int(h))
        rows.append({"horizon": h, **_score_row(runs[runs["sweep_value"] == h]),
                     "paper (Table 8)": score.cell() if score else NO_VALUE})
    return Table("table8", f"Table 8: PASTA on {task} against the planning horizon",
                 pd.DataFrame(rows, columns=["horizon", "seeds", "performance", "success", "paper (Table 8)"]))


def distractor_table(ev: pd.DataFrame, task: str = "CRS") -> Table:
    """§4.5: CRS without distractors (the ``main`` runs) and with them (``sweep_distractors``)."""
    sweep = _select(ev, "sweep_distractors", task, PAPER_VARIANT)
    rows = [{"distractors": "0", **_score_row(_select(ev, "main", task, PAPER_VARIANT)),
             "paper (§4.5)": paper.DISTRACTORS[0].cell()}]
    for value in _numeric_order([*(str(d) for d in paper.DISTRACTORS if d), *sweep["sweep_value"]]):
        score = paper.DISTRACTORS.get(_as_int(value))
        rows.append({"distractors": value, **_score_row(sweep[sweep["sweep_value"] == value]),
                     "paper (§4.5)": score.cell() if score else NO_VALUE})
    return Table("distractors", f"Robustness to distractors on {task} (§4.5)",
                 pd.DataFrame(rows, columns=["distractors", "seeds", "performance", "success", "paper (§4.5)"]))


def data_scale_table(ev: pd.DataFrame, task: str = "CutRearrange") -> Table:
    """Plan quality and performance against the number of demonstrations the models were trained on
    (``sweep_data``: one bundle per point, its learned plans run by the scripted skills; docs/planning.md)."""
    runs = _select(ev, "sweep_data", task, PAPER_VARIANT)
    rows = [{"demonstrations": value, "seeds": str(len(group)), "performance": cell(group["performance"]),
             "success": cell(group["success_rate"], percent=True),
             "skills = truth": cell(group["plan_sequence_match_rate"], percent=True),
             "EMD(subgoal, truth)": cell(group["plan_subgoal_emd"], 4),
             "EMD(planned, goal)": cell(group["emd_planned_goal"], 4)}
            for value in _numeric_order(runs["sweep_value"]) for group in [runs[runs["sweep_value"] == value]]]
    columns = ["demonstrations", "seeds", "performance", "success", "skills = truth", "EMD(subgoal, truth)",
               "EMD(planned, goal)"]
    if not rows:
        rows = [dict.fromkeys(columns, NOT_RUN) | {"demonstrations": NO_VALUE, "seeds": "0"}]
    return Table("data_scale", f"Plans against the number of demonstrations ({task})",
                 pd.DataFrame(rows, columns=columns),
                 "Each point trains the models on its own demonstrations (train + test trajectories) with the "
                 "same number of gradient steps, then runs the learned plans with the scripted skills, so the "
                 "score measures the plans alone. Mean ± std over evaluation seeds.")


def samples_stats(ev: pd.DataFrame, task: str = "CutRearrange") -> pd.DataFrame:
    """Fig. 2 data: per sample count, mean and std of planning time and performance over seeds."""
    runs = _select(ev, "sweep_samples", task, PAPER_VARIANT)
    rows = []
    for value in _numeric_order(runs["sweep_value"]):
        group = runs[runs["sweep_value"] == value]
        t_mean, t_std, n = mean_std(group["planning_time_s"])
        p_mean, p_std, _ = mean_std(group["performance"])
        rows.append({"samples": value, "seeds": len(group), "time_mean": t_mean, "time_std": t_std,
                     "performance_mean": p_mean, "performance_std": p_std})
    return pd.DataFrame(rows, columns=["samples", "seeds", "time_mean", "time_std", "performance_mean",
                                       "performance_std"])


def samples_table(ev: pd.DataFrame, task: str = "CutRearrange") -> Table:
    """Fig. 2 as a table: planning time and performance against the number of samples."""
    runs = _select(ev, "sweep_samples", task, PAPER_VARIANT)
    values = _numeric_order(runs["sweep_value"])
    rows = [{"samples": value, "seeds": str(len(group)), "planning time (s)": cell(group["planning_time_s"], 2),
             "performance": cell(group["performance"]), "success": cell(group["success_rate"], percent=True)}
            for value in values for group in [runs[runs["sweep_value"] == value]]]
    if not rows:
        rows = [{"samples": NO_VALUE, "seeds": "0", "planning time (s)": NOT_RUN, "performance": NOT_RUN,
                 "success": NOT_RUN}]
    return Table("fig2", f"Fig. 2: planning time and performance against the number of samples ({task})",
                 pd.DataFrame(rows, columns=["samples", "seeds", "planning time (s)", "performance", "success"]),
                 "The appendix plots Fig. 2 without printing its values (planning time grows about linearly "
                 "with the samples; mean and std over 5 runs).")
