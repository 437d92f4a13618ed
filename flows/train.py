"""Prefect flow: train a task's models for one variant and record them in MLflow.

    pasta train --task CutRearrange --profile small --variant pasta [--method scripted|gbto]

1. The VAE is trained once per task, profile and representation (entity VAE; a whole-scene VAE for
   ``flat3d``) and kept under ``$PASTA_HOME/checkpoints/<task>/<profile>/vae-<key>/vae.pt``; the key hashes
   the VAE settings and the dataset index, so every variant reuses it and a changed dataset retrains it.
2. The feasibility and cost heads of the variant train on the frozen VAE's cached latents (eq. 6), then its
   policies in their own loop (a step budget per skill, early stopping on held-out action MSE), then, with
   ``train.dagger_rounds``, DAgger rounds that simulate the policies on fresh problems in this thread
   (``pasta.train.dagger``); the finished bundle is ``checkpoint_dir(task, profile, variant)/models.pt``.

Every stage checkpoints after every epoch (the policies after every evaluation) and resumes from there, so a
rerun after an interruption continues where it stopped. Training is torch only, so it runs in the flow's
thread. One MLflow run (stage ``train``) holds the resolved config, per-epoch metrics (step = epoch), the
policies' curves (``policy_heldout_mse_<skill>``, ``policy_train_loss_<skill>``, ``policy_lr``; step =
gradient steps taken), the final metrics (``vae_heldout_chamfer``, ``feasibility_auc_random``,
``feasibility_auc_hard``, ``cost_r2``, ``policy_mse``, ``policy_zero_mse``, and per skill
``policy_steps_<skill>``, the steps it took, and ``policy_best_step_<skill>``, the step of its kept weights),
the reconstruction and latent-space figures and the bundle as ``checkpoints/models.pt``.
"""

import hashlib
import json
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from pasta import progress, tracking
from pasta.config import load
from pasta.config.schema import TaskConfig
from pasta.models import ModelConfig, variant_spec
from pasta.paths import checkpoint_dir, data_dir
from pasta.train.allocator import keep_freed_memory
from pasta.train.bundle import save_trained
from pasta.train.dagger import dagger_metrics
from pasta.train.datasets import vae_clouds
from pasta.train.device import training_device
from pasta.train.figures import latent_grid_figure, reconstruction_figure
from pasta.train.locate import BUNDLE_FILE, model_task
from pasta.train.progress import EpochBars, epoch_status
from pasta.train.stages import heads_stage, load_training_data, vae_file_name, vae_stage

FINAL_METRICS = ("feasibility_auc_random", "feasibility_auc_hard", "cost_r2", "policy_mse", "policy_zero_mse")
METHOD_PREFERENCE = ("gbto", "scripted")


def dataset_folder(task_name: str, profile: str, method: str | None) -> Path:
    """The dataset to train on: ``method``'s, or the first of gbto, scripted that has an index."""
    root = data_dir(task_name, profile)
    for candidate in (method,) if method else METHOD_PREFERENCE:
        if (root / candidate / "index.csv").is_file():
            return root / candidate
    raise FileNotFoundError(f"no dataset for {task_name} at profile {profile} under {root} "
                            f"(looked for {method or ' or '.join(METHOD_PREFERENCE)}); run "
                            f"`pasta data --task {task_name} --profile {profile}` first")


def _digest(*parts: object) -> str:
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def vae_key(cfg: TaskConfig, folder: Path, whole_scene: bool, model_config: ModelConfig, seed: int) -> str:
    """Hash of what the VAE depends on: its settings (precision included), the representation and the dataset
    index's content."""
    index = (folder / "index.csv").read_bytes()
    return _digest(cfg.train.vae_lr, cfg.train.vae_epochs, cfg.train.latent_dim, cfg.train.precision, whole_scene,
                   model_config.with_latent_dim(cfg.train.latent_dim).with_vae_height_input(cfg.train.vae_height_input)
                   .vae, hashlib.sha256(index).hexdigest(),
                   cfg.data.model_dump(mode="json"), seed)


@task(name="train-vae", cache_policy=NO_CACHE)
def train_vae_task(cfg: TaskConfig, data, folder: Path, model_config: ModelConfig, seed: int, device, log_epoch):
    """The task's VAE: ``folder/vae.pt`` when it exists, else trained (resuming from ``folder/training.pt``)."""
    return vae_stage(cfg, data, folder, model_config=model_config, seed=seed, on_epoch=log_epoch, device=device)


@task(name="train-heads", cache_policy=NO_CACHE)
def train_heads_task(cfg: TaskConfig, variant: str, data, vae, progress_path: Path, model_config: ModelConfig,
                     seed: int, device, log_epoch):
    """The variant's policy, feasibility and cost heads (resuming from ``progress_path``)."""
    return heads_stage(cfg, variant, data, vae, progress_path, model_config=model_config, seed=seed,
                       on_epoch=log_epoch, device=device)


class EpochLogger:
    """Logs each epoch's metrics to the active MLflow run (step = epoch, or gradient steps for the policies)
    and remembers which it logged."""

    def __init__(self) -> None:
        self.seen: set[tuple[str, int]] = set()

    def __call__(self, stage: str, epoch: int, metrics: dict[str, float]) -> None:
        tracking.log_metrics(metrics, step=epoch)
        self.seen.add((stage, epoch))

    def backfill(self, stage: str, points: Iterable[tuple[int, Mapping[str, float]]]) -> None:
        """Log the ``(epoch or step, metrics)`` points this run did not see (trained before a resume, or a
        reused VAE)."""
        for epoch, metrics in points:
            if (stage, epoch) not in self.seen:
                self(stage, epoch, dict(metrics))


@flow(name="train", flow_run_name="train-{task_name}-{profile}-{variant}")
def train(task_name: str, profile: str = "smoke", variant: str = "pasta", method: str | None = None,
          overrides: Sequence[str] = (), seed: int = 0, device: str | None = None,
          networks: dict | None = None) -> dict:
    """Train (or finish training) one variant of a task; returns the final metrics and where things are.

    ``networks`` (a ``ModelConfig.to_dict()``) changes the network sizes, e.g. for tests.
    """
    variant_spec(variant)
    cfg = load(model_task(task_name), profile, list(overrides))
    sizes = ModelConfig() if networks is None else ModelConfig.from_dict(networks)
    sizes = sizes.with_latent_dim(cfg.train.latent_dim).with_vae_height_input(cfg.train.vae_height_input)
    whole_scene = variant_spec(variant).whole_scene_latent
    folder = dataset_folder(cfg.task, profile, method)
    chosen_device = training_device(device)
    keep_freed_memory()  # the next step reuses this step's pages (pasta/train/allocator.py)
    started, started_at = time.perf_counter(), time.time()  # the run covers reading the data too
    data = load_training_data(cfg, folder, whole_scene=whole_scene, seed=seed,
                              entity_points=sizes.vae.n_decoded_points)
    key = vae_key(cfg, folder, whole_scene, sizes, seed)
    vae_folder = checkpoint_dir(cfg.task, profile, f"{vae_file_name(whole_scene)}-{key}")
    variant_folder = checkpoint_dir(cfg.task, profile, variant)
    training_hash = tracking.config_hash(cfg, without=tracking.TRAINING_IRRELEVANT)
    progress_file = variant_folder / f"training-{_digest(key, training_hash, sizes, seed)}.pt"
    logger = EpochLogger()
    bars = epoch_bars(cfg, variant, logger)
    with tracking.run(cfg.task, "train", profile=profile, variant=variant, seed=seed, cfg=cfg,
                      started_at=started_at) as active, bars:
        tracking.log_metrics({"trajectories": len(data.demos), "entities": len(data.table)})
        vae = train_vae_task(cfg, data, vae_folder, sizes, seed, chosen_device, bars)
        bars.finish("vae", f"held-out Chamfer {vae.heldout_chamfer:.4g} (best epoch {vae.best_epoch + 1})")
        logger.backfill("vae", enumerate(vae.history))
        heads = train_heads_task(cfg, variant, data, vae.vae, progress_file, sizes, seed, chosen_device, bars)
        bars.finish("heads", epoch_status("heads", heads.metrics))
        bars.finish("policy", policy_status(heads.metrics, heads.policy.steps))
        logger.backfill("heads", enumerate(heads.history))
        logger.backfill("policy", heads.policy.curve)
        for r, result in enumerate(heads.dagger):
            offset = cfg.train.policy_steps + r * cfg.train.dagger_steps
            logger.backfill("dagger", ((offset + step, {**dagger_metrics(metrics), "dagger_round": float(r + 1)})
                                       for step, metrics in result.curve))
        if heads.dagger:
            mse = heads.metrics.get("policy_mse")
            shown = "" if mse is None else f", held-out policy MSE {mse:.4g}"
            bars.finish("dagger", f"{len(heads.dagger)} rounds{shown}")
        bundle_path = variant_folder / BUNDLE_FILE
        save_trained(bundle_path, heads.bundle, epoch=len(heads.history), extra={"vae_key": key})
        summary = {"vae_heldout_chamfer": vae.heldout_chamfer, **{k: heads.metrics[k] for k in FINAL_METRICS
                                                                  if k in heads.metrics},
                   **{k: v for k, v in heads.metrics.items() if k.startswith("policy_mse_ratio_")},
                   **heads.policy.metrics()}
        if heads.dagger:
            summary["dagger_rounds"] = float(len(heads.dagger))
        summary["wall_s"] = time.perf_counter() - started
        tracking.log_metrics(summary)
        heldout = vae_clouds(data.demos, data.table, data.vae_heldout)
        with tempfile.TemporaryDirectory() as scratch:
            title = ("Fig. 4: whole-scene latent space" if whole_scene else "Fig. 3: entity latent space")
            tracking.log_artifact(latent_grid_figure(vae.vae, Path(scratch) / "latent_space.png",
                                                     title=f"{cfg.task} {title}"), "figures")
            tracking.log_artifact(reconstruction_figure(vae.vae, heldout, Path(scratch) / "reconstruction.png"),
                                  "figures")
        tracking.log_artifact(bundle_path, "checkpoints")
        summary.update(mlflow_run_id=active.info.run_id, bundle=str(bundle_path), dataset=str(folder),
                       vae=str(vae_folder / "vae.pt"), device=str(chosen_device))
    progress.summary(f"train {cfg.task} {variant}", train_line(summary), summary["wall_s"])
    return summary


def epoch_bars(cfg: TaskConfig, variant: str, then: EpochLogger) -> EpochBars:
    """Progress bars over the VAE's and the heads' epochs and the policies' steps that pass each on to ``then``."""
    labels = {"vae": f"{cfg.task} VAE", "heads": f"{cfg.task} heads ({variant})",
              "policy": f"{cfg.task} policies ({variant})"}
    totals = {"vae": cfg.train.vae_epochs, "heads": cfg.train.epochs, "policy": cfg.train.policy_steps}
    if cfg.train.dagger_rounds:
        labels["dagger"] = f"{cfg.task} DAgger ({cfg.train.dagger_rounds} rounds)"
        totals["dagger"] = cfg.train.policy_steps + cfg.train.dagger_rounds * cfg.train.dagger_steps
    return EpochBars(labels, totals, then=then)


def policy_status(metrics: Mapping[str, float], steps: Mapping[str, int]) -> str:
    """The policies' final held-out MSE (kept weights) and the steps each skill took, e.g.
    ``held-out policy MSE 0.41, steps cut 300, rearrange 175``."""
    shown = f"held-out policy MSE {metrics['policy_mse']:.4g}, " if "policy_mse" in metrics else ""
    return shown + "steps " + ", ".join(f"{skill} {n}" for skill, n in steps.items())


def train_line(summary: Mapping[str, float]) -> str:
    """The final metrics of a training run in one line."""
    shown = (("vae_heldout_chamfer", "VAE held-out Chamfer"), ("policy_mse", "policy MSE"),
             ("policy_zero_mse", "zero-action MSE"), ("feasibility_auc_random", "AUC random"),
             ("feasibility_auc_hard", "AUC hard"), ("cost_r2", "cost R2"))
    return ", ".join(f"{label} {summary[key]:.4g}" for key, label in shown if key in summary)


def run(task_name: str, profile: str = "smoke", variant: str = "pasta", method: str | None = None,
        overrides: Sequence[str] = (), seed: int = 0, device: str | None = None) -> dict:
    """Run :func:`train`; the CLI's entry point. Refuses a bad task, profile, override or variant before Prefect."""
    variant_spec(variant)
    load(model_task(task_name), profile, list(overrides))
    return train(task_name, profile, variant, method, tuple(overrides), seed, device)
