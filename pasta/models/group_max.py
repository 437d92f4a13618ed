"""A linear layer followed by a max over groups of rows, with a backward pass that touches only the winners.

PointNet-style encoders end each stage with ``max_g (W x_g)``: a linear layer applied to every member of a
group (a ball's neighbours, a cloud's points), then a max over the members. Autograd's own backward of that
pair is dense: the max scatters its gradient into a zero tensor as large as the layer's output, and the
layer's backward multiplies that mostly-zero tensor by ``W`` and by the inputs. Only one member per group
and output channel receives a gradient, so ``linear_group_max`` keeps the winners' indices and computes

* ``dL/dW[c] = sum_m g[m, c] x[winner(m, c)]``, a sparse (CSR) product with one entry per (group, channel)
  (in float32 at least),
* ``dL/dx[r] = sum_{(m, c) won by r} g[m, c] W[c]``, a sparse (COO) product with the same entries,

which is exact (no approximation: the same sums as the dense backward, without the zeros). Ties in the max
go to one member (the one ``torch.max`` returns), as in autograd's ``max(dim)`` backward.

Rows are member-major: row ``g * M + m`` is member ``g`` of group ``m``, the layout of
``pasta.models.pointnet._mlp_max``.
"""

from __future__ import annotations

import warnings

import torch
from torch import nn

__all__ = ["linear_group_max", "mlp_max_over_points"]


class _LinearGroupMax(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, n_members: int) -> torch.Tensor:
        y = torch.mm(x, weight.t())  # (G * M, C_out); reduced precision under a caller's autocast
        values, winners = y.view(n_members, -1, y.shape[-1]).max(dim=0)  # (M, C_out) each
        ctx.save_for_backward(x, weight, winners)
        return values

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight, winners = ctx.saved_tensors
        n_groups, c_out = winners.shape
        rows = winners * n_groups + torch.arange(n_groups, device=winners.device).unsqueeze(1)  # (M, C_out)
        # dL/dW sums M terms per entry: bfloat16 gradients accumulate it in float32. dL/dx sums the few
        # channels a row wins (2 on average in the policy's first stage), in the gradient's own precision
        # as autocast's dense backward would round it.
        dtype = torch.promote_types(grad.dtype, torch.float32)
        grad_x = grad_weight = None
        with warnings.catch_warnings(), torch.autocast(device_type=x.device.type, enabled=False):
            warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
            if ctx.needs_input_grad[1]:
                # (C_out, G * M) with exactly M entries per row: one per group.
                row_starts = torch.arange(0, n_groups * c_out + 1, n_groups, device=rows.device)
                by_channel = torch.sparse_csr_tensor(
                    row_starts, rows.t().reshape(-1), grad.t().reshape(-1).to(dtype), (c_out, x.shape[0]),
                    check_invariants=False,
                )
                grad_weight = (by_channel @ x.to(dtype)).to(weight.dtype)
            if ctx.needs_input_grad[0]:
                channels = torch.arange(c_out, device=rows.device).repeat(n_groups)
                by_row = torch.sparse_coo_tensor(
                    torch.stack([rows.reshape(-1), channels]), grad.reshape(-1), (x.shape[0], c_out),
                    check_invariants=False,
                )
                grad_x = torch.sparse.mm(by_row, weight.to(grad.dtype)).to(x.dtype)
        return grad_x, grad_weight, None


def linear_group_max(x: torch.Tensor, weight: torch.Tensor, n_members: int) -> torch.Tensor:
    """Per group, the max over its members of ``x @ weight.T`` (no bias: add it after the max).

    Args:
        x: ``(G * M, C_in)`` member-major rows (row ``g * M + m`` is member ``g`` of group ``m``).
        weight: ``(C_out, C_in)``, an ``nn.Linear``'s weight.
        n_members: ``G``.

    Returns:
        ``(M, C_out)``. Equal to ``torch.mm(x, weight.t()).view(G, M, -1).max(dim=0).values`` with the
        same gradients; the backward pass costs one term per (group, channel) instead of ``G``.
    """
    if x.ndim != 2 or weight.ndim != 2 or x.shape[1] != weight.shape[1]:
        raise ValueError(
            f"x must be (R, C_in) and weight (C_out, C_in), got {tuple(x.shape)} and {tuple(weight.shape)}"
        )
    if n_members < 1 or x.shape[0] % n_members:
        raise ValueError(f"{x.shape[0]} rows do not split into groups of {n_members} members")
    return _LinearGroupMax.apply(x, weight, n_members)


def mlp_max_over_points(net: nn.Sequential, points: torch.Tensor) -> torch.Tensor:
    """A per-point MLP (``pasta.models.layers.mlp``) max-pooled over each cloud's points, ``(B, N, C_in)`` ->
    ``(B, C_out)``, with its last layer and the max as one ``linear_group_max``.

    The last layer's bias, and a final ReLU if ``net`` ends with one, commute with the max and follow it.
    The layers before run on 2-D point-major rows ``(N * B, C)`` (B groups of N members).
    """
    *layers, final = net
    last, activation = (layers.pop(), final) if isinstance(final, nn.ReLU) else (final, None)
    rows = points.transpose(0, 1).reshape(-1, points.shape[-1])
    for layer in layers:
        rows = layer(rows)
    pooled = linear_group_max(rows, last.weight, points.shape[1]) + last.bias
    return pooled.relu() if activation is not None else pooled
