"""The evaluation flow: a real Prefect flow run with untrained models, recorded in a temporary MLflow store."""

from __future__ import annotations

import json

import mlflow
import numpy as np
import pytest

from pasta.cli import build_parser
from pasta.config import load
from pasta.evaluate.metrics import PLAN_QUALITY
from pasta.models.latent_prior import LatentPrior
from pasta.paths import checkpoint_dir
from pasta.train.bundle import save_trained, untrained

pytestmark = pytest.mark.flow

# The smoke simulator (grid 32, 2000 particles) with two configurations, 2-step skills and a tiny planner.
OVERRIDES = ("sim.steps_per_skill=2", "sim.settle_steps=1", "plan.samples=8", "plan.iterations=2",
             "data.n_eval_configs=2")


def test_evaluation_flow_plans_executes_and_logs_every_metric(prefect_server, isolated_store):
    from flows import evaluate as evaluate_flow

    _, uri = isolated_store
    cfg = load("CutRearrange", "smoke", list(OVERRIDES))
    _save_untrained_bundle()

    summary = evaluate_flow.run("CutRearrange", "smoke", seeds=[3], overrides=OVERRIDES, experiment="ablation",
                                sweep_value="150")
    assert summary["seeds"] == [3] and summary["executor"] == "policy"
    assert np.isfinite(summary["performance_mean"]) and summary["performance_std"] == 0.0
    assert 0.0 <= summary["success_mean"] <= 1.0

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["pasta/CutRearrange"])
    assert len(runs) == 1
    run = runs.iloc[0]
    assert run["tags.pasta.stage"] == "evaluate" and run["tags.pasta.seed"] == "3"
    assert run["tags.pasta.experiment"] == "ablation" and run["tags.pasta.variant"] == "pasta"
    assert run["tags.pasta.sweep_value"] == "150"
    names = ["performance", "success_rate", "planning_time_s", "emd_planned_goal", "emd_reached_goal", "emd_initial"]
    names += [f"{m}_config_{i}" for m in ("performance", "success", "planning_time_s") for i in (0, 1)]
    names += list(PLAN_QUALITY)  # a learned plan's diagnostics against the ground truth
    names += [f"{m}_config_{i}" for m in ("plan_sequence_match", "plan_score", "plan_ground_truth_score")
              for i in (0, 1)]
    for name in names:
        assert np.isfinite(run[f"metrics.{name}"]), name
    assert run["metrics.performance"] == pytest.approx(summary["performance_mean"])
    per_config = [run[f"metrics.success_config_{i}"] for i in (0, 1)]
    assert set(per_config) <= {0.0, 1.0}
    assert summary["success_mean"] == pytest.approx(np.mean(per_config))  # one seed: the mean over configurations
    assert run["metrics.success_rate"] == pytest.approx(summary["success_mean"])
    assert run["metrics.emd_initial"] > 0
    duration = (run["end_time"] - run["start_time"]).total_seconds()
    assert duration == pytest.approx(summary["wall_s"], rel=0.1)  # the run spans the evaluation it records

    client = mlflow.tracking.MlflowClient(uri)
    run_id = run["run_id"]
    table = json.loads(open(client.download_artifacts(run_id, "tables/evaluation.json")).read())
    assert [row["config_id"] for row in table] == [0, 1]
    assert [float(row["success"]) for row in table] == per_config
    assert all(len(row["skills"]) == cfg.horizon and row["emd_reached_goal"] == row["emd_final"] for row in table)
    assert [row["sequence_match"] for row in table] == [run[f"metrics.plan_sequence_match_config_{i}"] for i in (0, 1)]
    figures = {f.path for f in client.list_artifacts(run_id, "figures")}
    assert figures == {"figures/plan_config_0.png", "figures/plan_config_1.png"}


def test_bad_arguments_are_refused_before_anything_runs(isolated_store):
    from flows import evaluate as evaluate_flow

    with pytest.raises(ValueError, match="'magic'"):
        evaluate_flow.run("CutRearrange", "smoke", executor="magic")
    with pytest.raises(ValueError, match="CutRearange"):
        evaluate_flow.run("CutRearange", "smoke")


def test_cli_evaluate_arguments():
    args = build_parser().parse_args(["evaluate", "--task", "CRS", "--executor", "scripted", "--seeds", "0", "2",
                                      "--set", "plan.samples=8"])
    assert (args.task, args.profile, args.variant, args.executor, args.seeds) == ("CRS", "smoke", "pasta",
                                                                                 "scripted", [0, 2])
    assert args.set == ["plan.samples=8"] and args.experiment is None and args.plan == "learned"
    assert (args.workers, args.dask_address, args.sweep_value) == (1, None, None)
    assert build_parser().parse_args(["evaluate", "--task", "CRS", "--sweep-value", "150"]).sweep_value == "150"
    assert build_parser().parse_args(["evaluate", "--task", "CRS"]).seeds is None
    on_dask = build_parser().parse_args(["evaluate", "--task", "CRS", "--dask-address", "tcp://scheduler:8786"])
    assert on_dask.dask_address == "tcp://scheduler:8786"


def test_cli_oracle_plan_runs_without_models_and_ends_with_one_json_line(prefect_server, isolated_store, capsys):
    """``pasta evaluate --plan oracle --executor scripted``: no trained models on disk, runs tagged with the plan
    and the oracle_plan experiment, and the last line of standard output is the one-line JSON summary."""
    from pasta.cli import main

    _, uri = isolated_store
    argv = ["evaluate", "--task", "CutRearrange", "--plan", "oracle", "--executor", "scripted", "--seeds", "1"]
    for override in OVERRIDES:
        argv += ["--set", override]
    assert main(argv) == 0
    out = capsys.readouterr().out
    line = json.loads(out.strip().splitlines()[-1])
    assert (line["task"], line["profile"], line["plan"], line["executor"], line["seeds"]) == (
        "CutRearrange", "smoke", "oracle", "scripted", [1])
    assert "CutRearrange evaluation (pasta, oracle plan, scripted)" in out  # the bar over the configurations
    assert f"mean performance {line['performance_mean']:.3f}" in out  # one seed: the bar's mean is the seed's
    assert f"performance {line['performance_mean']:.3f} ± 0.000, success" in out.split(
        "evaluate CutRearrange pasta done in")[1]  # the stage's one-line summary

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["pasta/CutRearrange"])
    assert len(runs) == 1
    run = runs.iloc[0]
    assert run["tags.pasta.plan"] == "oracle" and run["tags.pasta.experiment"] == "oracle_plan"
    assert run["tags.pasta.executor"] == "scripted"
    assert line["performance_mean"] == pytest.approx(run["metrics.performance"])
    per_config = [run[f"metrics.success_config_{i}"] for i in (0, 1)]
    assert line["success_mean"] == pytest.approx(np.mean(per_config))
    assert run["metrics.planning_time_s"] == 0.0 and run["metrics.emd_planned_goal"] == 0.0
    table = json.loads(open(mlflow.tracking.MlflowClient(uri).download_artifacts(
        run["run_id"], "tables/evaluation.json")).read())
    assert [tuple(row["skills"]) for row in table] == [("cut", "rearrange", "rearrange")] * 2


def _save_untrained_bundle() -> None:
    cfg = load("CutRearrange", "smoke", list(OVERRIDES))
    bundle = untrained(cfg, "pasta", LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8)))
    save_trained(checkpoint_dir("CutRearrange", "smoke", "pasta") / "models.pt", bundle)


def _per_config(summary: dict) -> list[tuple]:
    """(seed, config, skills, performance) of every evaluated configuration, from the seeds' MLflow tables."""
    client = mlflow.tracking.MlflowClient()
    rows = []
    for seed in summary["per_seed"]:
        table = json.loads(open(client.download_artifacts(seed["mlflow_run_id"], "tables/evaluation.json")).read())
        rows += [(seed["seed"], row["config_id"], tuple(row["skills"]), row["performance"]) for row in table]
    return rows


def _assert_same_results(apart: list[tuple], here: list[tuple]) -> None:
    assert [row[:3] for row in apart] == [row[:3] for row in here]
    # Taichi's threaded scatter may sum in another order with another thread count: equal to float precision.
    assert [row[3] for row in apart] == pytest.approx([row[3] for row in here], abs=1e-3)


def test_evaluation_on_a_process_pool_matches_the_flow_thread(prefect_server, isolated_store):
    from flows import evaluate as evaluate_flow

    _, uri = isolated_store
    mlflow.set_tracking_uri(uri)
    _save_untrained_bundle()
    here = evaluate_flow.run("CutRearrange", "smoke", seeds=[3, 4], overrides=OVERRIDES, experiment="here")
    apart = evaluate_flow.run("CutRearrange", "smoke", seeds=[3, 4], overrides=OVERRIDES, experiment="apart",
                              workers=2)
    assert [s["seed"] for s in apart["per_seed"]] == [3, 4]
    _assert_same_results(_per_config(apart), _per_config(here))


def test_evaluation_runs_its_configurations_on_dask_workers(prefect_server, isolated_store):
    from distributed import Client, LocalCluster, get_task_stream

    from flows import evaluate as evaluate_flow

    _, uri = isolated_store
    mlflow.set_tracking_uri(uri)
    _save_untrained_bundle()
    with (LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
          Client(cluster) as client, get_task_stream(client) as stream):
        on_dask = evaluate_flow.run("CutRearrange", "smoke", seeds=[3], overrides=OVERRIDES, experiment="dask",
                                    dask_address=cluster.scheduler_address)
    assert len(stream.data) >= 2, "the configurations did not run on the Dask cluster"
    here = evaluate_flow.run("CutRearrange", "smoke", seeds=[3], overrides=OVERRIDES, experiment="here")
    _assert_same_results(_per_config(on_dask), _per_config(here))


def test_a_bad_worker_count_is_refused_by_name(isolated_store):
    from flows import evaluate as evaluate_flow

    with pytest.raises(ValueError, match="got 0"):
        evaluate_flow.run("CutRearrange", "smoke", workers=0)


def test_the_summary_std_over_seeds_is_the_sample_std_the_reports_use():
    from statistics import stdev

    from flows.evaluate import seed_std

    assert seed_std(np.array([0.846, 0.772, 0.818])) == pytest.approx(stdev([0.846, 0.772, 0.818]))
    assert seed_std(np.array([0.5])) == 0.0
