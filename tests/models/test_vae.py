"""Point-cloud VAE: shapes, normalisation, world-frame decoding, ELBO, training."""

from __future__ import annotations

import pytest
import torch

from pasta.models import PointCloudVAE, VAEConfig
from tests.models.synthetic import box_clouds, tiny_model_config, train


def test_default_shapes():
    torch.manual_seed(0)
    vae = PointCloudVAE()
    points = box_clouds(3, 128, torch.Generator().manual_seed(0))
    z_mean, z_logvar, t = vae.encode(points)
    assert z_mean.shape == z_logvar.shape == (3, 2) and t.shape == (3, 3)
    torch.testing.assert_close(t, points.mean(dim=1))
    assert vae.decode(z_mean, t).shape == (3, 1000, 3)
    assert vae.encode_entities(points).shape == (3, 5)
    assert [m.out_features for m in vae.point_net[::2]] == [128, 256, 512]


def test_scale_normalisation_and_world_frame_decoding():
    torch.manual_seed(0)
    vae = PointCloudVAE(VAEConfig(n_decoded_points=50))
    points = box_clouds(8, 64, torch.Generator().manual_seed(1))
    vae.fit_scale(points)
    centred = points - points.mean(dim=1, keepdim=True)
    torch.testing.assert_close(vae.scale, centred.reshape(-1).std())
    shape, t = vae.normalise(points)
    torch.testing.assert_close(shape * vae.scale + t[:, None], points)
    # the code depends on the shape only: translating an entity moves t, not z
    z1, _, t1 = vae.encode(points)
    z2, _, t2 = vae.encode(points + torch.tensor([0.1, -0.2, 0.3]))
    torch.testing.assert_close(z1, z2, atol=1e-5, rtol=0)
    torch.testing.assert_close(t2 - t1, torch.tensor([0.1, -0.2, 0.3]).expand(8, 3))
    z = torch.randn(8, 2)
    offset = torch.tensor([0.5, 0.0, -0.5])
    torch.testing.assert_close(vae.decode(z, t1 + offset), vae.decode(z, t1) + offset)
    with pytest.raises(ValueError):
        vae.fit_scale(torch.zeros(2, 5, 3))


def test_elbo_metrics_and_determinism():
    torch.manual_seed(0)
    vae = PointCloudVAE(tiny_model_config().vae)
    points = box_clouds(4, 64, torch.Generator().manual_seed(2))
    vae.fit_scale(points)
    loss, metrics = vae.elbo_loss(points, torch.Generator().manual_seed(0))
    assert set(metrics) == {"loss", "reconstruction", "kl", "chamfer_world"}
    assert metrics["loss"] == pytest.approx(metrics["reconstruction"] + vae.config.beta * metrics["kl"], rel=1e-5)
    assert metrics["kl"] >= 0 and metrics["chamfer_world"] == pytest.approx(
        metrics["reconstruction"] * float(vae.scale) ** 2, rel=1e-5
    )
    again, _ = vae.elbo_loss(points, torch.Generator().manual_seed(0))
    assert again.item() == loss.item()


def test_training_lowers_the_loss_on_random_boxes():
    torch.manual_seed(0)
    vae = PointCloudVAE(tiny_model_config().vae)
    points = box_clouds(16, 64, torch.Generator().manual_seed(3))
    vae.fit_scale(points)
    first, last = train(lambda: vae.elbo_loss(points, torch.Generator().manual_seed(0))[0], vae.parameters(), lr=3e-3)
    assert last < 0.5 * first


def test_encoder_matches_the_plain_mlp_and_max_with_gradients():
    gen = torch.Generator().manual_seed(5)
    vae = PointCloudVAE(VAEConfig(encoder_channels=(16, 24, 32), head_hidden=8, n_decoded_points=20)).double()
    shape = torch.randn(3, 40, 3, generator=gen, dtype=torch.float64)

    def mean_and_gradients(encode):
        vae.zero_grad()
        z_mean, z_logvar = encode()
        (z_mean.sum() + 0.5 * z_logvar.sum()).backward()
        return z_mean.detach(), {name: p.grad.clone() for name, p in vae.named_parameters() if p.grad is not None}

    fast, fast_grads = mean_and_gradients(lambda: vae.encode_shape(shape))
    pooled = lambda: vae.point_net(shape).max(dim=1).values  # noqa: E731
    plain, plain_grads = mean_and_gradients(lambda: (vae.mean_head(pooled()), vae.logvar_head(pooled())))
    torch.testing.assert_close(fast, plain, rtol=1e-12, atol=1e-12)
    assert fast_grads.keys() == plain_grads.keys() and "point_net.4.weight" in fast_grads
    for name, grad in fast_grads.items():
        torch.testing.assert_close(grad, plain_grads[name], rtol=1e-10, atol=1e-12, msg=name)


def test_a_height_reading_decoder_moves_with_the_centre_across_the_floor_but_not_up_and_down():
    """``height_input``: the decoder reads ``t_y / scale``, so moving a centre along x or z only translates the
    decoded cloud, while raising it changes the decoded shape (a thicker piece rests with a higher centre); the
    ELBO still trains."""
    torch.manual_seed(0)
    vae = PointCloudVAE(VAEConfig(encoder_channels=(16,), head_hidden=16, decoder_channels=(32,), n_decoded_points=30,
                                  height_input=True))
    assert vae.decoder[0].in_features == 3
    points = box_clouds(16, 64, torch.Generator().manual_seed(4))
    vae.fit_scale(points)
    z, t = torch.randn(4, 2), points[:4].mean(dim=1)
    across = torch.tensor([0.2, 0.0, -0.1])
    torch.testing.assert_close(vae.decode(z, t + across), vae.decode(z, t) + across)
    up = torch.tensor([0.0, 0.05, 0.0])
    assert not torch.allclose(vae.decode(z, t + up), vae.decode(z, t) + up, atol=1e-4)
    first, last = train(lambda: vae.elbo_loss(points, torch.Generator().manual_seed(0))[0], vae.parameters(), lr=3e-3)
    assert last < 0.5 * first
