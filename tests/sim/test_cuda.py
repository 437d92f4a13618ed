"""The simulator on CUDA gives the CPU's loss and gradients (each architecture in its own process)."""

import subprocess
import sys

import numpy as np
import pytest


def _episode(arch: str, folder) -> dict:
    out = folder / f"{arch}.npz"
    subprocess.run([sys.executable, "-m", "tests.sim.arch_episode", arch, str(out)], check=True)
    return dict(np.load(out))


@pytest.mark.gpu
def test_cuda_episode_matches_the_cpu_one(tmp_path):
    cpu, cuda = _episode("cpu", tmp_path), _episode("cuda", tmp_path)
    assert float(cuda["loss"]) == pytest.approx(float(cpu["loss"]), rel=1e-3)
    np.testing.assert_allclose(cuda["action_grad"], cpu["action_grad"], rtol=0.02, atol=1e-3)
    np.testing.assert_allclose(cuda["x0_grad"], cpu["x0_grad"], rtol=0.02, atol=1e-3)
