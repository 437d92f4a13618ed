"""The closed-form 3x3 SVD (pasta.sim.svd3.fast_svd) against numpy and Taichi's built-in ti.svd.

Both SVDs run in one small kernel over numpy arrays of matrices (float32 on the CPU); the checks
are in float64 against ``numpy.linalg.svd``. The convention (ti.svd's): F = U sig V^T, U and V
rotations, sig[0] >= sig[1] >= |sig[2]|, sig[2] < 0 exactly when det F < 0.
"""

import numpy as np
import pytest
import taichi as ti

from pasta.sim.runtime import ensure_taichi
from pasta.sim.svd3 import fast_svd
from tests.sim.conftest import BLOCK_HI, BLOCK_LO, PUSHER, PUSHER_HALF, SIM, block_state, simulator, uniform_block

TOL = 1e-5  # relative to the largest singular value
Mats = ti.types.ndarray(dtype=ti.math.mat3, ndim=1)


@ti.kernel
def _both_svds(F: Mats, U: Mats, S: Mats, V: Mats, U_ti: Mats, S_ti: Mats, V_ti: Mats):
    for i in range(F.shape[0]):
        U[i], S[i], V[i] = fast_svd(F[i])
        U_ti[i], S_ti[i], V_ti[i] = ti.svd(F[i], ti.f32)


def decompose(F: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``{"fast": (U, s, V), "taichi": (U, s, V)}`` of the float32 matrices ``F`` (n, 3, 3): U, V (n, 3, 3),
    the diagonal of sig as s (n, 3), all float64."""
    ensure_taichi("cpu")
    F = np.ascontiguousarray(F, np.float32)
    out = [np.zeros_like(F) for _ in range(6)]
    _both_svds(F, *out)
    U, S, V, U_ti, S_ti, V_ti = (a.astype(np.float64) for a in out)
    return {"fast": (U, np.diagonal(S, axis1=1, axis2=2), V),
            "taichi": (U_ti, np.diagonal(S_ti, axis1=1, axis2=2), V_ti)}


def reference_singular_values(F: np.ndarray) -> np.ndarray:
    """numpy's singular values (n, 3) in the convention: descending, the last one carrying det F's sign."""
    s = np.linalg.svd(F, compute_uv=False)
    s[:, 2] *= np.where(np.linalg.det(F) < 0, -1.0, 1.0)
    return s


def assert_valid_svd(F: np.ndarray, U: np.ndarray, s: np.ndarray, V: np.ndarray) -> None:
    """U and V rotations, F = U diag(s) V^T and s the signed singular values, all to TOL."""
    scale = np.maximum(np.linalg.norm(F, 2, axis=(1, 2)), 1e-30)[:, None, None]
    eye = np.eye(3)
    for name, R in (("U", U), ("V", V)):
        assert np.abs(np.swapaxes(R, 1, 2) @ R - eye).max() < TOL, f"{name} is not orthonormal"
        assert np.abs(np.linalg.det(R) - 1.0).max() < TOL, f"{name} is a reflection"
    rebuilt = U @ (s[:, :, None] * np.swapaxes(V, 1, 2))
    assert (np.abs(rebuilt - F) / scale).max() < TOL, "U sig V^T is not F"
    assert (np.abs(s - reference_singular_values(F)) / scale[:, 0]).max() < TOL, "singular values"
    assert (s[:, :2] >= 0).all()
    slack = TOL * scale[:, 0, 0]
    assert (s[:, 0] - s[:, 1] >= -slack).all() and (s[:, 1] - np.abs(s[:, 2]) >= -slack).all()


def assert_agrees_with_taichi(F: np.ndarray, svds: dict) -> None:
    """Same singular values (signs included) as ti.svd and, where it is unique, the same rotation U V^T."""
    (U, s, V), (U_ti, s_ti, V_ti) = svds["fast"], svds["taichi"]
    scale = np.maximum(np.linalg.norm(F, 2, axis=(1, 2)), 1e-30)
    assert (np.abs(s - s_ti).max(axis=1) / scale).max() < TOL
    signed = np.abs(s[:, 2]) > TOL * scale
    np.testing.assert_array_equal(np.sign(s[signed, 2]), np.sign(s_ti[signed, 2]))
    unique = s[:, 1] + s[:, 2] > 0.1 * scale  # U V^T is then well conditioned
    R, R_ti = U @ np.swapaxes(V, 1, 2), U_ti @ np.swapaxes(V_ti, 1, 2)
    assert np.abs(R - R_ti)[unique].max() < 1e-4


def rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` random proper rotations (n, 3, 3)."""
    q, _ = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    q[np.linalg.det(q) < 0, :, 0] *= -1
    return q


def with_singular_values(rng: np.random.Generator, s: np.ndarray) -> np.ndarray:
    """R1 diag(s) R2^T for random rotations R1, R2, one matrix per row of ``s`` (n, 3)."""
    n = len(s)
    return rotations(rng, n) @ (s[:, :, None] * np.swapaxes(rotations(rng, n), 1, 2))


def float32(F: np.ndarray) -> np.ndarray:
    """``F`` rounded to float32 and back, the matrix both SVDs actually see."""
    return np.asarray(F, np.float32).astype(np.float64)


def test_near_identity_matches_numpy_and_ti_svd():
    F = float32(np.eye(3) + 0.3 * np.random.default_rng(0).standard_normal((10_000, 3, 3)))
    svds = decompose(F)
    assert_valid_svd(F, *svds["fast"])
    assert_agrees_with_taichi(F, svds)


def test_wide_range_of_scales_matches_numpy():
    """Overall scales 1e-3..1e3 and singular values spread over six decades (where ti.svd, with absolute
    thresholds, loses the small ones)."""
    rng = np.random.default_rng(1)
    n = 5000
    overall = 10.0 ** rng.uniform(-3, 3, (n, 1, 1))
    columns = (np.eye(3) + 0.3 * rng.standard_normal((n, 3, 3))) * 10.0 ** rng.uniform(-2, 2, (n, 1, 3))
    spread = with_singular_values(rng, 10.0 ** rng.uniform(-6, 0, (n, 3)))
    F = float32(np.concatenate([overall * columns, overall * spread]))
    assert_valid_svd(F, *decompose(F)["fast"])


def degenerate_matrices(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """Repeated, nearly repeated and zero singular values, reflections and near-rotations, each as is
    (axis-aligned) and between random rotations."""
    diagonals = [
        (1, 1, 1), (2, 2, 2), (2, 1, 1), (1, 1, 2), (2, 2, 1), (1, 2, 2), (3, 1, 0), (1, 0, 0), (0, 0, 0),
        (1, 1, -1), (2, 1, -1), (1, 2, -2), (1, 1 + 1e-6, 1 - 1e-6), (2, 1 + 1e-6, 1), (1, 1, 1 + 1e-6),
        (1 + 1e-6, 1, -1),
    ]
    blocks = []
    for d in diagonals:
        s = np.broadcast_to(np.asarray(d, np.float64), (n, 3))
        blocks += [np.diag(d)[None], with_singular_values(rng, s)]
    blocks.append(rotations(rng, n) + 1e-6 * rng.standard_normal((n, 3, 3)))  # very close to a rotation
    blocks.append(-rotations(rng, n))  # a rotation times -1: det -1, all singular values 1
    zero_column = np.eye(3) + 0.3 * rng.standard_normal((n, 3, 3))
    zero_column[:, :, 1] = 0.0
    blocks.append(zero_column)
    rank_one = rng.standard_normal((n, 3, 1)) * rng.standard_normal((n, 1, 3))
    blocks.append(rank_one)
    return float32(np.concatenate(blocks))


def test_near_degenerate_matrices_match_numpy_and_ti_svd():
    F = degenerate_matrices(np.random.default_rng(2))
    svds = decompose(F)
    assert_valid_svd(F, *svds["fast"])
    assert_agrees_with_taichi(F, svds)


def test_identity_and_diagonal_matrices_give_identity_rotations():
    F = float32([np.eye(3), np.diag([3.0, 2.0, 1.0]), np.diag([2.0, 2.0, 2.0])])
    U, s, V = decompose(F)["fast"]
    np.testing.assert_allclose(U, np.broadcast_to(np.eye(3), U.shape), atol=1e-7)
    np.testing.assert_allclose(V, np.broadcast_to(np.eye(3), V.shape), atol=1e-7)
    np.testing.assert_allclose(s, [[1, 1, 1], [3, 2, 1], [2, 2, 2]], rtol=1e-6)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_entry_gives_a_non_finite_result(bad):
    """The simulator's health check must still see a broken F after the SVD."""
    F = np.broadcast_to(np.eye(3), (9, 3, 3)).copy()
    F[np.arange(9), np.arange(9) // 3, np.arange(9) % 3] = bad
    U, s, V = decompose(F)["fast"]
    assert not np.isfinite(U @ (s[:, :, None] * np.swapaxes(V, 1, 2))).all(axis=(1, 2)).any()


def test_simulation_with_the_fast_svd_follows_the_builtin():
    """Eight steps (80 substeps) of a box pressing a block into plastic flow: the same particle positions."""
    x0 = uniform_block(np.random.default_rng(4), BLOCK_LO, BLOCK_HI)
    tool = (0.5, BLOCK_HI[1] + PUSHER_HALF[1] + 0.005, 0.5)
    down = np.array([0.0, -1.0, 0.0, 0.0, 0.0, 0.0], np.float32)
    finals = {}
    for method in ("taichi", "fast"):
        sim = simulator(PUSHER, SIM.model_copy(update={"svd": method}))
        sim.set_state(block_state(x0, tool))
        for t in range(8):
            sim.step(down, step=t)
        finals[method] = sim.get_state()
    assert np.abs(finals["taichi"]["x"] - x0).max() > 0.02  # the press moved the dough
    # Measured: 2.5e-6 in x and 2.5e-5 in F (float32 round-off, grown over 80 substeps).
    assert np.abs(finals["fast"]["x"] - finals["taichi"]["x"]).max() < 2e-5
    np.testing.assert_allclose(finals["fast"]["F"], finals["taichi"]["F"], atol=2e-4)


def test_families_a_pressed_dough_may_reach_match_numpy():
    """Families a simulation may produce that the tests above sample thinly: two singular values equal to
    1e-9..1e-3 and the third anywhere below, three nearly equal, two nearly zero, axis-aligned diagonals with
    sparse perturbations down to 1e-9, and trial matrices (I + dt C) F with |dt C| up to 30. (Measured with
    400 000 matrices per family: no non-finite result, reconstruction within 8e-7.)"""
    rng = np.random.default_rng(5)
    n = 20_000
    a = np.exp(rng.uniform(-3, 1, (n, 1)))
    pair = np.concatenate([a, a * (1 + 10.0 ** rng.uniform(-9, -3, (n, 1))), np.exp(rng.uniform(-7, 1, (n, 1)))], 1)
    triple = a * (1 + 10.0 ** rng.uniform(-9, -2, (n, 3)) * rng.standard_normal((n, 3)))
    needle = np.concatenate([a, 10.0 ** rng.uniform(-8, -2, (n, 2))], 1)
    diagonal = np.zeros((n, 3, 3))
    diagonal[:, [0, 1, 2], [0, 1, 2]] = rng.choice([0.01, 0.1, 0.5, 1.0, 1.5], (n, 3))
    diagonal += 10.0 ** rng.uniform(-9, -1, (n, 1, 1)) * rng.standard_normal((n, 3, 3)) * (rng.random((n, 3, 3)) < 0.3)
    dt_C = 10.0 ** rng.uniform(-2, 1.5, (n, 1, 1)) * rng.standard_normal((n, 3, 3))
    trial = (np.eye(3) + dt_C) @ with_singular_values(rng, np.exp(rng.uniform(np.log(0.05), np.log(2), (n, 3))))
    F = float32(np.concatenate([with_singular_values(rng, pair), with_singular_values(rng, triple),
                                with_singular_values(rng, needle), diagonal, trial]))
    assert_valid_svd(F, *decompose(F)["fast"])
