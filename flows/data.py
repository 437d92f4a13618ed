"""Prefect flow: generate a task's demonstration dataset and record it in MLflow.

    pasta data --task CutRearrange --profile small [--method gbto|scripted] [--workers 2]

Configurations fan out to a process pool (Taichi cannot run in Prefect's thread
pool), or to a Dask cluster with ``--dask-address``. Every demo is one atomic
``.npz``: a rerun skips every trajectory whose file is already there and
readable, so an interrupted run resumes where it stopped. The flow's MLflow run
(experiment ``pasta/<task>``, stage ``data``) holds the counts, the distribution
of normalised performance, the GBTO loss curves, the wall time and an image grid
of sample initial/target pairs.
"""

import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
from prefect import flow, task

from flows.runners import in_main_thread, task_runner
from pasta import progress, tracking
from pasta.config import load
from pasta.config.schema import TaskConfig
from pasta.data.configurations import generate_skill_problems, skill_problem, split_problems
from pasta.data.demos import DemoResult, check_method, demonstration_key, generate_demo
from pasta.data.storage import DatasetError, DatasetIndex, read_trajectory
from pasta.paths import data_dir


def dataset_dir(task_name: str, profile: str, method: str) -> Path:
    """``$PASTA_HOME/data/<task>/<profile>/<method>``."""
    path = data_dir(task_name, profile) / method
    path.mkdir(parents=True, exist_ok=True)
    return path


def existing_result(path: Path, key: str) -> dict | None:
    """The metadata of a finished, readable trajectory file made under the demonstration key ``key``
    (:func:`pasta.data.demos.demonstration_key`), or None: missing, corrupt, or made under another config,
    method or seed (a file from before the keys counts as another)."""
    if not path.exists():
        return None
    try:
        metadata = read_trajectory(path)[1]
    except DatasetError:
        return None
    return metadata if metadata.get("demonstration_key") == key else None


@task(task_run_name="demo-{task_name}-{trajectory_id}")
def make_demo(task_name: str, profile: str, overrides: tuple[str, ...], trajectory_id: int, method: str,
              out_dir: str, seed: int) -> dict:
    """Make one demo (in a worker process) unless its file already exists under the same demonstration key
    (config less training, planning and evaluation; method; seed); returns its metadata.

    Taichi must own a process's main thread; where tasks run in a worker thread (a Dask worker), the
    demo is made by a child ``python -m flows.data`` process and its metadata read back from the file.
    """
    cfg = load(task_name, profile, list(overrides))
    path = Path(out_dir) / f"trajectory_{trajectory_id:06d}.npz"
    key = demonstration_key(cfg, method, seed)
    done = existing_result(path, key)
    if done is not None:
        return {**done, "reused": True}
    if not in_main_thread():
        arguments = [task_name, profile, list(overrides), trajectory_id, method, out_dir, seed]
        subprocess.run([sys.executable, "-m", "flows.data", json.dumps(arguments)], check=True)
        made = existing_result(path, key)
        if made is None:
            raise RuntimeError(f"the demo process for {task_name} trajectory {trajectory_id} wrote no {path}")
        return {**made, "path": str(path), "reused": False}
    result: DemoResult = generate_demo(cfg, skill_problem(cfg, trajectory_id, seed), trajectory_id, method,
                                       Path(out_dir), seed=seed)
    record = asdict(result)
    record["path"] = str(result.path)
    record["reused"] = False
    return record


def summary_rows(records: Sequence[dict]) -> list[dict]:
    keys = ("trajectory_id", "configuration_id", "skill", "method", "normalised_performance",
            "scripted_normalised_performance", "gbto_normalised_performance")
    rows = []
    for r in records:
        row = {k: r.get(k) for k in keys}
        row["scripted_normalised_performance"] = r.get("scripted_normalised_performance",
                                                       r.get("scripted_performance"))
        row["gbto_normalised_performance"] = r.get("gbto_normalised_performance", r.get("gbto_performance"))
        rows.append(row)
    return rows


def figures(cfg: TaskConfig, records: Sequence[dict], folder: Path) -> list[Path]:
    """Performance histogram, GBTO loss curves and a grid of initial/target pairs, as PNGs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    perf = [r["normalised_performance"] for r in records]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.hist(perf, bins=20, range=(-0.5, 1.0), color="tab:brown")
    ax.set_xlabel("normalised performance")
    ax.set_ylabel("demos")
    ax.set_title(f"{cfg.task} ({cfg.profile}): {len(perf)} demos")
    paths.append(folder / "performance_hist.png")
    fig.savefig(paths[-1], dpi=100, bbox_inches="tight")
    plt.close(fig)

    curves = [r.get("gbto_losses") or [] for r in records]
    if any(curves):
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for curve in curves:
            if curve:
                ax.plot(np.asarray(curve) / curve[0], alpha=0.5)
        ax.set_xlabel("GBTO iteration")
        ax.set_ylabel("loss / first loss")
        paths.append(folder / "gbto_loss_curves.png")
        fig.savefig(paths[-1], dpi=100, bbox_inches="tight")
        plt.close(fig)

    samples = [skill_problem(cfg, r["trajectory_id"]) for r in records[:4]]
    fig, axes = plt.subplots(2, len(samples), figsize=(3 * len(samples), 6), squeeze=False)
    for col, problem in enumerate(samples):
        for row, (points, label) in enumerate(((problem.initial.particles, "initial"), (problem.target, "target"))):
            ax = axes[row, col]
            ax.scatter(points[:, 0], points[:, 2], s=1, c=points[:, 1], cmap="copper")
            ax.set_xlim(0, 1)
            ax.set_ylim(0, 1)
            ax.set_aspect("equal")
            ax.set_title(f"{problem.skill} #{problem.config_id}: {label}", fontsize=8)
    paths.append(folder / "initial_target_pairs.png")
    fig.savefig(paths[-1], dpi=100, bbox_inches="tight")
    plt.close(fig)
    return paths


@flow(name="generate-data", flow_run_name="data-{task_name}-{profile}-{method}")
def generate_data(task_name: str, profile: str = "smoke", method: str = "gbto", overrides: Sequence[str] = (),
                  seed: int = 0) -> dict:
    """Generate (or complete) the demonstration dataset of one task; returns counts and the index path."""
    check_method(method)
    cfg = load(task_name, profile, list(overrides))
    problems = generate_skill_problems(cfg, seed)
    train, test = split_problems(problems, cfg)
    split_of = {**{p.config_id: "train" for p in train}, **{p.config_id: "test" for p in test}}
    out_dir = dataset_dir(cfg.task, profile, method)
    index_path = out_dir / "index.csv"
    index = DatasetIndex.load(index_path, missing_ok=True)
    started, started_at = time.perf_counter(), time.time()  # the run covers the demos it records
    futures = [make_demo.submit(cfg.task, profile, tuple(overrides), p.config_id, method, str(out_dir), seed)
               for p in problems]
    records = []
    with progress.stage_progress() as bars:
        bar = bars.add_task(f"{cfg.task} demos ({method})", total=len(futures), status="")
        for future in futures:
            record = future.result()
            records.append(record)
            index.add(trajectory_id=record["trajectory_id"], configuration_id=record["configuration_id"],
                      skill=record["skill"], file_name=Path(record.get("path", "")).name
                      or f"trajectory_{record['trajectory_id']:06d}.npz",
                      split=split_of[record["configuration_id"]], final_shape_distance=record["emd_final"],
                      normalised_performance=record["normalised_performance"])
            index.save(index_path)
            bars.update(bar, advance=1, status=f"normalised performance {record['normalised_performance']:.3f}")
    wall_s = time.perf_counter() - started
    made = sum(not r["reused"] for r in records)
    perf = np.array([r["normalised_performance"] for r in records])
    rows = summary_rows(records)
    improved = [r for r in rows if r["gbto_normalised_performance"] is not None]
    summary = {
        "demos": len(records), "made": made, "reused": len(records) - made, "wall_s": wall_s,
        "performance_median": float(np.median(perf)), "performance_mean": float(np.mean(perf)),
        "gbto_beats_scripted_fraction": (
            float(np.mean([r["gbto_normalised_performance"] > r["scripted_normalised_performance"]
                           for r in improved])) if improved else float("nan")),
        "train": len(train), "test": len(test),
    }
    with tracking.run(cfg.task, "data", profile=profile, variant=method, seed=seed, cfg=cfg,
                      started_at=started_at) as active:
        tracking.log_metrics(summary)
        tracking.log_table(rows, "tables/demos.json")
        tracking.log_artifact(index_path, "dataset")
        with tempfile.TemporaryDirectory() as folder:
            for path in figures(cfg, records, Path(folder)):
                tracking.log_artifact(path, "figures")
        summary["mlflow_run_id"] = active.info.run_id
    summary["index"] = str(index_path)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    progress.summary(f"data {cfg.task} {method}", f"{len(records)} demos ({made} made, {len(records) - made} reused), "
                     f"mean normalised performance {summary['performance_mean']:.3f}", wall_s)
    return summary


def run(task_name: str, profile: str = "smoke", method: str = "gbto", workers: int = 2,
        overrides: Sequence[str] = (), dask_address: str | None = None, seed: int = 0) -> dict:
    """Run :func:`generate_data` on a process pool (or Dask cluster); the CLI's entry point."""
    check_method(method)
    load(task_name, profile, list(overrides))  # refuse a bad task/profile/override before starting Prefect
    runner = task_runner(workers, dask_address)
    return generate_data.with_options(task_runner=runner)(task_name, profile, method, tuple(overrides), seed)


if __name__ == "__main__":  # one demo in this process's main thread (see make_demo)
    name, prof, over, trajectory, how, folder, demo_seed = json.loads(sys.argv[1])
    make_demo.fn(name, prof, tuple(over), trajectory, how, folder, demo_seed)
