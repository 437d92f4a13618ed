"""linear_group_max against the dense linear layer and max it replaces: values and gradients."""

from __future__ import annotations

import pytest
import torch

from pasta.models.group_max import linear_group_max


def dense_group_max(x: torch.Tensor, weight: torch.Tensor, n_members: int) -> torch.Tensor:
    return torch.mm(x, weight.t()).view(n_members, -1, weight.shape[0]).max(dim=0).values


def value_and_gradients(fn, x: torch.Tensor, weight: torch.Tensor, seed: int):
    x, weight = x.detach().requires_grad_(True), weight.detach().requires_grad_(True)
    out = fn(x, weight)
    probe = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed), dtype=out.dtype)
    (out * probe).sum().backward()
    return out.detach(), x.grad, weight.grad


@pytest.mark.parametrize(("members", "groups", "c_in", "c_out"), [(1, 5, 3, 4), (7, 11, 6, 9), (64, 3, 16, 32)])
def test_matches_dense_layer_and_max_in_float64(members, groups, c_in, c_out):
    gen = torch.Generator().manual_seed(members + groups)
    x = torch.randn(members * groups, c_in, generator=gen, dtype=torch.float64)
    weight = torch.randn(c_out, c_in, generator=gen, dtype=torch.float64)
    out, grad_x, grad_w = value_and_gradients(lambda a, w: linear_group_max(a, w, members), x, weight, seed=1)
    ref, ref_x, ref_w = value_and_gradients(lambda a, w: dense_group_max(a, w, members), x, weight, seed=1)
    assert out.shape == (groups, c_out)
    torch.testing.assert_close(out, ref, rtol=0, atol=0)
    torch.testing.assert_close(grad_x, ref_x, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(grad_w, ref_w, rtol=1e-12, atol=1e-12)


def test_only_the_winners_receive_gradient():
    x = torch.tensor([[1.0], [3.0], [2.0], [0.0]], dtype=torch.float64, requires_grad=True)  # 2 members, 2 groups
    weight = torch.tensor([[1.0], [-1.0]], dtype=torch.float64, requires_grad=True)
    out = linear_group_max(x, weight, 2)  # group 0: rows 0, 2; group 1: rows 1, 3
    torch.testing.assert_close(out, torch.tensor([[2.0, -1.0], [3.0, 0.0]], dtype=torch.float64))
    out.sum().backward()
    # channel 0 (w = 1) is won by rows 2 and 1, channel 1 (w = -1) by rows 0 and 3
    torch.testing.assert_close(x.grad, torch.tensor([[-1.0], [1.0], [1.0], [-1.0]], dtype=torch.float64))
    torch.testing.assert_close(weight.grad, torch.tensor([[5.0], [1.0]], dtype=torch.float64))


def test_bfloat16_autocast_keeps_float32_gradients():
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(16 * 8, 12, generator=gen)
    weight = torch.randn(24, 12, generator=gen)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out, grad_x, grad_w = value_and_gradients(lambda a, w: linear_group_max(a, w, 16), x, weight, seed=4)
        ref, ref_x, ref_w = value_and_gradients(lambda a, w: dense_group_max(a, w, 16), x, weight, seed=4)
    assert out.dtype == torch.bfloat16 and grad_x.dtype == grad_w.dtype == torch.float32
    torch.testing.assert_close(out, ref)
    torch.testing.assert_close(grad_w, ref_w, rtol=2e-2, atol=2e-2 * float(ref_w.abs().max()))
    torch.testing.assert_close(grad_x, ref_x, rtol=2e-2, atol=2e-2 * float(ref_x.abs().max()))


def test_rejects_rows_that_do_not_split_into_groups():
    with pytest.raises(ValueError, match="10 rows do not split into groups of 3"):
        linear_group_max(torch.zeros(10, 2), torch.zeros(4, 2), 3)
    with pytest.raises(ValueError, match=r"\(C_out, C_in\)"):
        linear_group_max(torch.zeros(10, 2), torch.zeros(4, 3), 5)
