"""Chamfer, exact EMD, Sinkhorn and the normalised performance, against slow references."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from pasta.geometry import (
    chamfer_distance,
    earth_movers_distance,
    is_success,
    normalised_performance,
    sinkhorn_emd,
)


def chamfer_reference(a: np.ndarray, b: np.ndarray) -> float:
    """Double loop: mean squared nearest-neighbour distance a->b plus b->a."""

    def one_way(x, y):
        total = 0.0
        for p in x:
            best = np.inf
            for q in y:
                best = min(best, float(((p - q) ** 2).sum()))
            total += best
        return total / len(x)

    return one_way(a, b) + one_way(b, a)


@pytest.mark.parametrize(("batch", "n", "m"), [(1, 1, 1), (3, 5, 7), (6, 16, 9), (2, 12, 1)])
def test_chamfer_matches_double_loop(batch, n, m):
    rng = np.random.default_rng(n * 100 + m)
    a = rng.normal(size=(batch, n, 3))
    b = rng.normal(size=(batch, m, 3))
    got = chamfer_distance(torch.from_numpy(a), torch.from_numpy(b))
    expected = np.array([chamfer_reference(a[i], b[i]) for i in range(batch)])
    assert got.shape == (batch,)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-10, atol=1e-12)
    got32 = chamfer_distance(torch.from_numpy(a).float(), torch.from_numpy(b).float())
    np.testing.assert_allclose(got32.numpy(), expected, rtol=1e-5, atol=1e-5)


def test_chamfer_unbatched_broadcast_and_chunking_agree():
    rng = np.random.default_rng(1)
    a = torch.from_numpy(rng.random((9, 20, 3)))
    b = torch.from_numpy(rng.random((9, 15, 3)))
    full = chamfer_distance(a, b)
    for chunk in (1, 2, 4, 100):
        torch.testing.assert_close(chamfer_distance(a, b, chunk_size=chunk), full)
    scalar = chamfer_distance(a[3], b[3])
    assert scalar.ndim == 0
    torch.testing.assert_close(scalar, full[3])
    assert float(scalar) == pytest.approx(chamfer_reference(a[3].numpy(), b[3].numpy()), rel=1e-10)
    broadcast = chamfer_distance(a[:1], b)  # a batch of 1 broadcasts
    torch.testing.assert_close(broadcast[5], chamfer_distance(a[0], b[5]))
    # symmetric, zero on itself, and the translation of a cloud with well-separated points costs 2|d|^2
    torch.testing.assert_close(chamfer_distance(b, a), full)
    assert float(chamfer_distance(a[0], a[0])) == pytest.approx(0.0, abs=1e-12)
    grid = torch.from_numpy(np.stack(np.meshgrid(*[np.arange(3) * 0.1] * 3), -1).reshape(-1, 3))
    shift = torch.tensor([0.003, -0.004, 0.0], dtype=torch.float64)
    assert float(chamfer_distance(grid, grid + shift)) == pytest.approx(2 * 0.005**2, rel=1e-9)


def test_chamfer_rejects_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        chamfer_distance(torch.zeros(5, 2), torch.zeros(5, 3))
    with pytest.raises(ValueError, match="batch sizes"):
        chamfer_distance(torch.zeros(2, 5, 3), torch.zeros(3, 5, 3))
    with pytest.raises(ValueError, match="empty"):
        chamfer_distance(torch.zeros(0, 3), torch.zeros(5, 3))


def test_chamfer_gradcheck_float64():
    rng = np.random.default_rng(2)
    a = torch.from_numpy(rng.random((2, 4, 3))).requires_grad_(True)
    b = torch.from_numpy(rng.random((2, 5, 3))).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, y: chamfer_distance(x, y), (a, b), eps=1e-6, atol=1e-6)


def test_chamfer_gradient_path_matches_the_dense_minimum():
    # With a gradient the distance is taken on nearest-neighbour pairs; without, from the distance blocks.
    rng = np.random.default_rng(4)
    a = torch.from_numpy(rng.random((3, 30, 3))).requires_grad_(True)
    b = torch.from_numpy(rng.random((3, 25, 3))).requires_grad_(True)
    probe = torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64)
    (chamfer_distance(a, b) * probe).sum().backward()
    grads = a.grad.clone(), b.grad.clone()
    a.grad, b.grad = None, None
    sq = torch.cdist(a, b).square()
    dense = sq.min(dim=2).values.mean(dim=1) + sq.min(dim=1).values.mean(dim=1)
    (dense * probe).sum().backward()
    torch.testing.assert_close(grads[0], a.grad, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(grads[1], b.grad, rtol=1e-10, atol=1e-12)
    with torch.no_grad():
        torch.testing.assert_close(chamfer_distance(a, b), dense.detach(), rtol=1e-10, atol=1e-12)


def test_chamfer_gradient_finite_float32_including_identical_clouds():
    rng = np.random.default_rng(3)
    a = torch.from_numpy(rng.random((2, 100, 3)).astype(np.float32)).requires_grad_(True)
    b = torch.from_numpy(rng.random((2, 80, 3)).astype(np.float32)).requires_grad_(True)
    (chamfer_distance(a, b).sum() + chamfer_distance(a, a.detach().clone()).sum()).backward()
    assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all()
    assert a.grad.abs().sum() > 0 and b.grad.abs().sum() > 0


def emd_brute_force(a: np.ndarray, b: np.ndarray) -> float:
    cost = np.linalg.norm(a[:, None] - b[None], axis=-1)
    n = len(a)
    return min(cost[np.arange(n), list(perm)].mean() for perm in itertools.permutations(range(n)))


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6])
def test_emd_matches_permutation_search(n):
    rng = np.random.default_rng(10 + n)
    for _ in range(3):
        a, b = rng.random((n, 3)), rng.random((n, 3))
        assert earth_movers_distance(a, b) == pytest.approx(emd_brute_force(a, b), rel=1e-12, abs=1e-15)


def test_emd_of_translate_is_shift_length():
    rng = np.random.default_rng(4)
    a = rng.random((200, 3))
    d = np.array([0.03, -0.12, 0.05])
    assert earth_movers_distance(a, a + d) == pytest.approx(np.linalg.norm(d), rel=1e-12)
    assert earth_movers_distance(torch.from_numpy(a), a) == pytest.approx(0.0, abs=1e-15)
    # max_points takes one shared index set from both clouds, so the translate property survives
    big = rng.random((80, 3))
    assert earth_movers_distance(big, big + d, max_points=20, rng=5) == pytest.approx(np.linalg.norm(d))


def test_emd_subsamples_the_larger_cloud_with_the_given_generator():
    rng = np.random.default_rng(6)
    a, b = rng.random((30, 3)), rng.random((20, 3))
    idx = np.random.default_rng(7).choice(30, 20, replace=False)
    expected = earth_movers_distance(a[idx], b)
    assert earth_movers_distance(a, b, rng=np.random.default_rng(7)) == pytest.approx(expected, rel=1e-12)
    assert earth_movers_distance(a, b, rng=7) == earth_movers_distance(a, b, rng=7)
    assert earth_movers_distance(b, a, rng=7) == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match="shape"):
        earth_movers_distance(a[:, :2], b)


@pytest.mark.parametrize("n", [16, 40])
def test_sinkhorn_close_to_exact_emd(n):
    rng = np.random.default_rng(8)
    a, b = rng.random((n, 3)), rng.random((n, 3)) * 0.5 + 0.3
    exact = earth_movers_distance(a, b)
    approx = float(sinkhorn_emd(torch.from_numpy(a), torch.from_numpy(b)))
    # geomloss' eps-scaling (scaling 0.5) stops a few percent short of W1 at blur 1e-3
    assert approx == pytest.approx(exact, rel=0.1)
    assert approx <= exact + 1e-3


def test_sinkhorn_batched_and_differentiable():
    rng = np.random.default_rng(9)
    a = torch.from_numpy(rng.random((3, 24, 3)).astype(np.float32)).requires_grad_(True)
    b = torch.from_numpy(rng.random((3, 24, 3)).astype(np.float32))
    out = sinkhorn_emd(a, b, blur=0.05)
    assert out.shape == (3,)
    torch.testing.assert_close(out[1], sinkhorn_emd(a[1], b[1], blur=0.05), rtol=1e-4, atol=1e-5)
    out.sum().backward()
    assert torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0


def test_normalised_performance_and_success():
    assert normalised_performance(0.2, 0.05) == pytest.approx(0.75)
    assert normalised_performance(0.2, 0.2) == 0.0
    assert normalised_performance(0.1, 0.3) == pytest.approx(-2.0)  # worse than the start is negative
    assert normalised_performance(0.0, 0.0) == 1.0
    assert normalised_performance(0.0, 0.4) == 1.0
    np.testing.assert_allclose(normalised_performance(np.array([0.2, 0.0]), np.array([0.1, 0.1])), [0.5, 1.0])
    with pytest.raises(ValueError):
        normalised_performance(-0.1, 0.0)
    assert is_success(0.81, 0.8) is True
    assert is_success(0.8, 0.8) is False  # strictly greater
    np.testing.assert_array_equal(is_success(np.array([0.9, 0.88, 0.5]), 0.88), [True, False, False])
