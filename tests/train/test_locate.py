"""locate.trained_models finds the local bundle (CRS-Twice -> CRS) and names the command when there is none."""

import pytest

from pasta.cli import _cmd_train, build_parser
from pasta.config import load
from pasta.models import LatentPrior
from pasta.paths import checkpoint_dir
from pasta.train.bundle import save_trained, untrained
from pasta.train.locate import trained_models
from tests.models.synthetic import tiny_model_config


@pytest.fixture
def store(tmp_path, monkeypatch):
    monkeypatch.setenv("PASTA_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")


def test_crs_twice_finds_the_crs_bundle(store):
    bundle = untrained(load("CRS", "smoke"), "pasta", LatentPrior(2, (0, 0, 0), (1, 1, 1)),
                       model_config=tiny_model_config())
    save_trained(checkpoint_dir("CRS", "smoke", "pasta") / "models.pt", bundle)
    found = trained_models("CRS-Twice", "smoke", "pasta")
    assert found.task == "CRS" and found.skill_names == ("cut", "push", "spread")


def test_missing_models_name_the_training_command(store):
    with pytest.raises(FileNotFoundError, match="pasta train --task CRS --profile smoke --variant flat3d"):
        trained_models("CRS-Twice", "smoke", "flat3d")


def test_cli_has_a_train_subcommand():
    args = build_parser().parse_args(["train", "--task", "CutRearrange", "--variant", "flat3d", "--set", "a.b=1"])
    assert args.func is _cmd_train and args.variant == "flat3d" and args.profile == "smoke" and args.set == ["a.b=1"]
