"""Training loops on tiny synthetic data: losses fall for every variant, metrics come out, resume is exact."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from pasta.models import VARIANTS, variant_spec
from pasta.models.vae import PointCloudVAE
from pasta.train.bundle import untrained
from pasta.train.datasets import vae_clouds
from pasta.train.entities import decode_latents
from pasta.train.heads_loop import HeadsSettings, HeldOut, skill_loss, train_heads
from pasta.train.policy_loop import PolicySettings, policy_loss
from pasta.train.vae_loop import VAESettings, train_vae
from tests.models.synthetic import tiny_model_config
from tests.train.helpers import heads_inputs

POLICY = PolicySettings(steps=4, lr=1e-3, batch_size=4, point_noise=0.005, eval_every=2, sigma_z=0.02,
                        sigma_t=0.01)
SETTINGS = HeadsSettings(epochs=2, feasibility_lr=1e-3, cost_lr=1e-3, feasibility_batch_size=16, cost_batch_size=16,
                         sigma_z=0.02, sigma_t=0.01, policy=POLICY, hard_copies=2, n_random=32)


@pytest.mark.parametrize("variant", VARIANTS)
def test_a_few_steps_lower_the_loss_of_every_variant(cfg, training_data, scene_data, variant):
    data = scene_data if variant_spec(variant).whole_scene_latent else training_data
    config, vae, latents, prior, sampler, _ = heads_inputs(cfg, data, variant)
    bundle = untrained(cfg, variant, prior, model_config=config, seed=0)
    settings = dataclasses.replace(SETTINGS, sigma_z=0.0, sigma_t=0.0) if variant == "no_smoothing_feasibility" \
        else SETTINGS
    rows = [sampler.transitions[k][:16] for k in range(2)]

    def loss() -> torch.Tensor:
        generator = torch.Generator().manual_seed(0)
        rng = np.random.default_rng(0)
        total = torch.zeros(())
        for k in range(2):
            total = total + skill_loss(bundle, settings, sampler, latents, k, rows[k], rng, generator)[0]
            samples = sampler.policy_samples(k, rows[k], rng, POLICY.batch_size)
            assert samples is not None
            total = total + policy_loss(bundle.models["policy"][k], variant_spec(variant), POLICY, samples, latents,
                                        prior.latent_dim, generator)
        return total

    optimiser = torch.optim.Adam([p for name, m in bundle.models.items() if name != "vae" for p in m.parameters()],
                                 lr=3e-3)
    before = loss().item()
    for _ in range(20):
        optimiser.zero_grad()
        loss().backward()
        optimiser.step()
    assert loss().item() < 0.85 * before


def test_vae_training_lowers_the_loss_and_keeps_the_best(tmp_path, training_data):
    data = training_data
    train, held = vae_clouds(data.demos, data.table, data.vae_train), vae_clouds(data.demos, data.table,
                                                                                 data.vae_heldout)
    seen = []
    result = train_vae(train, held, tiny_model_config().vae, VAESettings(epochs=3, lr=2e-3, batch_size=16),
                       tmp_path / "vae.pt", on_epoch=lambda s, e, m: seen.append((s, e)))
    assert seen == [("vae", 0), ("vae", 1), ("vae", 2)]
    losses = [h["vae_train_loss"] for h in result.history]
    assert losses[-1] < 0.7 * losses[0], losses  # measured 1.43 -> 0.76
    assert result.heldout_chamfer == min(h["vae_heldout_chamfer_epoch"] for h in result.history)


def test_bf16_vae_training_encodes_in_bfloat16_decodes_in_float32_and_lowers_the_loss(tmp_path, training_data):
    data = training_data
    train, held = vae_clouds(data.demos, data.table, data.vae_train), vae_clouds(data.demos, data.table,
                                                                                 data.vae_heldout)
    config = tiny_model_config().vae
    vae = PointCloudVAE(config)
    vae.fit_scale(train)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert vae.encode_shape(vae.normalise(train[:4])[0])[0].dtype == torch.bfloat16
        loss, _ = vae.elbo_loss(train[:4], torch.Generator().manual_seed(0))
    assert loss.dtype == torch.float32
    result = train_vae(train, held, config, VAESettings(epochs=3, lr=2e-3, batch_size=16, precision="bf16"),
                       tmp_path / "vae.pt")
    losses = [h["vae_train_loss"] for h in result.history]
    assert losses[-1] < 0.7 * losses[0], losses


class Interrupt(Exception):
    pass


def _without_timings(history):
    return [{k: v for k, v in h.items() if not k.endswith(("_epoch_s", "_round_s"))} for h in history]


def test_vae_resume_continues_from_the_saved_epoch(tmp_path, training_data):
    data = training_data
    train, held = vae_clouds(data.demos, data.table, data.vae_train), vae_clouds(data.demos, data.table,
                                                                                 data.vae_heldout)
    settings = VAESettings(epochs=2, lr=2e-3, batch_size=32)
    straight = train_vae(train, held, tiny_model_config().vae, settings, tmp_path / "a.pt")

    def stop(stage, epoch, metrics):
        raise Interrupt

    with pytest.raises(Interrupt):
        train_vae(train, held, tiny_model_config().vae, settings, tmp_path / "b.pt", on_epoch=stop)
    epochs = []
    resumed = train_vae(train, held, tiny_model_config().vae, settings, tmp_path / "b.pt",
                        on_epoch=lambda s, e, m: epochs.append(e))
    assert epochs == [1]
    assert _without_timings(resumed.history) == _without_timings(straight.history)
    for key, value in straight.vae.state_dict().items():
        assert torch.equal(value, resumed.vae.state_dict()[key]), key


def test_heads_and_policies_resume_where_they_stopped_and_report_metrics(tmp_path, cfg, training_data):
    config, vae, latents, prior, train, test = heads_inputs(cfg, training_data, "pasta")
    held_out = HeldOut.build(test, latents)
    # enough policy training to beat the all-zero action on the held-out transitions (measured 0.47 vs 0.67)
    settings = dataclasses.replace(SETTINGS, epochs=8, policy=dataclasses.replace(POLICY, steps=24, eval_every=6,
                                                                                 lr=5e-3))

    def fit(path, on_epoch=None):
        return train_heads(cfg, "pasta", vae, latents, train, held_out, prior, settings, path, model_config=config,
                           on_epoch=on_epoch)

    straight = fit(tmp_path / "a.pt")
    for key in ("feasibility_auc_random", "feasibility_auc_hard", "cost_r2", "policy_mse", "policy_zero_mse"):
        assert np.isfinite(straight.metrics[key]), key
    metrics = straight.metrics
    assert metrics["policy_mse"] < 0.9 * metrics["policy_zero_mse"], metrics
    skills = [k for k in range(2) if held_out.policy[k] is not None]  # per skill: the pooled figures split
    assert skills, "no held-out policy samples"
    names = [("cut", "rearrange")[k] for k in skills]
    for skill in names:
        ratio = metrics[f"policy_mse_{skill}"] / metrics[f"policy_zero_mse_{skill}"]
        assert metrics[f"policy_mse_ratio_{skill}"] == pytest.approx(ratio), metrics
    zeros = [metrics[f"policy_zero_mse_{s}"] for s in names]
    assert min(zeros) - 1e-9 <= metrics["policy_zero_mse"] <= max(zeros) + 1e-9, metrics
    for k, name in enumerate(("cut", "rearrange")):  # a skill without held-out samples reports nothing
        assert (f"policy_mse_ratio_{name}" in metrics) == (held_out.policy[k] is not None), metrics
    assert metrics["feasibility_auc_random"] > 0.8, metrics  # measured 1.0; 0.5 is chance
    assert metrics["policy_steps_cut"] == metrics["policy_steps_rearrange"] == 24, metrics

    def stop_at(stage, epoch):
        def stop(seen_stage, seen_epoch, metrics):
            if (seen_stage, seen_epoch) == (stage, epoch):
                raise Interrupt
        return stop

    with pytest.raises(Interrupt):
        fit(tmp_path / "b.pt", stop_at("heads", 0))
    with pytest.raises(Interrupt):
        fit(tmp_path / "b.pt", stop_at("policy", 6))
    calls = []
    resumed = fit(tmp_path / "b.pt", lambda s, e, m: calls.append((s, e)))
    assert calls == [("policy", 12), ("policy", 18), ("policy", 24)]
    for name in ("feasibility", "cost", "policy"):
        a, b = straight.bundle.models[name].state_dict(), resumed.bundle.models[name].state_dict()
        for key in a:
            assert torch.equal(a[key], b[key]), (name, key)
    assert _without_timings(straight.history) == _without_timings(resumed.history)
    assert [s for s, _ in resumed.policy.curve] == [0, 6, 12, 18, 24]
    assert _without_timings(m for _, m in straight.policy.curve) == _without_timings(
        m for _, m in resumed.policy.curve)


@pytest.mark.gpu
def test_vae_and_heads_train_on_cuda_like_on_the_cpu(tmp_path, cfg, training_data):
    data = training_data
    cuda = torch.device("cuda")
    train, held = vae_clouds(data.demos, data.table, data.vae_train), vae_clouds(data.demos, data.table,
                                                                                 data.vae_heldout)
    settings = VAESettings(epochs=2, lr=2e-3, batch_size=16)
    on_cpu = train_vae(train, held, tiny_model_config().vae, settings, tmp_path / "cpu.pt")
    on_gpu = train_vae(train, held, tiny_model_config().vae, settings, tmp_path / "gpu.pt", device=cuda)
    gpu_losses = [h["vae_train_loss"] for h in on_gpu.history]
    assert gpu_losses == pytest.approx([h["vae_train_loss"] for h in on_cpu.history], rel=0.05)
    config, vae, latents, prior, sampler, test = heads_inputs(cfg, data, "pasta")
    latents = latents.to(cuda)  # as heads_stage encodes them, on the training device
    torch.cuda.reset_peak_memory_stats()
    heads = train_heads(cfg, "pasta", vae, latents, sampler, HeldOut.build(test, latents), prior, SETTINGS,
                        tmp_path / "heads.pt", model_config=config, device=cuda)
    assert torch.cuda.max_memory_allocated() > 0
    assert all(not p.is_cuda for p in heads.bundle.models["policy"].parameters())  # handed back on the CPU
    for key in ("feasibility_auc_random", "cost_r2", "policy_mse"):
        assert np.isfinite(heads.metrics[key]), key


def test_decoded_entities_are_the_vaes_decoding_of_each_latent_in_any_batch_size():
    torch.manual_seed(0)
    vae = PointCloudVAE(dataclasses.replace(tiny_model_config().vae, height_input=True)).eval()
    vae.scale.fill_(0.05)
    latent_dim = vae.config.latent_dim
    latents = torch.randn(5, latent_dim + 3)
    decoded = decode_latents(vae, latents, batch_size=2)
    with torch.no_grad():
        expected = vae.decode(latents[:, :latent_dim], latents[:, latent_dim:]).numpy()
    assert decoded.shape == (5, vae.config.n_decoded_points, 3)
    np.testing.assert_allclose(decoded, expected, atol=1e-6)
    np.testing.assert_allclose(decoded.mean(axis=1), latents[:, latent_dim:].numpy(), atol=0.2)
