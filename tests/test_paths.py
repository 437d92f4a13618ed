"""pasta.paths: PASTA_HOME and MLFLOW_TRACKING_URI handling."""

from __future__ import annotations

from pathlib import Path

import pytest

from pasta import paths

REPO_ROOT = Path(__file__).resolve().parent.parent


def test_repo_root_is_the_checkout():
    assert paths.REPO_ROOT == REPO_ROOT
    assert (paths.REPO_ROOT / "pyproject.toml").is_file()


def test_pasta_home_from_env_is_created(tmp_path, monkeypatch):
    home = tmp_path / "somewhere" / "home"
    monkeypatch.setenv("PASTA_HOME", str(home))
    assert paths.pasta_home() == home
    assert home.is_dir()


def test_relative_pasta_home_is_made_absolute(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PASTA_HOME", "rel_home")
    assert paths.pasta_home() == tmp_path / "rel_home"


def test_pasta_home_default(monkeypatch):
    monkeypatch.delenv("PASTA_HOME", raising=False)
    assert paths.pasta_home() == REPO_ROOT / ".pasta_home"


def test_data_and_checkpoint_dirs_live_under_pasta_home(tmp_path, monkeypatch):
    monkeypatch.setenv("PASTA_HOME", str(tmp_path))
    assert paths.data_dir("CRS", "smoke") == tmp_path / "data" / "CRS" / "smoke"
    assert paths.checkpoint_dir("CRS", "smoke") == tmp_path / "checkpoints" / "CRS" / "smoke"
    assert paths.checkpoint_dir("CRS", "smoke", "run1") == tmp_path / "checkpoints" / "CRS" / "smoke" / "run1"
    assert paths.data_dir("CRS", "smoke").is_dir()
    with pytest.raises(ValueError, match="task"):
        paths.data_dir("../CRS", "smoke")


def test_a_rebuild_writes_build_reports_not_the_published_reports(tmp_path, monkeypatch):
    monkeypatch.delenv("PASTA_REPORTS_DIR", raising=False)
    assert paths.reports_dir() == REPO_ROOT / "build" / "reports"
    assert paths.published_reports_dir() == REPO_ROOT / "reports"
    assert "/build/" in (REPO_ROOT / ".gitignore").read_text().split()  # a rebuild leaves git status clean
    monkeypatch.setenv("PASTA_REPORTS_DIR", str(tmp_path / "elsewhere"))
    assert paths.reports_dir() == tmp_path / "elsewhere"
    assert paths.published_reports_dir() == REPO_ROOT / "reports"


def test_tracking_uri_from_env(monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://mlflow.example:5000")
    assert paths.tracking_uri() == "http://mlflow.example:5000"


def test_tracking_uri_default_is_absolute_sqlite(monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    uri = paths.tracking_uri()
    assert uri == f"sqlite:///{REPO_ROOT}/mlflow.db"
    assert uri.startswith("sqlite:////")  # three slashes of the scheme, one of the absolute path
