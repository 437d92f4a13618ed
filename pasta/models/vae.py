"""Point-cloud VAE for single entities: PointNet encoder, MLP decoder, Chamfer ELBO (appendix eq. 2).

Each entity cloud ``P`` is split into its centre ``t = mean(P)`` and its normalised shape
``(P - t) / scale``, with one global ``scale`` (the standard deviation of all centred training
coordinates, model_spec §1.5) kept as a buffer. Only the shape is encoded, into a diagonal Gaussian
over ``z`` (``latent_dim`` = 2); the entity latent is ``u = [z, t]`` (5-D).

The official decoder was PointFlow's conditional CNF (model_spec §1.3), far too slow on a CPU. This
one is an MLP ``z -> M x 3`` trained with the Chamfer distance (model_spec §1.9 option b); see
``docs/models.md`` for the choice.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pasta.geometry.distances import chamfer_distance
from pasta.models import random_draws
from pasta.models.group_max import mlp_max_over_points
from pasta.models.layers import mlp

__all__ = ["PointCloudVAE", "VAEConfig"]


@dataclass(frozen=True)
class VAEConfig:
    """VAE hyper-parameters.

    Attributes:
        latent_dim: ``D_z`` (2 in every PASTA run).
        encoder_channels: widths of the shared per-point MLP after the 3 input coordinates.
        head_hidden: hidden width of the mean and log-variance heads.
        decoder_channels: hidden widths of the decoder MLP between ``z`` and the ``M x 3`` output.
        n_decoded_points: ``M``, points per decoded entity (official 1000).
        beta: weight of the KL term (model_spec §1.9 suggests 1e-3 to 1e-2).
        height_input: the decoder also reads the entity centre's height ``t_y / scale``. Dough rests on the
            floor, so the centre's height tells a piece's thickness, which a 2-D ``z`` shared with every other
            shape feature holds only roughly. False (the appendix's): ``z`` alone.
    """

    latent_dim: int = 2
    encoder_channels: tuple[int, ...] = (128, 256, 512)
    head_hidden: int = 256
    decoder_channels: tuple[int, ...] = (256, 256)
    n_decoded_points: int = 1000
    beta: float = 1e-3
    height_input: bool = False

    @property
    def entity_dim(self) -> int:
        """``latent_dim + 3``: the size of ``u = [z, t]``."""
        return self.latent_dim + 3


class PointCloudVAE(nn.Module):
    """Entity VAE: ``encode`` points to ``(z_mean, z_logvar, t)``, ``decode`` ``(z, t)`` to points.

    The encoder is a PointNet: per-point MLP ``3 -> 128 -> 256 -> 512`` (ReLU between layers), max over
    points, then two heads ``512 -> 256 -> D_z`` for the mean and the log-variance. There is no batch
    normalisation, so an entity's code does not depend on the other clouds in its batch. The last layer
    and the max run as one ``linear_group_max`` (its bias added after the max), whose backward pass
    touches only the point that wins each channel.
    """

    scale: torch.Tensor

    def __init__(self, config: VAEConfig = VAEConfig()) -> None:
        super().__init__()
        self.config = config
        self.point_net = mlp((3, *config.encoder_channels), final_activation=False)
        width = config.encoder_channels[-1]
        self.mean_head = mlp((width, config.head_hidden, config.latent_dim), final_activation=False)
        self.logvar_head = mlp((width, config.head_hidden, config.latent_dim), final_activation=False)
        self.decoder = mlp(
            (config.latent_dim + (1 if config.height_input else 0), *config.decoder_channels,
             3 * config.n_decoded_points), final_activation=False
        )
        self.register_buffer("scale", torch.tensor(1.0))

    def fit_scale(self, points: torch.Tensor) -> None:
        """Set ``scale`` to the standard deviation of all coordinates of the centred training clouds.

        Args:
            points: ``(B, N, 3)`` training entities in world coordinates.
        """
        with torch.no_grad():
            centred = points - points.mean(dim=1, keepdim=True)
            value = centred.reshape(-1).std()
            if not bool(value > 0):
                raise ValueError("cannot fit the scale: the centred clouds have zero spread")
            self.scale.copy_(value)

    def normalise(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B, N, 3)`` world points -> ``(shape (B, N, 3), t (B, 3))`` with ``shape = (points - t) / scale``."""
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must have shape (B, N, 3), got {tuple(points.shape)}")
        t = points.mean(dim=1)
        return (points - t.unsqueeze(1)) / self.scale, t

    def encode_shape(self, shape: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised shapes ``(B, N, 3)`` -> ``(z_mean (B, D_z), z_logvar (B, D_z))``."""
        pooled = mlp_max_over_points(self.point_net, shape)  # (B, 512)
        return self.mean_head(pooled), self.logvar_head(pooled)

    def encode(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """World points ``(B, N, 3)`` -> ``(z_mean (B, D_z), z_logvar (B, D_z), t (B, 3))``."""
        shape, t = self.normalise(points)
        z_mean, z_logvar = self.encode_shape(shape)
        return z_mean, z_logvar, t

    def encode_entities(self, points: torch.Tensor) -> torch.Tensor:
        """World points ``(B, N, 3)`` -> entity latents ``u = [z_mean, t]`` ``(B, D_z + 3)`` (posterior mean)."""
        z_mean, _, t = self.encode(points)
        return torch.cat([z_mean, t], dim=-1)

    def decode_shape(self, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """``z (B, D_z)`` and the centres ``t (B, 3)`` (read only with ``config.height_input``) -> normalised shapes
        ``(B, M, 3)``."""
        if self.config.height_input:
            z = torch.cat([z, t[:, 1:2].to(z.dtype) / self.scale], dim=-1)
        return self.decoder(z).view(z.shape[0], self.config.n_decoded_points, 3)

    def decode(self, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """``z (B, D_z)``, ``t (B, 3)`` -> world points ``(B, M, 3)`` (``shape * scale + t``)."""
        return self.decode_shape(z, t) * self.scale + t.unsqueeze(1)

    def elbo_loss(
        self, points: torch.Tensor, generator: torch.Generator | None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Negative ELBO with a Chamfer reconstruction term: ``CD(decode(z), shape) + beta * KL(q(z|P) || N(0, I))``.

        ``z`` is drawn by reparameterisation with noise from ``generator``. The Chamfer distance (squared,
        summed over both directions, ``pasta.geometry.chamfer_distance``) is taken in normalised
        coordinates, so the loss does not depend on the world scale. Under a caller's autocast only the
        encoder runs in reduced precision: the decoder and the Chamfer distance (whose squared distances
        cancel) always run in float32.

        Args:
            points: ``(B, N, 3)`` entities in world coordinates.
            generator: source of the reparameterisation noise (``None``: torch's global generator).

        Returns:
            The scalar loss (mean over the batch) and floats ``loss``, ``reconstruction`` (normalised
            Chamfer), ``kl`` (nats per entity) and ``chamfer_world`` (the Chamfer in world units).
        """
        shape, t = self.normalise(points)
        z_mean, z_logvar = (value.float() for value in self.encode_shape(shape))
        with torch.autocast(device_type=shape.device.type, enabled=False):  # a caller's bf16 covers the encoder only
            noise = random_draws.randn(z_mean.shape, generator, dtype=z_mean.dtype, device=z_mean.device)
            z = z_mean + noise * torch.exp(0.5 * z_logvar)
            reconstruction = chamfer_distance(self.decode_shape(z, t.float()), shape).mean()
            kl = 0.5 * (z_mean.square() + z_logvar.exp() - 1.0 - z_logvar).sum(dim=-1).mean()
        loss = reconstruction + self.config.beta * kl
        metrics = {
            "loss": loss.item(),
            "reconstruction": reconstruction.item(),
            "kl": kl.item(),
            "chamfer_world": (reconstruction.detach() * self.scale.square()).item(),
        }
        return loss, metrics
