"""`pasta status`: what exists for a task and profile, read from PASTA_HOME and MLflow."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from pasta import status, tracking
from pasta.cli import main
from pasta.config import load
from pasta.paths import BUNDLE_FILE, REPO_ROOT, checkpoint_dir, data_dir

TASK = "CutRearrange"


@pytest.fixture
def store(tmp_path, monkeypatch):
    """PASTA_HOME, the reports and the MLflow sqlite store under the test's temporary folder."""
    monkeypatch.setenv("PASTA_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("PASTA_REPORTS_DIR", str(tmp_path / "reports"))
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    return tmp_path


def evaluation_run(cfg, seed: int, tags: dict[str, str]) -> str:
    """An evaluation run opened as flows/evaluate.py's log_seed opens it."""
    with tracking.run(cfg.task, "evaluate", profile="smoke", variant="pasta", seed=seed, cfg=cfg,
                      extra_tags=tags) as active:
        tracking.log_metrics({"performance_mean": 0.5})
        return active.info.run_id


@pytest.fixture
def filled(store):
    """Two gbto demo files and their data run, a trained pasta bundle and its train run, two evaluation runs of
    the main experiment and one older run without a plan tag."""
    cfg = load(TASK, "smoke")
    folder = data_dir(TASK, "smoke") / "gbto"
    folder.mkdir()
    for i in range(2):
        (folder / f"trajectory_{i:06d}.npz").write_bytes(b"")
    (folder / "index.csv").write_text("")
    with tracking.run(TASK, "data", profile="smoke", variant="gbto", seed=0) as active:
        data_run = active.info.run_id
    with tracking.run(TASK, "train", profile="smoke", variant="pasta", seed=0, cfg=cfg) as active:
        train_run = active.info.run_id
    bundle = checkpoint_dir(TASK, "smoke", "pasta") / BUNDLE_FILE
    bundle.write_bytes(b"")
    main_tags = {"pasta.experiment": "main", "pasta.executor": "policy", "pasta.plan": "learned"}
    evaluations = [evaluation_run(cfg, seed, main_tags) for seed in (0, 1)]
    old = evaluation_run(cfg, 2, {"pasta.experiment": "ablation", "pasta.executor": "scripted"})
    return {"folder": folder, "data_run": data_run, "train_run": train_run, "bundle": bundle,
            "evaluations": evaluations, "old": old}


def test_human_age():
    assert [status.human_age(s) for s in (None, 5, 59, 60, 185, 3600, 7300, 86400, 5 * 86400 + 10)] == [
        "-", "5 s", "59 s", "1 min", "3 min", "1 h", "2 h", "1 d", "5 d"]


def test_rows_of_demos_trained_variants_and_evaluations(filled):
    found = status.gather(TASK, "smoke")
    assert found["models_from"] == TASK
    [demo] = found["demos"]
    assert demo["method"] == "gbto" and demo["trajectories"] == 2
    assert demo["folder"] == str(filled["folder"]) and demo["run_id"] == filled["data_run"]
    assert 0 <= demo["age_s"] < 600 and demo["age"].endswith((" s", " min"))
    [model] = found["trained"]
    assert model["variant"] == "pasta" and model["bundle"] == str(filled["bundle"])
    assert model["run_id"] == filled["train_run"] and model["current_config"]
    old_row, main_row = found["evaluations"]  # by experiment name
    assert (main_row["experiment"], main_row["variant"], main_row["plan"], main_row["executor"]) == (
        "main", "pasta", "learned", "policy")
    assert main_row["seeds"] == [0, 1] and main_row["run_ids"] == filled["evaluations"]
    assert main_row["current_config"] and len(main_row["ages"]) == 2
    assert (old_row["experiment"], old_row["plan"], old_row["executor"], old_row["seeds"]) == (
        "ablation", "learned", "scripted", [2])  # no plan tag: planned with the networks
    assert old_row["run_ids"] == [filled["old"]]
    assert found["reuse"] == ["demonstrations: 2 gbto trajectory files kept, the missing ones made",
                              f"training: pasta reused (run {filled['train_run']})",
                              "evaluation: seeds 0 reused"]


def test_a_bundle_without_a_current_train_run_is_retrained(filled):
    found = status.gather(TASK, "smoke")
    assert status.reuse_lines(found, variant="no_vae")[1].startswith("training: no_vae trained")
    filled["bundle"].unlink()
    assert status.reuse_lines(status.gather(TASK, "smoke"))[1].startswith("training: pasta trained")


def test_cli_prints_the_tables(filled, capsys):
    assert main(["status", "--task", TASK]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert f"pasta status: {TASK} at profile smoke" in out
    assert "nothing yet" not in out
    for text in (filled["data_run"], filled["train_run"], str(filled["bundle"]), *filled["evaluations"],
                 filled["old"], "main, variant pasta, plan learned, executor policy (current config): seeds 0 1",
                 "ablation, variant pasta, plan learned, executor scripted", "seeds 0 reused"):
        assert text in out
    assert "Cannot retrieve experiment" not in captured.err


def test_cli_says_nothing_yet_and_creates_nothing(store, capsys):
    assert main(["status", "--task", "CRS-Twice", "--profile", "small"]) == 0
    out = capsys.readouterr().out
    assert out.count("nothing yet") == 3
    assert "Demonstrations (of CRS: CRS-Twice uses CRS's)" in out
    assert "demonstrations: all made (gbto)" in out
    assert not (store / "home" / "data").exists() and not (store / "home" / "checkpoints").exists()


def test_status_imports_neither_torch_nor_prefect(store):
    code = ("import sys; from pasta.cli import main; main(['status', '--task', 'CRS']); "
            "assert 'torch' not in sys.modules and 'prefect' not in sys.modules, 'heavy import'")
    env = {**os.environ, "PASTA_HOME": str(store / "home"),
           "MLFLOW_TRACKING_URI": f"sqlite:///{store / 'mlflow.db'}"}
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert "nothing yet" in done.stdout
