"""Flow tests: one temporary Prefect server per session, a fresh PASTA_HOME and MLflow store per test."""

import os

import pytest


@pytest.fixture(scope="session")
def prefect_server():
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


@pytest.fixture
def isolated_store(tmp_path, monkeypatch):
    """PASTA_HOME, the reports and the MLflow sqlite store (artifacts beside it) under the test's temporary folder."""
    monkeypatch.setenv("PASTA_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("PASTA_REPORTS_DIR", str(tmp_path / "reports"))
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return tmp_path, uri
