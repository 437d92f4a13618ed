"""One Prefect server per command: pool workers report to the parent's server instead of starting their own."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import prefect.server.api.server
import pytest
from prefect.settings import PREFECT_API_URL, get_current_settings, temporary_settings

from flows.runners import one_prefect_server
from pasta.sim.runtime import CACHE_ENV, kernel_cache_dir


class FakeServer:
    """Stands in for Prefect's temporary server: counts its starts."""

    starts = 0
    api_url = "http://127.0.0.1:8999/api"

    def start(self) -> None:
        FakeServer.starts += 1


@pytest.fixture
def fake_server(monkeypatch):
    FakeServer.starts = 0
    monkeypatch.setattr(prefect.server.api.server, "SubprocessASGIServer", FakeServer)
    return FakeServer


def test_without_an_api_url_one_server_starts_and_its_url_goes_to_the_workers(fake_server):
    with temporary_settings(restore_defaults={PREFECT_API_URL}):
        with one_prefect_server() as url:
            assert url == fake_server.api_url and PREFECT_API_URL.value() == url
            # what a ProcessPoolTaskRunner hands its workers
            assert get_current_settings().to_environment_variables(exclude_unset=True)["PREFECT_API_URL"] == url
        assert not PREFECT_API_URL.value()
    assert fake_server.starts == 1


def test_a_given_api_url_or_a_dask_cluster_starts_no_server(fake_server):
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:4200/api"}):
        with one_prefect_server() as url:
            assert url == "http://127.0.0.1:4200/api"
    with temporary_settings(restore_defaults={PREFECT_API_URL}), one_prefect_server(enabled=False) as url:
        assert not url
    assert fake_server.starts == 0


@pytest.mark.flow
def test_the_cli_starts_one_server_for_its_workers_and_prints_no_avoidable_warning(tmp_path):
    """``pasta data`` on a 2-worker pool, as a user runs it: no PREFECT_API_URL, the kernel cache variable set."""
    env = {key: value for key, value in os.environ.items() if key != "PREFECT_API_URL"}
    env.update(PREFECT_HOME=str(tmp_path / "prefect"), PASTA_HOME=str(tmp_path / "home"),
               PASTA_REPORTS_DIR=str(tmp_path / "reports"), MLFLOW_TRACKING_URI=f"sqlite:///{tmp_path / 'mlflow.db'}",
               **{CACHE_ENV: str(kernel_cache_dir())})
    argv = ["data", "--task", "CutRearrange", "--method", "scripted", "--workers", "2",
            "--set", "data.n_train_trajectories=2", "--set", "data.n_test_trajectories=1",
            "--set", "sim.steps_per_skill=3", "--set", "sim.settle_steps=1"]
    done = subprocess.run([sys.executable, "-m", "pasta", *argv], env=env, cwd=tmp_path, capture_output=True,
                          text=True, timeout=900)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-3000:]
    ports = set(re.findall(r"temporary server on http://127\.0\.0\.1:(\d+)", output))
    assert len(ports) == 1, output[-3000:]
    for warning in ("overridden by ti.init", "Cannot retrieve experiment"):
        assert warning not in output, warning
    assert "CutRearrange demos (scripted)" in output and "data CutRearrange scripted done in" in output
