"""MLflow tracking: experiment lookups without warnings, experiment descriptions, no empty Default experiment."""

from __future__ import annotations

import logging
import time

import mlflow
import pytest

from pasta import tracking
from pasta.config import load
from pasta.report.runs import load_runs


@pytest.fixture
def store(tmp_path, monkeypatch):
    """A fresh sqlite MLflow store; returns its URI."""
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("MLFLOW_ARTIFACT_ROOT", (tmp_path / "artifacts").as_uri())
    assert tracking.configure() == uri
    return uri


@pytest.fixture
def mlflow_warnings():
    """The warnings MLflow's loggers emit during a test (they do not propagate to pytest's caplog)."""
    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = records.append
    logger = logging.getLogger("mlflow")
    logger.addHandler(handler)
    yield records
    logger.removeHandler(handler)


def test_runs_of_a_task_without_an_experiment_are_empty_and_silent(store, mlflow_warnings):
    with tracking.run("CRS", "data", profile="smoke"):
        pass
    assert tracking.search_runs("LiftSpread").empty
    assert len(load_runs(["LiftSpread", "CRS"])) == 1  # a report over tasks with and without runs
    assert [r.getMessage() for r in mlflow_warnings if "Cannot retrieve experiment" in r.getMessage()] == []


def test_a_new_experiment_is_described_and_the_empty_default_experiment_goes(store):
    experiment_id = tracking.use_experiment("CutRearrange")
    client = mlflow.MlflowClient(store)
    note = client.get_experiment(experiment_id).tags[tracking.DESCRIPTION_TAG]
    assert "CutRearrange" in note
    for tag in ("pasta.stage", "pasta.experiment", "pasta.variant", "pasta.plan", "pasta.executor"):
        assert f"`{tag}`" in note, tag
    assert client.get_experiment_by_name("Default").lifecycle_stage == "deleted"
    assert [e.name for e in client.search_experiments()] == ["pasta/CutRearrange"]


def test_an_older_experiment_gets_its_description_and_a_used_default_experiment_stays(store):
    client = mlflow.MlflowClient(store)
    older = client.create_experiment("pasta/CRS")
    default = client.get_experiment_by_name("Default").experiment_id
    client.create_run(default)
    tracking.use_experiment("CRS")
    assert "CRS" in client.get_experiment(older).tags[tracking.DESCRIPTION_TAG]
    tracking.use_experiment("LiftSpread")
    assert client.get_experiment(default).lifecycle_stage == "active"


def test_a_run_started_earlier_spans_the_work_it_records(store):
    began = time.time() - 60
    with tracking.run("CRS", "evaluate", profile="smoke", variant="pasta", seed=1, started_at=began) as parent:
        pass
    with tracking.run("CRS", "evaluate", profile="smoke", seed=2, parent_run_id=parent.info.run_id) as child:
        pass
    client = mlflow.MlflowClient(store)
    done = client.get_run(parent.info.run_id)
    assert done.info.start_time == round(1000 * began) and done.info.status == "FINISHED"
    assert 60 <= (done.info.end_time - done.info.start_time) / 1000 < 70
    assert done.info.run_name == "evaluate-pasta-s1" and done.data.tags["pasta.seed"] == "1"
    assert "mlflow.user" in done.data.tags  # MLflow's own context tags, as mlflow.start_run adds them
    nested = client.get_run(child.info.run_id)
    assert nested.data.tags["mlflow.parentRunId"] == parent.info.run_id
    assert 0 <= nested.info.end_time - nested.info.start_time < 10_000


def test_a_run_logs_the_policy_encoder_with_the_other_model_params(store):
    cfg = load("CutRearrange", "smoke", ["policy.encoder=pointnet"])
    with tracking.run("CutRearrange", "train", profile="smoke", variant="pasta", seed=0, cfg=cfg) as active:
        pass
    params = mlflow.MlflowClient(store).get_run(active.info.run_id).data.params
    assert params["policy.encoder"] == "pointnet" and params["train.latent_dim"] == str(cfg.train.latent_dim)
