"""Seeded draws come from the generator's device and land on the requested one."""

import pytest
import torch

from pasta.models import random_draws


def test_draws_equal_torchs_own_on_the_cpu():
    for draw, reference in ((random_draws.randn, torch.randn), (random_draws.rand, torch.rand)):
        got = draw((3, 4), torch.Generator().manual_seed(5), dtype=torch.float64)
        assert torch.equal(got, reference((3, 4), generator=torch.Generator().manual_seed(5), dtype=torch.float64))
    ints = random_draws.randint(7, (20,), torch.Generator().manual_seed(1))
    assert torch.equal(ints, torch.randint(7, (20,), generator=torch.Generator().manual_seed(1)))
    weights = torch.tensor([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    assert random_draws.multinomial(weights, 1, torch.Generator().manual_seed(0)).squeeze(1).tolist() == [1, 0]
    assert random_draws.randn((2,), None).shape == (2,)


@pytest.mark.gpu
def test_a_cpu_generator_draws_the_same_numbers_onto_cuda():
    on_cpu = random_draws.randn((5,), torch.Generator().manual_seed(3))
    on_gpu = random_draws.randn((5,), torch.Generator().manual_seed(3), device="cuda")
    assert on_gpu.is_cuda and torch.equal(on_gpu.cpu(), on_cpu)
    weights = torch.tensor([[0.0, 1.0]], device="cuda")
    assert random_draws.multinomial(weights, 1, torch.Generator().manual_seed(0)).is_cuda
