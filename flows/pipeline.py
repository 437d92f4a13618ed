"""Prefect flow: one task's whole pipeline (data, training, evaluation, report), reusing what is done.

    pasta run --task CutRearrange --profile smoke
    pasta run --all --profile small

Each stage resumes on its own: demonstrations already on disk are kept (``flows/data.py``),
training restarts from its last checkpoint and skips a finished one (``flows/train.py``), and an
evaluation seed whose MLflow run already finished with the same resolved config is not run again.
CRS-Twice has no demonstrations or models of its own: it is planned and executed with CRS's.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from prefect import flow

from flows.data import generate_data
from flows.evaluate import evaluate
from flows.report import report
from flows.runners import check_workers, task_runner
from flows.train import train
from pasta import tracking
from pasta.config import load
from pasta.config.schema import TASK_NAMES
from pasta.paths import checkpoint_dir, reports_dir, tracking_uri
from pasta.train.locate import BUNDLE_FILE

# Tasks that borrow another task's demonstrations and models.
MODELS_FROM = {"CRS-Twice": "CRS"}


def models_task(task_name: str) -> str:
    """The task whose data and models ``task_name`` uses."""
    return MODELS_FROM.get(task_name, task_name)


def pending_seeds(task_name: str, profile: str, variant: str, seeds: Sequence[int], overrides: Sequence[str],
                  experiment: str, sweep_value: str | None = None) -> list[int]:
    """The seeds with no finished evaluation run of this exact config (and experiment tags)."""
    cfg = load(task_name, profile, list(overrides))
    tags = {"profile": profile, "variant": variant, "experiment": experiment}
    if sweep_value is not None:
        tags["sweep_value"] = sweep_value
    return [seed for seed in seeds
            if tracking.finished_run_id(cfg.task, "evaluate", cfg, seed=str(seed), **tags) is None]


def train_unless_done(task_name: str, profile: str, variant: str, method: str, overrides: Sequence[str]) -> dict:
    """Train, unless a finished train run of this config exists and its bundle is on disk."""
    cfg = load(task_name, profile, list(overrides))
    run_id = tracking.finished_run_id(cfg.task, "train", cfg, profile=profile, variant=variant)
    bundle = checkpoint_dir(cfg.task, profile, variant) / BUNDLE_FILE
    if run_id is not None and bundle.exists():
        return {"skipped": True, "mlflow_run_id": run_id, "bundle": str(bundle)}
    return train(task_name, profile, variant, method=method, overrides=tuple(overrides))


@flow(name="pipeline", flow_run_name="pipeline-{task_name}-{profile}-{variant}")
def pipeline(task_name: str, profile: str = "smoke", variant: str = "pasta", method: str = "gbto",
             workers: int = 2, executor: str = "policy", overrides: Sequence[str] = (),
             dask_address: str | None = None) -> dict:
    """Data, training, evaluation and report of one task; returns where things went and the scores.

    The demos and the evaluations run on a process pool of ``workers``, or on the Dask cluster at
    ``dask_address``; training runs in this process.
    """
    started = time.perf_counter()
    cfg = load(task_name, profile, list(overrides))
    source = models_task(cfg.task)
    data_summary = generate_data.with_options(task_runner=task_runner(workers, dask_address))(
        source, profile, method, tuple(overrides), 0)
    train_summary = train_unless_done(source, profile, variant, method, overrides)
    seeds = pending_seeds(cfg.task, profile, variant, cfg.eval.seeds, overrides, "main")
    evaluation = (evaluate(cfg.task, profile, variant, seeds=seeds, executor=executor, experiment="main",
                           overrides=tuple(overrides), workers=workers, dask_address=dask_address)
                  if seeds else {"skipped": True})
    report_paths = report(cfg.task)
    return {
        "task": cfg.task,
        "profile": profile,
        "variant": variant,
        "data": data_summary,
        "train": train_summary,
        "evaluation": evaluation,
        "evaluated_seeds": seeds,
        "report": [str(path) for path in report_paths],
        "wall_s": time.perf_counter() - started,
    }


def run(task_names: Sequence[str], profile: str = "smoke", variant: str = "pasta", method: str = "gbto",
        workers: int = 2, executor: str = "policy", overrides: Sequence[str] = (),
        dask_address: str | None = None) -> list[dict]:
    """The CLI's entry point: the pipeline of each task in turn, then where to look."""
    for name in task_names:
        load(name, profile, list(overrides))  # refuse a bad task/profile/override before starting anything
    check_workers(workers)
    results = [pipeline(name, profile, variant, method, workers, executor, tuple(overrides), dask_address)
               for name in task_names]
    print(where_to_look(results))
    return results


def where_to_look(results: Sequence[dict]) -> str:
    """The closing message: the report files (the local folder, not the published ``reports/``) and how to open
    the MLflow UI on this store."""
    files = [path for result in results for path in result["report"] if Path(path).suffix in {".md", ".csv"}]
    lines = ["", "Reports:", *(f"  {path}" for path in dict.fromkeys(files))]  # the summary once, not per task
    lines += [
        f"All reports: {reports_dir()}  (local; the published reports/ change only with `pasta report --publish`)",
        "MLflow UI:  make ui   (or: .venv/bin/mlflow ui --backend-store-uri " + tracking_uri() + ")",
        "            then open http://127.0.0.1:5000 and pick the experiment pasta/<task>",
    ]
    return "\n".join(lines)


ALL_TASKS = tuple(TASK_NAMES)
