"""Reports from synthetic runs logged to a real (temporary) MLflow store: numbers, "not run", determinism."""

from __future__ import annotations

import json
import re
import time

import pandas as pd
import pytest

from pasta import tracking
from pasta.report import SUMMARY, build_report, evaluation_runs, load_runs, tables, write_report
from pasta.report import paper_numbers as paper

# (experiment, variant, seed, sweep value, performance, success rate, planning time)
EVAL_RUNS = [
    ("ablation", "pasta", 0, "", 0.9, 1.0, 2.0),
    ("ablation", "pasta", 1, "", 0.7, 0.6, 4.0),
    ("ablation", "pasta", 2, "", 0.8, 0.8, 6.0),
    ("ablation", "tool_concat_policy", 0, "", 0.5, 0.4, 3.0),
    ("main", "pasta", 0, "", 0.6, 0.4, 10.0),
    ("main", "pasta", 1, "", 0.2, 0.2, 20.0),
    ("sweep_samples", "pasta", 0, "10", 0.1, 0.0, 1.0),
    ("sweep_samples", "pasta", 1, "10", 0.3, 0.2, 3.0),
    ("sweep_samples", "pasta", 0, "100", 0.5, 0.4, 10.0),
    ("decoded_cost", "pasta", 0, "", 0.7, 0.8, 5.0),
    ("decoded_cost", "pasta", 1, "", 0.5, 0.6, 5.0),
]


def _log(task: str, stage: str, variant: str, seed: int | None, metrics: dict, experiment: str = "",
         sweep_value: str = "", status: str = "FINISHED", profile: str = "smoke") -> str:
    tags = {"pasta.experiment": experiment, "pasta.sweep_value": sweep_value} if stage == "evaluate" else {}
    with tracking.run(task, stage, profile=profile, variant=variant, seed=seed, extra_tags=tags) as active:
        tracking.log_metrics(metrics)
        run_id = active.info.run_id
    if status != "FINISHED":
        import mlflow

        mlflow.MlflowClient().set_terminated(run_id, status=status)
    time.sleep(0.002)  # distinct start times: the newest run of a seed must win
    return run_id


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A temporary MLflow store holding the synthetic runs; yields the runs DataFrame read back from it."""
    folder = tmp_path_factory.mktemp("mlflow")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{folder / 'mlflow.db'}")
        # An older run of ablation/pasta seed 0 (superseded) and a failed one (ignored).
        _log("CutRearrange", "evaluate", "pasta", 0, {"performance": -1.0, "success_rate": 0.0}, "ablation")
        _log("CutRearrange", "evaluate", "pasta", 3, {"performance": -5.0, "success_rate": 0.0}, "ablation",
             status="FAILED")
        for experiment, variant, seed, value, perf, success, seconds in EVAL_RUNS:
            _log("CutRearrange", "evaluate", variant, seed,
                 {"performance": perf, "success_rate": success, "planning_time_s": seconds,
                  "emd_planned_goal": 0.01 * (seed + 1), "emd_reached_goal": 0.02 * (seed + 1)},
                 experiment, value)
        _log("CRS", "evaluate", "pasta", 0, {"performance": 0.5, "success_rate": 0.6}, "sweep_horizon", "4")
        old = _log("CutRearrange", "train", "pasta", None, {"cost_r2": 0.5})
        new = _log("CutRearrange", "train", "pasta", None, {"cost_r2": 0.6})
        runs = load_runs(["CutRearrange", "CRS", "GatherMove"])
        yield {"runs": runs, "old_train": old, "new_train": new}


def _row(table: tables.Table, column: str, value: str) -> dict:
    rows = table.frame[table.frame[column] == value]
    assert len(rows) == 1, f"expected one row {column}={value} in {table.key}, got {len(rows)}"
    return rows.iloc[0].to_dict()


def test_evaluation_runs_keep_the_newest_finished_run_per_seed(store):
    ev = evaluation_runs(store["runs"])
    assert len(ev) == len(EVAL_RUNS) + 1  # the superseded and the failed run are gone, the CRS one counts
    pasta0 = ev[(ev["experiment"] == "ablation") & (ev["variant"] == "pasta") & (ev["seed"] == "0")]
    assert pasta0["performance"].tolist() == [0.9]
    assert "3" not in set(ev["seed"])


def test_ablation_table_has_mean_and_std_over_seeds(store):
    table = tables.ablation_table(evaluation_runs(store["runs"]))
    # performance 0.9, 0.7, 0.8: mean 0.8, sample std sqrt(((0.1)^2 + (0.1)^2 + 0) / 2) = 0.1
    # success 1.0, 0.6, 0.8: mean 80 %, std 20 %
    assert _row(table, "variant", "pasta") == {"variant": "pasta", "seeds": "3", "performance": "0.800 ± 0.100",
                                               "success": "80% ± 20%", "paper (Table 5)": "0.837 / 80%"}
    single = _row(table, "variant", "tool_concat_policy")
    assert (single["seeds"], single["performance"], single["success"]) == ("1", "0.500", "40%")
    missing = _row(table, "variant", "shared_encoder_policy")
    assert (missing["performance"], missing["success"], missing["paper (Table 5)"]) == (
        "not run", "not run", "-0.304 / 0%")
    assert table.frame["variant"].tolist()[:5] == list(paper.TABLE5)


def test_main_planning_time_and_emd_tables(store):
    ev = evaluation_runs(store["runs"])
    main = tables.main_table(ev, ["CutRearrange", "LiftSpread"])
    # performance 0.6, 0.2: mean 0.4, std sqrt(0.08) = 0.2828; success 0.4, 0.2: 30 % ± 14 %
    assert _row(main, "task", "CutRearrange")["performance"] == "0.400 ± 0.283"
    assert _row(main, "task", "CutRearrange")["success"] == "30% ± 14%"
    assert _row(main, "task", "LiftSpread")["performance"] == "not run"
    time_table = tables.planning_time_table(ev, ["CutRearrange", "CRS-Twice"])
    assert _row(time_table, "task", "CutRearrange")["planning time (s)"] == "15.00 ± 7.07"  # 10, 20
    assert _row(time_table, "task", "CRS-Twice") == {"task": "CRS-Twice", "seeds": "0", "planning time (s)": "not run",
                                                     "paper (s)": "7810"}
    emd = _row(tables.emd_table(ev, ["CutRearrange"]), "task", "CutRearrange")
    # seeds 0, 1 of main: planned 0.01, 0.02 -> 0.0150 ± 0.0071; reached 0.02, 0.04 -> 0.0300 ± 0.0141
    assert (emd["EMD(planned, goal)"], emd["EMD(reached, goal)"]) == ("0.0150 ± 0.0071", "0.0300 ± 0.0141")
    assert (emd["paper planned"], emd["paper reached"]) == ("0.038 ± 0.004", "0.056 ± 0.007")


def test_other_experiments_sit_beside_the_main_runs(store):
    ev = evaluation_runs(store["runs"])
    assert tables.other_experiments(ev, ["CutRearrange", "CRS"]) == ["decoded_cost"]
    table = tables.experiments_table(ev, ["CutRearrange", "GatherMove"])
    assert table.frame["experiment"].tolist() == ["main", "decoded_cost"]  # GatherMove has no runs: no rows
    decoded = _row(table, "experiment", "decoded_cost")
    # performance 0.7, 0.5 -> 0.600 ± 0.141; success 80 %, 60 % -> 70% ± 14%; planned EMD 0.01, 0.02
    assert (decoded["seeds"], decoded["performance"], decoded["success"], decoded["EMD(planned, goal)"]) == (
        "2", "0.600 ± 0.141", "70% ± 14%", "0.0150 ± 0.0071")
    assert _row(table, "experiment", "main")["performance"] == "0.400 ± 0.283"


def test_sweep_tables_and_figure_data(store):
    ev = evaluation_runs(store["runs"])
    stats = tables.samples_stats(ev)
    assert stats["samples"].tolist() == ["10", "100"]  # numeric order
    assert stats["time_mean"].tolist() == [2.0, 10.0]
    assert stats["time_std"].iloc[0] == pytest.approx(2 ** 0.5)
    assert stats["performance_mean"].iloc[0] == pytest.approx(0.2)
    assert pd.isna(stats["performance_std"].iloc[1])  # one seed: no std
    horizon = tables.horizon_table(ev)
    assert horizon.frame["horizon"].tolist() == ["3", "4", "5", "6"]
    assert _row(horizon, "horizon", "4") == {"horizon": "4", "seeds": "1", "performance": "0.500", "success": "60%",
                                             "paper (Table 8)": "0.866 / 4/5"}
    assert _row(horizon, "horizon", "5")["performance"] == "not run"
    distractors = tables.distractor_table(ev)
    assert distractors.frame["distractors"].tolist() == ["0", "2"]
    assert _row(distractors, "distractors", "2")["paper (§4.5)"] == "0.879 / 100%"


def test_missing_runs_give_not_run_rows_not_errors(tmp_path):
    report = build_report(SUMMARY, pd.DataFrame())
    assert "## No finished runs yet" in report.markdown
    for _, table in report.tables:
        metric_columns = [c for c in table.frame.columns if c not in {"task", "variant", "seeds", "horizon",
                                                                       "distractors", "samples", "demonstrations",
                                                                       "plan", "experiment"}
                          and not c.startswith("paper")]
        empty = tables.NO_VALUE if table.key == "matrix" else "not run"  # the matrix marks an empty cell "—"
        assert (table.frame[metric_columns] == empty).all().all(), table.key
    assert report.figures == {}
    paths = write_report("CRS-Twice", pd.DataFrame(), tmp_path)
    assert paths == [tmp_path / "CRS-Twice" / "report.md"]
    assert "not run" in paths[0].read_text()
    with pytest.raises(ValueError, match="CutRearrange"):
        build_report("CutRearange", pd.DataFrame())


def test_report_is_deterministic_and_replaces_its_old_files(store, tmp_path):
    latent = {store["new_train"]: b"new latent png", store["old_train"]: b"old latent png"}
    ev = evaluation_runs(store["runs"])
    main_seed0 = ev[(ev["experiment"] == "main") & (ev["seed"] == "0")]["run_id"].item()
    evaluation = {"tables/evaluation.json": json.dumps([
        {"config_id": 0, "skills": ["cut", "rearrange"], "performance": 0.3},
        {"config_id": 1, "skills": ["rearrange", "cut"], "performance": 0.8},
        {"config_id": 2, "skills": ["cut", "cut"], "performance": 0.8}]).encode(),
        "figures/plan_config_1.png": b"strip of configuration 1"}

    def fetch(run_id, path):
        if path == "figures/latent_space.png":
            return latent.get(run_id)
        return evaluation.get(path) if run_id == main_seed0 else None

    first = write_report("CutRearrange", store["runs"], tmp_path / "a", fetch)
    again = write_report("CutRearrange", store["runs"], tmp_path / "b", fetch)
    assert [p.name for p in first] == [p.name for p in again]
    assert [p.read_bytes() for p in first] == [p.read_bytes() for p in again]
    names = {p.name for p in first}
    assert {"report.md", "fig2a_planning_time_smoke.png", "fig2b_performance_smoke.png",
            "latent_space_pasta_smoke.png", "executed_plan_CutRearrange_smoke.png"} == names
    folder = tmp_path / "a" / "CutRearrange"
    assert (folder / "latent_space_pasta_smoke.png").read_bytes() == b"new latent png"
    # The best configuration of the lowest main seed (ties go to the lower configuration id).
    assert (folder / "executed_plan_CutRearrange_smoke.png").read_bytes() == b"strip of configuration 1"
    assert (folder / "fig2a_planning_time_smoke.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    markdown = (folder / "report.md").read_text()
    for image in re.findall(r"!\[[^]]*\]\(([^)]+)\)", markdown):
        assert (folder / image).exists(), image
    assert "no finished `flat3d` train run" in markdown
    assert "`rearrange -> cut`" in markdown and "configuration 1, the best of its seed" in markdown
    assert main_seed0 in markdown

    without_sweeps = store["runs"][store["runs"]["tags.pasta.experiment"] != "sweep_samples"]
    write_report("CutRearrange", without_sweeps, tmp_path / "a")
    assert sorted(p.name for p in folder.iterdir()) == ["report.md"]  # stale figures gone, no temp files


def test_paper_numbers_agree_with_their_printed_cells():
    scores = [*paper.TABLE5.values(), *paper.TABLE8_HORIZON.values(), *paper.DISTRACTORS.values()]
    for score in scores:
        performance, success = score.printed.split(" / ")
        assert float(performance) == score.performance
        if success.endswith("%"):
            assert float(success[:-1]) / 100 == pytest.approx(score.success_rate)
        else:
            done, total = success.split("/")
            assert int(done) / int(total) == pytest.approx(score.success_rate)
