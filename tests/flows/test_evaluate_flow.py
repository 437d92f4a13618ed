"""The evaluation flow: a real Prefect flow run with untrained models, recorded in a temporary MLflow store."""

from __future__ import annotations

import json

import mlflow
import numpy as np
import pytest

from pasta.cli import build_parser
from pasta.config import load
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
    bundle = untrained(cfg, "pasta", LatentPrior(2, (0.2, 0.1, 0.2), (0.8, 0.2, 0.8)))
    save_trained(checkpoint_dir("CutRearrange", "smoke", "pasta") / "models.pt", bundle)

    summary = evaluate_flow.run("CutRearrange", "smoke", seeds=[3], overrides=OVERRIDES, experiment="ablation")
    assert summary["seeds"] == [3] and summary["executor"] == "policy"
    assert np.isfinite(summary["performance_mean"]) and summary["performance_std"] == 0.0
    assert 0.0 <= summary["success_mean"] <= 1.0

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["pasta/CutRearrange"])
    assert len(runs) == 1
    run = runs.iloc[0]
    assert run["tags.pasta.stage"] == "evaluate" and run["tags.pasta.seed"] == "3"
    assert run["tags.pasta.experiment"] == "ablation" and run["tags.pasta.variant"] == "pasta"
    names = ["performance", "success_rate", "planning_time_s", "emd_planned_goal", "emd_reached_goal", "emd_initial"]
    names += [f"{m}_config_{i}" for m in ("performance", "success", "planning_time_s") for i in (0, 1)]
    for name in names:
        assert np.isfinite(run[f"metrics.{name}"]), name
    assert run["metrics.performance"] == pytest.approx(summary["performance_mean"])
    assert run["metrics.emd_initial"] > 0

    client = mlflow.tracking.MlflowClient(uri)
    run_id = run["run_id"]
    table = json.loads(open(client.download_artifacts(run_id, "tables/evaluation.json")).read())
    assert [row["config_id"] for row in table] == [0, 1]
    assert all(len(row["skills"]) == cfg.horizon and row["emd_reached_goal"] == row["emd_final"] for row in table)
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
    assert args.set == ["plan.samples=8"] and args.experiment == "main"
    assert build_parser().parse_args(["evaluate", "--task", "CRS"]).seeds is None
