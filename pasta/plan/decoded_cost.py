"""The decoded set cost: Chamfer distance between the decoded clouds of two entity latents.

The appendix's planner scores the final set with the learned cost predictor (a regression of the
Chamfer distance). The official decoder was a point CNF, so decoding while planning was about 1000
times slower (appendix: 37,200 s against 35 s on CutRearrange). Our decoder is an MLP, and decoding a
fixed subset of its output points is cheaper than the cost network itself. The decoded cost cannot be
exploited the way a regression can: at ``small`` the planner drives the learned cost below zero on
latents whose decoded Chamfer to the goal is 0.06 (docs/planning.md). ``plan.cost: decoded`` selects it.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from pasta.plan.functions import PairCostFn

__all__ = ["decoded_chamfer_cost", "subset_decoder"]


def subset_decoder(vae: nn.Module, n_points: int) -> nn.Sequential:
    """A frozen copy of ``vae.decoder`` that outputs only ``n_points`` of its ``M`` points, evenly strided.

    ``z (B, D_z)`` (with ``vae.config.height_input``: ``[z, t_y / scale]`` ``(B, D_z + 1)``, as
    ``PointCloudVAE.decode_shape`` builds it) -> ``(B, 3 * n_points)`` normalised coordinates, equal to the full
    decoder's output at point slots ``0, s, 2s, ...`` with ``s = M // n_points``.
    """
    n_decoded = vae.config.n_decoded_points
    if not 1 <= n_points <= n_decoded:
        raise ValueError(f"cost_points must be in [1, {n_decoded}] (the decoder's points), got {n_points}")
    layers = list(copy.deepcopy(vae.decoder))
    last = layers[-1]
    if not isinstance(last, nn.Linear) or last.out_features != 3 * n_decoded:
        raise ValueError(f"the decoder must end with a Linear layer to {3 * n_decoded} outputs, got {last}")
    slots = torch.arange(n_points, device=last.weight.device) * (n_decoded // n_points)
    rows = (slots.unsqueeze(1) * 3 + torch.arange(3, device=slots.device)).reshape(-1)
    head = nn.Linear(last.in_features, rows.numel()).to(last.weight.device, last.weight.dtype)
    with torch.no_grad():
        head.weight.copy_(last.weight[rows])
        head.bias.copy_(last.bias[rows])
    decoder = nn.Sequential(*layers[:-1], head).eval()
    for p in decoder.parameters():
        p.requires_grad_(False)
    return decoder


def decoded_chamfer_cost(vae: nn.Module, n_points: int) -> PairCostFn:
    """``c(a, b)``: Chamfer distance (squared, both directions, as the cost predictor's target) between the
    ``n_points``-point decoded clouds of entity latents ``a (..., D_z + 3)`` and ``b (..., D_z + 3)``; ``(...)``."""
    decoder = subset_decoder(vae, n_points)
    latent_dim = vae.config.latent_dim
    scale = vae.scale.detach().clone()
    height_input = vae.config.height_input

    def points(u: torch.Tensor) -> torch.Tensor:
        code = torch.cat([u[:, :latent_dim], u[:, latent_dim + 1 : latent_dim + 2] / scale], dim=-1) if height_input \
            else u[:, :latent_dim]
        return decoder(code).view(-1, n_points, 3) * scale + u[:, None, latent_dim:]

    def cost(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        batch = torch.broadcast_shapes(a.shape[:-1], b.shape[:-1])
        pa = points(a.expand(*batch, a.shape[-1]).reshape(-1, a.shape[-1]))
        pb = points(b.expand(*batch, b.shape[-1]).reshape(-1, b.shape[-1]))
        squared = (pa.pow(2).sum(-1, keepdim=True) + pb.pow(2).sum(-1).unsqueeze(1)
                   - 2 * pa @ pb.transpose(1, 2)).clamp_min(0.0)
        return (squared.min(dim=2).values.mean(dim=1) + squared.min(dim=1).values.mean(dim=1)).view(batch)

    return cost
