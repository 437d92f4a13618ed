"""Prefect flow: the ablations of appendix Table 5 on one task, as child runs of one MLflow parent run.

    pasta ablations --task CutRearrange --profile small

Every variant is trained (the entity VAE is shared, see ``flows/train.py``) and evaluated on the same
test configurations and seeds; the evaluation runs are children of one ``ablations`` run, so the MLflow
UI lists them side by side, and they carry ``pasta.experiment = ablation`` for the report.
"""

from __future__ import annotations

from collections.abc import Sequence

from prefect import flow

from flows.data import generate_data
from flows.evaluate import evaluate
from flows.pipeline import models_task, pending_seeds, train_unless_done
from flows.report import report
from flows.runners import check_workers, task_runner
from pasta import tracking
from pasta.config import load
from pasta.models.variants import VARIANTS, variant_spec


@flow(name="ablations", flow_run_name="ablations-{task_name}-{profile}")
def ablations(task_name: str = "CutRearrange", profile: str = "smoke", variants: Sequence[str] = VARIANTS,
              method: str = "gbto", workers: int = 2, executor: str = "policy",
              overrides: Sequence[str] = (), dask_address: str | None = None) -> dict:
    """Train and evaluate each variant; returns ``{variant: evaluation summary}``.

    Demos and evaluations run on a process pool of ``workers`` or on the Dask cluster at ``dask_address``.
    """
    cfg = load(task_name, profile, list(overrides))
    source = models_task(cfg.task)
    runner = task_runner(workers, dask_address)
    generate_data.with_options(task_runner=runner)(source, profile, method, tuple(overrides), 0)
    results: dict[str, dict] = {}
    parent_id = tracking.finished_run_id(cfg.task, "ablations", cfg, profile=profile)
    if parent_id is None:  # a rerun adds its missing children to the same parent
        with tracking.run(cfg.task, "ablations", profile=profile, cfg=cfg, run_name=f"ablations-{profile}",
                          extra_tags={"pasta.experiment": "ablation"}) as parent:
            parent_id = parent.info.run_id
    for variant in variants:
        train_unless_done(source, profile, variant, method, overrides)
        seeds = pending_seeds(cfg.task, profile, variant, cfg.eval.seeds, overrides, "ablation")
        results[variant] = (evaluate(cfg.task, profile, variant, seeds=seeds, executor=executor,
                                     parent_run_id=parent_id, experiment="ablation", overrides=tuple(overrides),
                                     workers=workers, dask_address=dask_address)
                            if seeds else {"skipped": True})
    report(cfg.task)
    return results


def run(task_name: str = "CutRearrange", profile: str = "smoke", variants: Sequence[str] | None = None,
        method: str = "gbto", workers: int = 2, executor: str = "policy", overrides: Sequence[str] = (),
        dask_address: str | None = None) -> dict:
    """The CLI's entry point: check the arguments, then run :func:`ablations`."""
    chosen = tuple(VARIANTS if variants is None else variants)
    for variant in chosen:
        variant_spec(variant)
    check_workers(workers)
    load(task_name, profile, list(overrides))
    return ablations(task_name, profile, chosen, method, workers, executor, tuple(overrides), dask_address)
