"""Checkpoints: atomic save, identical outputs after load, config round trip."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from pasta.models import ModelConfig, build_models, load_checkpoint, restore_models, save_checkpoint
from tests.models.synthetic import box_clouds, tiny_model_config


def outputs(models, gen):
    clouds = box_clouds(2, 32, gen)
    u_obs, u_goal = torch.randn(2, 2, 5, generator=gen), torch.randn(2, 1, 5, generator=gen)
    with torch.no_grad():
        return [
            *models["vae"].encode(clouds),
            models["vae"].decode(torch.randn(2, 2, generator=gen), torch.rand(2, 3, generator=gen)),
            models["feasibility"][0](u_obs, u_goal),
            models["cost"].set_cost(u_obs, u_goal),
            models["policy"][0](clouds, clouds[:, :8], clouds + 0.1),
        ]


def test_round_trip_gives_identical_outputs(tmp_path):
    config = tiny_model_config()
    models = build_models("pasta", 4, config, seed=0)
    models["vae"].fit_scale(box_clouds(4, 32, torch.Generator().manual_seed(9)))
    optimiser = torch.optim.Adam(models["cost"].parameters(), lr=1e-3)
    models["cost"](torch.randn(3, 5), torch.randn(3, 5)).sum().backward()
    optimiser.step()
    path = save_checkpoint(tmp_path / "run" / "model.pt", models, {"cost": optimiser.state_dict()}, 7, config.to_dict())
    assert sorted(p.name for p in path.parent.iterdir()) == ["model.pt"]  # no temporary file left behind

    checkpoint = load_checkpoint(path)
    assert checkpoint.epoch == 7 and set(checkpoint.optimiser_states) == {"cost"}
    restored_config = ModelConfig.from_dict(checkpoint.config)
    assert restored_config == config
    fresh = build_models("pasta", 4, restored_config, seed=1)
    assert not torch.equal(fresh["cost"].net[0].weight, models["cost"].net[0].weight)
    restore_models(fresh, checkpoint)
    for a, b in zip(outputs(models, torch.Generator().manual_seed(0)), outputs(fresh, torch.Generator().manual_seed(0)),
                    strict=True):
        assert torch.equal(a, b)
    assert torch.equal(fresh["vae"].scale, models["vae"].scale)
    new_optimiser = torch.optim.Adam(fresh["cost"].parameters(), lr=1e-3)
    new_optimiser.load_state_dict(checkpoint.optimiser_states["cost"])

    save_checkpoint(path, models, None, 8, {})  # replaces the old file
    assert load_checkpoint(path).epoch == 8


def test_failed_save_keeps_the_old_file(tmp_path):
    models = build_models("pasta", 4, tiny_model_config())
    path = save_checkpoint(tmp_path / "model.pt", models, None, 1, {})
    # pickle's error for a function defined in a test: "Can't pickle local object '...<lambda>'"
    with pytest.raises(AttributeError, match=r"Can't pickle local object '.*<lambda>'") as failure:
        save_checkpoint(path, models, None, 2, {"bad": lambda: None})
    # it failed while torch.save was writing the payload, not before writing started
    assert any(entry.name == "atomic_write_bytes" for entry in failure.traceback)
    assert any(entry.name == "save" and Path(entry.path).name == "serialization.py" for entry in failure.traceback)
    assert load_checkpoint(path).epoch == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt"]


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(ValueError):
        load_checkpoint(tmp_path / "other.pt")
    models = build_models("pasta", 4, tiny_model_config())
    checkpoint = load_checkpoint(save_checkpoint(tmp_path / "m.pt", models, None, 0, {}))
    with pytest.raises(ValueError):
        restore_models({"vae": models["vae"]}, checkpoint)
    with pytest.raises(ValueError):
        ModelConfig.from_dict({"vae": {"latent_dim": 2, "width": 3}})
