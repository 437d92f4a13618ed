"""Building blocks shared by the models: MLPs, orthogonal initialisation, masked set pooling.

Latent sets are ``(B, K, E)`` tensors of entity latents ``u = [z, t]`` (``E = latent_dim + 3``) with an
optional boolean mask ``(B, K)``: ``True`` marks a real entity, ``False`` a padded slot whose values
must not influence any output.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["SetMaxPool", "centre_set_positions", "check_set", "masked_max", "mlp", "orthogonal_init_"]


def mlp(channels: Sequence[int], *, final_activation: bool) -> nn.Sequential:
    """Linear layers ``channels[0] -> channels[1] -> ... -> channels[-1]`` with ReLU between them.

    Args:
        channels: at least two widths, input first.
        final_activation: also apply ReLU after the last layer (PyG's ``MLP`` helper as the official
            PointNet++ used it, and the per-entity set encoders); ``False`` gives a linear output.
    """
    if len(channels) < 2:
        raise ValueError(f"an MLP needs at least an input and an output width, got {tuple(channels)}")
    layers: list[nn.Module] = []
    for i, (c_in, c_out) in enumerate(zip(channels[:-1], channels[1:], strict=True)):
        layers.append(nn.Linear(c_in, c_out))
        if final_activation or i < len(channels) - 2:
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


def orthogonal_init_(module: nn.Module) -> None:
    """Orthogonal weights and zero biases for every ``nn.Linear`` inside ``module`` (official ``weight_init``)."""
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            nn.init.orthogonal_(layer.weight)
            nn.init.zeros_(layer.bias)


def check_set(u: torch.Tensor, mask: torch.Tensor | None, entity_dim: int, name: str) -> torch.Tensor:
    """Validate a latent set ``(B, K, entity_dim)`` and return its mask ``(B, K)`` (all ``True`` if ``None``).

    Raises:
        ValueError: on a wrong shape, or when a row has no valid entity (its max-pool would be empty).
    """
    if u.ndim != 3 or u.shape[-1] != entity_dim:
        raise ValueError(f"{name} must have shape (B, K, {entity_dim}), got {tuple(u.shape)}")
    if mask is None:
        return torch.ones(u.shape[:2], dtype=torch.bool, device=u.device)
    if mask.shape != u.shape[:2] or mask.dtype != torch.bool:
        raise ValueError(
            f"{name} mask must be a bool tensor of shape {tuple(u.shape[:2])}, got {mask.dtype} {tuple(mask.shape)}"
        )
    if not bool(mask.any(dim=1).all()):
        raise ValueError(f"every row of {name} needs at least one valid entity")
    return mask


def masked_max(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Max over the entity axis of ``x (B, K, C)``, ignoring slots where ``mask (B, K)`` is ``False``.

    Returns ``(B, C)``. Every row must have a valid entity (see ``check_set``).
    """
    return x.masked_fill(~mask.unsqueeze(-1), float("-inf")).max(dim=1).values


def centre_set_positions(
    sets: Sequence[torch.Tensor], masks: Sequence[torch.Tensor], latent_dim: int
) -> list[torch.Tensor]:
    """Subtract from every entity's position ``t`` the mean ``t`` of all valid entities of all ``sets``.

    The official ``fea_center``/``rew_center`` (model_spec §2.1, §3.1): it makes a predictor invariant to
    translating the whole input, while the shape codes ``z`` stay absolute.

    Args:
        sets: latent sets ``(B, K_i, latent_dim + 3)``.
        masks: their masks ``(B, K_i)``.
        latent_dim: ``D_z``; positions are the last 3 numbers of each entity.

    Returns:
        The sets with centred positions, same shapes.
    """
    valid = torch.cat(list(masks), dim=1).unsqueeze(-1)  # (B, sum K, 1)
    positions = torch.cat([u[..., latent_dim:] for u in sets], dim=1)  # (B, sum K, 3)
    total = torch.where(valid, positions, torch.zeros_like(positions)).sum(dim=1, keepdim=True)
    centre = total / valid.sum(dim=1, keepdim=True).to(positions.dtype)  # (B, 1, 3)
    return [torch.cat([u[..., :latent_dim], u[..., latent_dim:] - centre], dim=-1) for u in sets]


class SetMaxPool(nn.Module):
    """A per-entity MLP (ReLU after every layer) followed by a max over the valid entities.

    ``(B, K, channels[0])`` and a mask ``(B, K)`` -> ``(B, channels[-1])``; invariant to entity order.
    """

    def __init__(self, channels: Sequence[int]) -> None:
        super().__init__()
        self.net = mlp(channels, final_activation=True)

    def forward(self, u: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return masked_max(self.net(u), mask)
