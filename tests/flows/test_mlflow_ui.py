"""The MLflow UI lists an ablation's runs: a real ``mlflow server`` on localhost, read by headless Chromium.

The UI is a React app, so the test reads the DOM Chromium renders (``--dump-dom`` after a virtual-time
budget) and saves a screenshot beside it. Skipped only where ``chromium`` is missing and ``CI`` is unset.
"""

from __future__ import annotations

import html
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from pasta import tracking

VARIANTS = ("pasta", "no_smoothing_feasibility", "shared_encoder_policy", "tool_concat_policy",
            "set_without_filtering", "flat3d")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-dev-shm-usage", "--window-size=1600,1000", "--virtual-time-budget=20000")

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(shutil.which("chromium") is None and not os.environ.get("CI"),
                       reason="chromium is not installed (apt-get install chromium); required when CI is set"),
]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _log_ablation() -> str:
    """An ablation parent run with one evaluate child per variant; returns the experiment id."""
    with tracking.run("CutRearrange", "ablations", profile="smoke", run_name="ablations-smoke",
                      extra_tags={"pasta.experiment": "ablation"}) as parent:
        parent_id = parent.info.run_id
    for i, variant in enumerate(VARIANTS):
        with tracking.run("CutRearrange", "evaluate", profile="smoke", variant=variant, seed=0,
                          parent_run_id=parent_id, extra_tags={"pasta.experiment": "ablation"}):
            tracking.log_metrics({"performance": 0.1 * i, "success_rate": 0.2})
    return parent.info.experiment_id


@pytest.fixture
def mlflow_server(isolated_store):
    """``mlflow server`` on a free localhost port over the test's sqlite store; yields its URL."""
    tmp_path, uri = isolated_store
    experiment_id = _log_ablation()
    port = _free_port()
    mlflow_cli = Path(sys.executable).parent / "mlflow"
    log = (tmp_path / "mlflow_server.log").open("w")
    server = subprocess.Popen(
        [str(mlflow_cli), "server", "--backend-store-uri", uri, "--host", "127.0.0.1", "--port", str(port),
         "--workers", "1", "--artifacts-destination", str(tmp_path / "artifacts")],
        cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2) as reply:
                    if reply.status == 200:
                        break
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"mlflow server did not come up on {url}:\n{(tmp_path / 'mlflow_server.log').read_text()}")
            time.sleep(1)
        yield url, experiment_id
    finally:
        os.killpg(server.pid, signal.SIGTERM)  # the server and its uvicorn worker, started in their own group
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
        log.close()


def _visible_text(dom: str) -> str:
    text = re.sub(r"<script.*?</script>|<style.*?</style>", " ", dom, flags=re.S)
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", text)))


def test_the_experiment_page_lists_the_ablation_runs(mlflow_server, tmp_path):
    from mlflow import MlflowClient

    url, experiment_id = mlflow_server
    # Sorted by a tag, the run table lists child runs flat instead of folded under their parent.
    page = f"{url}/#/experiments/{experiment_id}/runs?orderByKey=tags.%60pasta.variant%60&orderByAsc=true"
    screenshot = tmp_path / "mlflow_ui_ablation.png"
    browser = subprocess.run(
        [shutil.which("chromium") or "chromium", *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium'}",
         f"--screenshot={screenshot}", "--dump-dom", page],
        capture_output=True, text=True, timeout=180, check=True)
    text = _visible_text(browser.stdout)
    assert "pasta/CutRearrange" in text, f"the experiment page did not render: {text[:500]}"
    assert "7 matching runs" in text
    listed = [name for name in ("ablations-smoke", *(f"evaluate-{v}-s0" for v in VARIANTS)) if name in text]
    assert len(listed) == 7, f"the run table lists {listed}: {text[:2000]}"
    assert "Sort: pasta.variant" in text  # the variant tag is known to the UI
    assert screenshot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and screenshot.stat().st_size > 10_000
    print(f"screenshot: {screenshot}")

    # The same server's REST API (what the UI reads) serves every child with its variant tag.
    runs = MlflowClient(tracking_uri=url).search_runs([experiment_id], "tags.`pasta.stage` = 'evaluate'")
    assert sorted(r.data.tags["pasta.variant"] for r in runs) == sorted(VARIANTS)
