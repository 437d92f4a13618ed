"""The compact point-cloud encoder of the policies: one PointNet per cloud (``policy.encoder: pointnet``).

Each cloud (observation, tool, goal) gets its own per-point MLP (``3 -> 64 -> 128 -> 256``, ReLU after every
layer), max-pooled over its points; the pooled features are concatenated (``3 x 256 = 768``). This is the
encoder of recent 3D imitation policies; it has no sampling, grouping or neighbourhoods, so a training step
costs one to two orders of magnitude less than the PointNet++ of ``pasta.models.pointnet``
(``docs/models.md``). The cloud a point belongs to is given by the MLP that sees it, so no role tags are
needed.

Inputs are normalised before the MLPs: ``(p - centre) / scale``, with ``centre`` the mean point and
``scale`` the standard deviation of the centred coordinates (one number for the three axes, so shapes are
not stretched) of the training points. One pair serves every cloud, so the clouds stay in one frame and
their relative positions (the tool against the dough) survive. The pair is set from the first batch the
module sees in training mode (data-dependent initialisation, as Glow's ActNorm) or by ``fit_normalisation``;
it lives in buffers, so it travels in the state dict with the weights and evaluation uses the same one.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from pasta.models.group_max import mlp_max_over_points
from pasta.models.layers import mlp, orthogonal_init_

__all__ = ["CloudPointNet", "CloudPointNetConfig"]

MIN_SCALE = 1e-6  # floor on the fitted scale: a degenerate batch (all points equal) must not divide by 0


@dataclass(frozen=True)
class CloudPointNetConfig:
    """The compact policy design (probed in ``shared/reference/skill-probes.md``).

    Attributes:
        channels: per-point MLP widths after the 3 input coordinates (``3 -> 64 -> 128 -> 256``).
        head_channels: hidden widths of the action MLP that follows this encoder in a policy
            (``768 -> 256 -> 256 -> action_dim`` for three clouds).
    """

    channels: tuple[int, ...] = (64, 128, 256)
    head_channels: tuple[int, ...] = (256, 256)


class CloudPointNet(nn.Module):
    """``n_clouds`` clouds ``(B, N_i, 3)`` -> features ``(B, n_clouds * channels[-1])``.

    Invariant to the order of the points within each cloud (max pooling), not to swapping clouds. All
    weights are orthogonally initialised with zero biases.

    Buffers:
        centre: ``(3,)`` mean training point.
        scale: ``()`` standard deviation of the centred training coordinates.
        fitted: ``()`` bool, whether ``centre`` and ``scale`` were set (before that: 0 and 1).
    """

    def __init__(self, n_clouds: int, config: CloudPointNetConfig = CloudPointNetConfig()) -> None:
        super().__init__()
        if n_clouds < 1:
            raise ValueError(f"need at least one cloud, got {n_clouds}")
        self.config = config
        self.nets = nn.ModuleList(mlp((3, *config.channels), final_activation=True) for _ in range(n_clouds))
        self.register_buffer("centre", torch.zeros(3))
        self.register_buffer("scale", torch.ones(()))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))
        orthogonal_init_(self)

    @property
    def out_dim(self) -> int:
        return len(self.nets) * self.config.channels[-1]

    def fit_normalisation(self, *clouds: torch.Tensor) -> None:
        """Set ``centre`` and ``scale`` from all points of ``clouds`` (each ``(B, N_i, 3)``), pooled."""
        with torch.no_grad():
            points = torch.cat([cloud.detach().reshape(-1, 3) for cloud in clouds])
            centre = points.mean(dim=0)
            self.centre.copy_(centre)
            self.scale.copy_((points - centre).square().mean().sqrt().clamp_min(MIN_SCALE))
            self.fitted.fill_(True)

    def forward(self, *clouds: torch.Tensor) -> torch.Tensor:
        """Encode one batch: ``clouds[i] (B, N_i, 3)`` -> ``(B, out_dim)``, cloud ``i``'s features at
        ``[i * C, (i + 1) * C)``. In training mode the first call fits the normalisation."""
        self._check(clouds)
        if self.training and not bool(self.fitted):
            self.fit_normalisation(*clouds)
        return torch.cat([self._pool(net, cloud) for net, cloud in zip(self.nets, clouds, strict=True)], dim=-1)

    def _pool(self, net: nn.Sequential, cloud: torch.Tensor) -> torch.Tensor:
        """``net`` on every normalised point of ``cloud (B, N, 3)``, max over the points: ``(B, C)``.

        ``mlp_max_over_points`` runs the MLP on 2-D rows (a Linear on a 3-D input works on a view of its
        output, and the in-place ReLU on that view costs a copy in backward) and its last layer and the max
        as one ``linear_group_max`` (backward through each channel's winning point only).
        """
        return mlp_max_over_points(net, (cloud - self.centre) / self.scale)

    def _check(self, clouds: tuple[torch.Tensor, ...]) -> None:
        if len(clouds) != len(self.nets):
            raise ValueError(f"expected {len(self.nets)} clouds, got {len(clouds)}")
        for i, cloud in enumerate(clouds):
            if cloud.ndim != 3 or cloud.shape[-1] != 3 or cloud.shape[0] != clouds[0].shape[0] or cloud.shape[1] < 1:
                raise ValueError(f"cloud {i} must have shape ({clouds[0].shape[0]}, N >= 1, 3), "
                                 f"got {tuple(cloud.shape)}")
