"""The whole pipeline at smoke through real Prefect flow runs and a real MLflow store: interrupted, resumed, rerun."""

from __future__ import annotations

import mlflow
import pytest

from pasta.cli import build_parser

pytestmark = pytest.mark.flow

# The smoke profile with short skills, two test configurations, one training epoch, one DAgger round of one
# problem and a tiny planner.
OVERRIDES = ("sim.steps_per_skill=4", "sim.settle_steps=1", "plan.samples=8", "plan.iterations=2",
             "data.n_eval_configs=2", "train.vae_epochs=1", "train.epochs=1", "train.dagger_rounds=1",
             "train.dagger_problems=1", "train.dagger_steps=2")


class Interrupted(RuntimeError):
    pass


def test_pipeline_resumes_after_an_interruption_and_skips_finished_steps(prefect_server, isolated_store,
                                                                         monkeypatch):
    from flows import pipeline
    from flows.report import report

    tmp_path, uri = isolated_store
    real_evaluate = pipeline.evaluate

    def interrupt(*args, **kwargs):
        raise Interrupted("stopped before the evaluation")

    monkeypatch.setattr(pipeline, "evaluate", interrupt)
    with pytest.raises(Interrupted):
        pipeline.run(["CutRearrange"], "smoke", method="scripted", workers=1, overrides=OVERRIDES)
    monkeypatch.setattr(pipeline, "evaluate", real_evaluate)

    (resumed,) = pipeline.run(["CutRearrange"], "smoke", method="scripted", workers=1, overrides=OVERRIDES)
    assert resumed["data"]["made"] == 0 and resumed["data"]["reused"] == resumed["data"]["demos"] >= 1
    assert resumed["train"].get("skipped") is True
    assert resumed["evaluated_seeds"] == [0]
    assert 0.0 <= resumed["evaluation"]["success_mean"] <= 1.0

    (again,) = pipeline.run(["CutRearrange"], "smoke", method="scripted", workers=1, overrides=OVERRIDES)
    assert again["data"]["made"] == 0 and again["train"].get("skipped") is True
    assert again["evaluated_seeds"] == [] and again["evaluation"] == {"skipped": True}

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["pasta/CutRearrange"])
    stages = runs["tags.pasta.stage"].value_counts().to_dict()
    assert stages["train"] == 1 and stages["evaluate"] == 1
    training = runs[runs["tags.pasta.stage"] == "train"].iloc[0]
    assert training["metrics.dagger_rounds"] == 1.0
    client = mlflow.MlflowClient()
    dagger_steps = [m.step for m in client.get_metric_history(training["run_id"], "dagger_heldout_mse")]
    policy_steps = [m.step for m in client.get_metric_history(training["run_id"], "policy_heldout_mse")]
    assert dagger_steps == [policy_steps[-1], policy_steps[-1] + 2]  # the round's 2 steps follow the loop's
    evaluation = runs[runs["tags.pasta.stage"] == "evaluate"].iloc[0]
    assert evaluation["status"] == "FINISHED" and evaluation["tags.pasta.experiment"] == "main"
    per_config = [evaluation[f"metrics.success_config_{i}"] for i in (0, 1)]
    assert set(per_config) <= {0.0, 1.0}
    assert resumed["evaluation"]["success_mean"] == pytest.approx(sum(per_config) / 2)  # one seed, two configurations

    markdown = tmp_path / "reports" / "CutRearrange" / "report.md"
    assert str(markdown) in resumed["report"]
    written = markdown.read_text()
    assert f"{evaluation['metrics.performance']:.3f}" in written
    report("CutRearrange")  # rebuilt from MLflow alone
    assert markdown.read_text() == written


def test_cli_run_needs_a_task_or_all():
    from pasta.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["run"])
    assert exit_info.value.code == 2
    args = build_parser().parse_args(["run", "--all", "--profile", "small", "--method", "scripted"])
    assert (args.all, args.task, args.profile, args.method, args.executor) == (True, None, "small", "scripted",
                                                                              "policy")


def test_closing_message_names_the_local_report_folder(tmp_path, monkeypatch):
    from flows.pipeline import where_to_look

    monkeypatch.setenv("PASTA_REPORTS_DIR", str(tmp_path / "local"))
    local = tmp_path / "local"
    files = [local / "CutRearrange" / "report.md", local / "CutRearrange" / "fig.png", local / "summary" / "report.md",
             local / "results.csv"]
    message = where_to_look([{"report": [str(p) for p in files]}, {"report": [str(p) for p in files[2:]]}])
    for path in (files[0], files[2], files[3]):
        assert message.count(f"  {path}\n") == 1  # the summary and results.csv once, though both runs wrote them
    assert "fig.png" not in message
    assert f"All reports: {local}  " in message and "pasta report --publish" in message
