"""The report flow: a real Prefect flow run reading a real MLflow store; a rebuilt report equals the first."""

from __future__ import annotations

import sys
import types

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from pasta import tracking  # noqa: E402
from pasta.cli import main  # noqa: E402

pytestmark = pytest.mark.flow


def _log_runs(tmp_path) -> bytes:
    """Two seeds of a CutRearrange evaluation and a train run with a latent-space figure; returns its PNG."""
    for seed, perf in ((0, 0.7), (1, 0.9)):
        with tracking.run("CutRearrange", "evaluate", profile="smoke", variant="pasta", seed=seed,
                          extra_tags={"pasta.experiment": "main"}):
            tracking.log_metrics({"performance": perf, "success_rate": 1.0, "planning_time_s": 3.0})
    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [1, 0])
    png = tmp_path / "latent_space.png"
    fig.savefig(png)
    plt.close(fig)
    with tracking.run("CutRearrange", "train", profile="smoke", variant="pasta"):
        tracking.log_artifact(png, "figures")
    return png.read_bytes()


def test_report_rebuilt_from_mlflow_equals_the_first(prefect_server, isolated_store, monkeypatch):
    from prefect.artifacts import Artifact

    from flows import report as report_flow

    tmp_path, _ = isolated_store
    latent = _log_runs(tmp_path)
    monkeypatch.setattr(report_flow, "reports_dir", lambda: tmp_path / "first")
    first = report_flow.run("CutRearrange")
    assert {p.parent.name for p in first} == {"CutRearrange", "summary"}
    task_report = tmp_path / "first" / "CutRearrange" / "report.md"
    text = task_report.read_text()
    assert "| CutRearrange | pasta | 2 | 0.800 ± 0.141 | 100% ± 0% | 0.837 / 80% |" in text
    assert (tmp_path / "first" / "CutRearrange" / "latent_space_pasta_smoke.png").read_bytes() == latent

    monkeypatch.setattr(report_flow, "reports_dir", lambda: tmp_path / "rebuilt")
    rebuilt = report_flow.run()  # every task with runs, from MLflow alone
    assert sorted(p.relative_to(tmp_path / "rebuilt") for p in rebuilt) == sorted(
        p.relative_to(tmp_path / "first") for p in first)
    for path in first:
        assert (tmp_path / "rebuilt" / path.relative_to(tmp_path / "first")).read_bytes() == path.read_bytes()

    published = Artifact.get("report-cutrearrange")
    assert published is not None and "0.837 / 80%" in published.data
    assert Artifact.get("cutrearrange-smoke-table5") is not None


def test_cli_report_runs_the_flow_lazily(monkeypatch, capsys, tmp_path):
    calls = []
    fake = types.ModuleType("flows.report")
    fake.run = lambda task: calls.append(task) or [tmp_path / "report.md"]
    monkeypatch.setitem(sys.modules, "flows.report", fake)
    assert main(["report", "--task", "CRS"]) == 0
    assert main(["report"]) == 0
    assert calls == ["CRS", None]
    assert str(tmp_path / "report.md") in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["report", "--task", "Pizza"])
