"""Prefect flow: plan and execute a task's test configurations with trained models, record them in MLflow.

    pasta evaluate --task CutRearrange --profile smoke [--variant pasta] [--plan oracle] [--executor scripted]
                   [--seeds 0 1 2] [--workers 2 | --dask-address tcp://scheduler:8786]

``--plan learned`` (default) plans with the trained networks; ``--plan oracle`` executes the generator's own
subgoals and attention (``pasta.evaluate.oracle``), and with ``--executor scripted`` needs no trained models.
Its runs are tagged ``pasta.plan=oracle`` and, unless ``--experiment`` says otherwise, ``pasta.experiment=
oracle_plan``.

For every seed, one MLflow run (experiment ``pasta/<task>``, stage ``evaluate``) holds the aggregated
and per-configuration metrics (``pasta.evaluate.metrics``; for a learned plan also its diagnostics against the
ground truth, ``plan_*``), the table ``tables/evaluation.json`` and one image strip per configuration
``figures/plan_config_<i>.png``. The simulator runs in the flow's own
thread, or with ``--workers N`` / ``--dask-address`` on a process pool or a Dask cluster (Taichi keeps
one runtime per process; Prefect's thread pool is never used, see ``flows.runners``). The models come from
``pasta.train.locate.trained_models`` (CRS-Twice uses CRS's).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from flows.runners import check_workers, in_main_thread, run_in_child_process, task_runner, write_child_result
from pasta import progress, tracking
from pasta.config import load
from pasta.config.schema import TaskConfig
from pasta.data.configurations import EvaluationProblem, evaluation_problem, evaluation_problems
from pasta.evaluate import (
    EvaluationResult,
    check_executor,
    evaluate_problem,
    executor_label,
    plan_quality_metrics,
    render_result_strip,
    summary_metrics,
)
from pasta.evaluate.oracle import check_plan_source, needs_models
from pasta.plan import PlanSettings
from pasta.train.bundle import TrainedModels
from pasta.train.locate import trained_models


@task(task_run_name="evaluate-{problem.task}-config{problem.config_id}-s{seed}", cache_policy=NO_CACHE)
def evaluate_configuration(cfg: TaskConfig, bundle: TrainedModels | None, problem: EvaluationProblem, seed: int,
                           executor: str, settings: PlanSettings, plan_source: str = "learned") -> EvaluationResult:
    """Plan and execute one configuration (called directly, so it runs in the flow's thread)."""
    return evaluate_problem(cfg, bundle, problem, seed, executor, settings, plan_source)


@task(task_run_name="evaluate-{task_name}-config{config_id}-s{seed}", cache_policy=NO_CACHE)
def evaluate_configuration_apart(task_name: str, profile: str, variant: str, overrides: tuple[str, ...],
                                 config_id: int, seed: int, executor: str, plan_source: str = "learned"
                                 ) -> EvaluationResult:
    """Plan and execute one configuration in a pool worker or on a Dask cluster.

    The worker loads the config and the trained models itself (workers share ``$PASTA_HOME`` or the MLflow
    store with the flow). In a Dask worker's thread the work moves to a child process (Taichi needs a main
    thread).
    """
    if not in_main_thread():
        return run_in_child_process("flows.evaluate", [task_name, profile, variant, list(overrides), config_id,
                                                       seed, executor, plan_source])
    cfg = load(task_name, profile, list(overrides))
    bundle = trained_models(cfg.task, profile, variant) if needs_models(plan_source, executor) else None
    return evaluate_problem(cfg, bundle, evaluation_problem(cfg, config_id), seed, executor,
                            PlanSettings.from_config(cfg), plan_source)


def evaluate_seeds(cfg: TaskConfig, profile: str, variant: str, overrides: Sequence[str], seeds: Sequence[int],
                   executor: str, workers: int, dask_address: str | None, plan_source: str = "learned"
                   ) -> list[list[EvaluationResult]]:
    """Every (seed, configuration) result, per seed in configuration order.

    One worker without a Dask address runs them one by one in the flow's own thread; otherwise they fan out
    to a process pool of ``workers`` or to the Dask cluster.
    """
    pairs = progress.ScoreBar(f"{cfg.task} evaluation ({variant}, {plan_source} plan, {executor})",
                              len(seeds) * cfg.data.n_eval_configs)
    if workers == 1 and not dask_address:
        problems = evaluation_problems(cfg)
        bundle = trained_models(cfg.task, profile, variant) if needs_models(plan_source, executor) else None
        settings = PlanSettings.from_config(cfg)
        with pairs:
            return [[pairs.done(evaluate_configuration(cfg, bundle, problem, seed, executor, settings, plan_source))
                     for problem in problems] for seed in seeds]
    with task_runner(workers, dask_address) as runner, pairs:
        futures = [[runner.submit(evaluate_configuration_apart, {
            "task_name": cfg.task, "profile": profile, "variant": variant, "overrides": tuple(overrides),
            "config_id": index, "seed": seed, "executor": executor, "plan_source": plan_source})
            for index in range(cfg.data.n_eval_configs)]
            for seed in seeds]
        return [[pairs.done(future.result()) for future in row] for row in futures]


def default_experiment(plan_source: str) -> str:
    """The ``pasta.experiment`` tag of an evaluation that names none."""
    return "oracle_plan" if plan_source == "oracle" else "main"


def log_seed(cfg: TaskConfig, results: Sequence[EvaluationResult], *, profile: str, variant: str, seed: int,
             executor: str, parent_run_id: str | None, tags: dict[str, str], plan_source: str = "learned",
             started_at: float | None = None) -> tuple[str, dict[str, float]]:
    """One MLflow run for one seed: metrics (with a learned plan's diagnostics), the table and the strips; returns
    its id and the metrics.

    ``started_at`` (``time.time()``) is when the seed's evaluation began: the run starts then.
    """
    rows = [r.row() for r in results]
    metrics = summary_metrics(rows)
    if plan_source == "learned":
        metrics.update(plan_quality_metrics(rows))
    with tracking.run(cfg.task, "evaluate", profile=profile, variant=variant, seed=seed, cfg=cfg,
                      parent_run_id=parent_run_id,
                      extra_tags={**tags, "pasta.executor": executor_label(cfg, executor), "pasta.plan": plan_source},
                      started_at=started_at) as active:
        tracking.log_metrics(metrics)
        tracking.log_table(rows, "tables/evaluation.json")
        with tempfile.TemporaryDirectory() as folder:
            for result in results:
                path = render_result_strip(result, Path(folder) / f"plan_config_{result.config_id}.png")
                tracking.log_artifact(path, "figures")
        return active.info.run_id, metrics


@flow(name="evaluate", flow_run_name="evaluate-{task_name}-{profile}-{variant}")
def evaluate(task_name: str, profile: str = "smoke", variant: str = "pasta", seeds: Sequence[int] | None = None,
             executor: str = "policy", parent_run_id: str | None = None, experiment: str | None = None,
             overrides: Sequence[str] = (), sweep_value: str | None = None, workers: int = 1,
             dask_address: str | None = None, plan_source: str = "learned") -> dict:
    """Evaluate the trained models of ``variant`` on the task's test configurations, one MLflow run per seed.

    ``workers`` > 1 runs the (seed, configuration) pairs on a process pool, ``dask_address`` on a Dask
    cluster (:func:`evaluate_seeds`).

    ``plan_source`` ``"oracle"`` executes the generator's own subgoals instead of planning; ``experiment``
    defaults to ``"main"`` for learned plans and ``"oracle_plan"`` for the oracle.

    Returns the mean and standard deviation over seeds of the mean performance and the success rate, and the
    per-seed metrics and run ids.
    """
    check_executor(executor)
    check_plan_source(plan_source)
    experiment = experiment or default_experiment(plan_source)
    check_workers(workers)
    cfg = load(task_name, profile, list(overrides))
    seeds = list(cfg.eval.seeds if seeds is None else seeds)
    if not seeds:
        raise ValueError("no seeds to evaluate")
    tags = {"pasta.experiment": experiment}
    if sweep_value is not None:
        tags["pasta.sweep_value"] = str(sweep_value)
    started, started_at = time.perf_counter(), time.time()  # every seed's run covers the whole evaluation
    per_seed = []
    all_results = evaluate_seeds(cfg, profile, variant, overrides, seeds, executor, workers, dask_address,
                                 plan_source)
    for seed, results in zip(seeds, all_results, strict=True):
        run_id, metrics = log_seed(cfg, results, profile=profile, variant=variant, seed=seed, executor=executor,
                                   parent_run_id=parent_run_id, tags=tags, plan_source=plan_source,
                                   started_at=started_at)
        per_seed.append({"seed": seed, "mlflow_run_id": run_id, **metrics})
    performance = np.array([s["performance"] for s in per_seed])
    success = np.array([s["success_rate"] for s in per_seed])
    summary = {
        "task": cfg.task, "profile": profile, "variant": variant, "plan": plan_source,
        "executor": executor_label(cfg, executor),
        "experiment": experiment, "seeds": seeds,
        "performance_mean": float(performance.mean()), "performance_std": seed_std(performance),
        "success_mean": float(success.mean()), "success_std": seed_std(success),
        "per_seed": per_seed, "wall_s": time.perf_counter() - started,
    }
    progress.summary(f"evaluate {cfg.task} {variant}", evaluation_text(summary), summary["wall_s"])
    return summary


def seed_std(values: np.ndarray) -> float:
    """The sample standard deviation (``ddof=1``) of per-seed scores, as the reports compute it; 0.0 for one seed
    (the reports leave that cell empty), so the summary stays valid JSON."""
    values = np.asarray(values, dtype=np.float64)
    return float(values.std(ddof=1)) if len(values) > 1 else 0.0


def evaluation_text(summary: dict) -> str:
    """An evaluation's scores over seeds in one line."""
    return (f"{len(summary['seeds'])} seeds, performance {summary['performance_mean']:.3f} "
            f"± {summary['performance_std']:.3f}, success {summary['success_mean']:.2f} "
            f"± {summary['success_std']:.2f} ({summary['plan']} plan, {summary['executor']} executor)")


def run(task_name: str, profile: str = "smoke", variant: str = "pasta", seeds: Sequence[int] | None = None,
        executor: str = "policy", overrides: Sequence[str] = (), experiment: str | None = None, workers: int = 1,
        dask_address: str | None = None, plan_source: str = "learned", sweep_value: str | None = None) -> dict:
    """The CLI's entry point: check the arguments, then run :func:`evaluate`."""
    check_executor(executor)
    check_plan_source(plan_source)
    check_workers(workers)
    load(task_name, profile, list(overrides))  # refuse a bad task/profile/override before starting Prefect
    return evaluate(task_name, profile, variant, seeds=None if seeds is None else list(seeds), executor=executor,
                    experiment=experiment, overrides=tuple(overrides), workers=workers, dask_address=dask_address,
                    plan_source=plan_source, sweep_value=sweep_value)


if __name__ == "__main__":  # one configuration in this process's main thread (see evaluate_configuration_apart)
    arguments, result_file = json.loads(sys.argv[1]), sys.argv[2]
    name, prof, var, over, config, run_seed, how, source = arguments
    write_child_result(evaluate_configuration_apart.fn(name, prof, var, tuple(over), config, run_seed, how, source),
                       result_file)
