"""Find the trained models of a (task, profile, variant): the local bundle, else the newest train run's artifact."""

from __future__ import annotations

import torch

from pasta.paths import BUNDLE_FILE, checkpoint_dir, model_task
from pasta.train.bundle import TrainedModels, load_trained

__all__ = ["BUNDLE_FILE", "model_task", "trained_models"]


def trained_models(task: str, profile: str, variant: str,
                   map_location: str | torch.device = "cpu") -> TrainedModels:
    """``checkpoint_dir(task, profile, variant) / models.pt``, or the ``checkpoints/models.pt`` artifact of the
    newest finished train run with those tags (downloaded to that path).

    Raises:
        FileNotFoundError: naming the task, profile, variant and the command that trains them.
    """
    owner = model_task(task)
    path = checkpoint_dir(owner, profile, variant) / BUNDLE_FILE
    if not path.is_file():
        from pasta import tracking  # MLflow only when the local file is missing

        tracking.download_latest_artifact(owner, "train", f"checkpoints/{BUNDLE_FILE}", path.parent,
                                          profile=profile, variant=variant)
    if not path.is_file():
        raise FileNotFoundError(
            f"no trained models for task {owner!r} (asked for {task!r}), profile {profile!r}, variant {variant!r}: "
            f"not at {path} and no finished train run in MLflow; train them with "
            f"`pasta train --task {owner} --profile {profile} --variant {variant}`"
        )
    return load_trained(path, map_location)
