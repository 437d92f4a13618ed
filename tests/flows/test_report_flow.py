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
                          extra_tags={"pasta.experiment": "main", "pasta.plan": "learned", "pasta.executor": "policy"}):
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
    from pasta import paths

    tmp_path, _ = isolated_store
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path / "repo")
    published = paths.published_reports_dir() / "CutRearrange" / "report.md"
    published.parent.mkdir(parents=True)
    published.write_text("# the committed report\n")
    latent = _log_runs(tmp_path)
    first = report_flow.run("CutRearrange")  # the default folder: $PASTA_REPORTS_DIR
    local = tmp_path / "reports"
    assert {p.relative_to(local).parts[0] for p in first} == {"CutRearrange", "summary", "results.csv"}
    text = (local / "CutRearrange" / "report.md").read_text()
    assert "| CutRearrange | pasta | 2 | 0.800 ± 0.141 | 100% ± 0% | 0.837 / 80% |" in text
    assert (local / "CutRearrange" / "latent_space_pasta_smoke.png").read_bytes() == latent
    results = (local / "results.csv").read_text().splitlines()
    assert results[1:] == ["CutRearrange,smoke,main,pasta,,learned,policy,2,0.8,0.141421,1,0,3,,"]
    assert published.read_text() == "# the committed report\n"

    rebuilt = report_flow.run(None, str(tmp_path / "rebuilt"))  # every task with runs, from MLflow alone
    assert sorted(p.relative_to(tmp_path / "rebuilt") for p in rebuilt) == sorted(p.relative_to(local) for p in first)
    for path in first:
        assert (tmp_path / "rebuilt" / path.relative_to(local)).read_bytes() == path.read_bytes()

    published_artifact = Artifact.get("report-cutrearrange")
    assert published_artifact is not None and "0.837 / 80%" in published_artifact.data
    assert Artifact.get("cutrearrange-smoke-table5") is not None


def test_cli_report_runs_the_flow_lazily_into_the_folder_asked(monkeypatch, capsys, tmp_path):
    from pasta import paths

    calls = []
    fake = types.ModuleType("flows.report")
    fake.run = lambda task, out_dir: calls.append((task, out_dir)) or [tmp_path / "report.md"]
    monkeypatch.setitem(sys.modules, "flows.report", fake)
    monkeypatch.setattr(paths, "REPO_ROOT", tmp_path)
    assert main(["report", "--task", "CRS"]) == 0
    assert main(["report"]) == 0
    assert "pasta report --publish" in capsys.readouterr().out
    assert main(["report", "--publish"]) == 0
    assert main(["report", "--out", "somewhere"]) == 0
    assert calls == [("CRS", None), (None, None), (None, str(tmp_path / "reports")), (None, "somewhere")]
    assert str(tmp_path / "report.md") in capsys.readouterr().out
    for argv in (["report", "--task", "Pizza"], ["report", "--publish", "--out", "somewhere"]):
        with pytest.raises(SystemExit):
            main(argv)
