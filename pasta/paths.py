"""Where files go.

* ``PASTA_HOME`` (default ``<repo root>/.pasta_home``): datasets and checkpoints.
* ``MLFLOW_TRACKING_URI`` (default ``sqlite:///<repo root>/mlflow.db``, absolute): run tracking.
* ``PASTA_REPORTS_DIR`` (default ``<repo root>/build/reports``, git-ignored): the tables and figures a local
  ``pasta report`` rebuilds. The published reports, committed to git, live in ``<repo root>/reports`` and are
  written only when asked (``pasta report --publish``).

The repo root is the parent of the ``pasta`` package directory. Directories are created on demand.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
BUNDLE_FILE = "models.pt"  # a trained variant's models: ``checkpoint_dir(task, profile, variant) / BUNDLE_FILE``
# Tasks that plan with another task's models (CRS-Twice uses CRS's skills and models).
_SHARED_MODELS = {"CRS-Twice": "CRS"}


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def _component(value: str, what: str) -> str:
    """Refuse names that would escape their parent directory."""
    if not value or value in {".", ".."} or "/" in value or "\\" in value:
        raise ValueError(f"invalid {what} {value!r}: must be a plain name without path separators")
    return value


def pasta_home() -> Path:
    """Root for data and checkpoints: ``$PASTA_HOME`` or ``<repo root>/.pasta_home``."""
    env = os.environ.get("PASTA_HOME")
    home = Path(env).expanduser().resolve() if env else REPO_ROOT / ".pasta_home"
    return _mkdir(home)


def tracking_uri() -> str:
    """MLflow tracking URI: ``$MLFLOW_TRACKING_URI`` or an absolute sqlite URI in the repo root."""
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{(REPO_ROOT / 'mlflow.db').as_posix()}"


def model_task(task: str) -> str:
    """The task whose models ``task`` uses."""
    return _SHARED_MODELS.get(task, task)


def data_dir(task: str, profile: str, *, create: bool = True) -> Path:
    """Datasets of one task at one profile: ``$PASTA_HOME/data/<task>/<profile>`` (created unless ``create`` is
    false)."""
    path = pasta_home() / "data" / _component(task, "task") / _component(profile, "profile")
    return _mkdir(path) if create else path


def checkpoint_dir(task: str, profile: str, run_name: str | None = None, *, create: bool = True) -> Path:
    """Model checkpoints: ``$PASTA_HOME/checkpoints/<task>/<profile>[/<run_name>]`` (created unless ``create`` is
    false)."""
    path = pasta_home() / "checkpoints" / _component(task, "task") / _component(profile, "profile")
    if run_name is not None:
        path = path / _component(run_name, "run name")
    return _mkdir(path) if create else path


def reports_dir() -> Path:
    """Where a report rebuild writes by default: ``$PASTA_REPORTS_DIR`` or ``<repo root>/build/reports``.

    Never the published folder (:func:`published_reports_dir`), whose reports may come from a store that no
    longer exists and so could not be rebuilt here.
    """
    env = os.environ.get("PASTA_REPORTS_DIR")
    return _mkdir(Path(env).expanduser().resolve() if env else REPO_ROOT / "build" / "reports")


def published_reports_dir() -> Path:
    """The published reports, committed to git: ``<repo root>/reports`` (``pasta report --publish``)."""
    return _mkdir(REPO_ROOT / "reports")
