"""Adjoint gradients of the simulator against central finite differences.

One tiny layout (grid 16, 300 particles, one box tool) keeps compile and run
times to seconds. Positions are float32 inside the simulator, so the finite
differences use steps large enough to rise above round-off and episodes short
enough that no contact switches on or off inside the step.
"""

import numpy as np
import pytest
import torch

from pasta.config.schema import MaterialConfig, SimConfig, ToolConfig
from pasta.sim.autodiff import backpropagate_episode, differentiable_episode, simulate_episode
from pasta.sim.engine import GRID_CHANNELS, RECORD_CHANNELS, simulator_for

N_PARTICLES = 300
SIM = SimConfig(n_grid=16, dt_s=4e-4, substeps_per_step=5, n_particles=N_PARTICLES, gravity_m_s2=(0, -600, 0),
                contact_softness=666.0, observation_points=100)
MATERIAL = MaterialConfig(youngs_modulus_pa=5e3, poisson_ratio=0.15, yield_stress_pa=150.0, ground_friction=0.5)
PUSHER = ToolConfig(name="pusher", kind="box", position=(0.5, 0.3, 0.5), half_extents=(0.05, 0.03, 0.05),
                    action_scales=(0.02, 0.02, 0.02, 0.05, 0.05, 0.05), friction=1.0)


def differentiable_simulator(svd: str = "taichi"):
    simulator = simulator_for(SIM.model_copy(update={"svd": svd}), [PUSHER], differentiable=True)
    simulator.set_material(MATERIAL)
    return simulator


@pytest.fixture(scope="module")
def sim():
    return differentiable_simulator()


def make_problem(seed: int):
    """A block under a tool that touches its top, random actions and a random linear loss."""
    rng = np.random.default_rng(seed)
    x = rng.uniform([0.4, 0.15, 0.4], [0.6, 0.25, 0.6], (N_PARTICLES, 3)).astype(np.float32)
    state0 = {
        "x": x,
        "v": rng.normal(0.0, 0.3, (N_PARTICLES, 3)).astype(np.float32),
        "tool_pos": np.array([[0.5, 0.27, 0.5]], np.float32),
        "tool_rot": np.array([[1.0, 0.0, 0.0, 0.0]], np.float32),
        "tool_gap": np.zeros(1, np.float32),
    }
    actions = rng.uniform(-0.5, 0.5, (2, 6))
    actions[:, 1] = -0.8
    weights_x = torch.tensor(rng.normal(0.0, 1.0, (N_PARTICLES, 3)))
    weights_v = torch.tensor(rng.normal(0.0, 0.01, (N_PARTICLES, 3)))
    return state0, torch.tensor(actions), weights_x, weights_v


def episode_loss(sim, state0, x0, actions, weights_x, weights_v):
    xs, vs, _ = differentiable_episode(sim, state0, x0, actions)
    return (xs[-1] * weights_x).sum() + (vs[-1] * weights_v).sum()


def relative_error(a: float, b: float) -> float:
    return abs(a - b) / max(abs(a), abs(b), 1e-12)


def check_action_gradient(sim, seed: int) -> None:
    """One action entry's adjoint gradient of a random linear loss against central differences."""
    state0, actions, wx, wv = make_problem(seed)
    x0 = torch.tensor(state0["x"], dtype=torch.float64)
    actions.requires_grad_(True)
    episode_loss(sim, state0, x0, actions, wx, wv).backward()
    step, dim, h = seed % 2, 2 * (seed % 2), 1e-2
    plus, minus = actions.detach().clone(), actions.detach().clone()
    plus[step, dim] += h
    minus[step, dim] -= h
    fd = (episode_loss(sim, state0, x0, plus, wx, wv) - episode_loss(sim, state0, x0, minus, wx, wv)).item() / (2 * h)
    ad = actions.grad[step, dim].item()
    assert abs(fd) > 1e-4, "the loss must depend on the action for the check to mean anything"
    assert relative_error(ad, fd) < 0.05, f"seed {seed}: autodiff {ad} vs finite differences {fd}"


def check_initial_position_gradient(sim, seed: int) -> None:
    """One initial position entry's adjoint gradient of a random linear loss against central differences."""
    state0, actions, wx, wv = make_problem(seed)
    x0 = torch.tensor(state0["x"], dtype=torch.float64, requires_grad=True)
    episode_loss(sim, state0, x0, actions, wx, wv).backward()
    particle, dim, h = 7 * seed + 3, seed % 3, 1e-3
    plus, minus = x0.detach().clone(), x0.detach().clone()
    plus[particle, dim] += h
    minus[particle, dim] -= h
    fd = (episode_loss(sim, state0, plus, actions, wx, wv) - episode_loss(sim, state0, minus, actions, wx, wv)).item()
    fd /= 2 * h
    ad = x0.grad[particle, dim].item()
    assert relative_error(ad, fd) < 0.05, f"seed {seed}: autodiff {ad} vs finite differences {fd}"


@pytest.mark.parametrize("seed", range(5))
def test_action_gradient_matches_finite_differences(sim, seed):
    check_action_gradient(sim, seed)


@pytest.mark.parametrize("seed", range(5))
def test_initial_position_gradient_matches_finite_differences(sim, seed):
    check_initial_position_gradient(sim, seed)


def test_gradients_with_the_fast_svd_match_finite_differences():
    """The adjoint of the SVD (svd_grad) holds for the closed-form SVD too (SimConfig.svd = "fast")."""
    sim = differentiable_simulator("fast")
    for seed in (0, 1):
        check_action_gradient(sim, seed)
        check_initial_position_gradient(sim, seed)


def test_gradient_through_long_episode_is_finite_and_memory_bounded(sim):
    """50 steps x all substeps with no memory for kept steps: the backward pass recomputes each step into
    the same substep frames."""
    sim.adjoint_memory_bytes = 0
    state0, _, wx, _ = make_problem(0)
    actions = torch.zeros(50, 6)
    actions[:, 1] = -0.2
    actions.requires_grad_(True)
    x0 = torch.tensor(state0["x"], dtype=torch.float64, requires_grad=True)
    xs, vs, tool_pos = differentiable_episode(sim, state0, x0, actions)
    assert xs.shape == (51, N_PARTICLES, 3) and tool_pos.shape == (51, 1, 3)
    (xs[-1] * wx).sum().backward()
    assert torch.isfinite(actions.grad).all() and torch.isfinite(x0.grad).all()
    assert actions.grad[:, 1].abs().sum() > 0
    assert sim.n_frames == SIM.substeps_per_step + 1
    sim.adjoint_memory_bytes = int(SIM.adjoint_memory_mb * 2**20)


def gradients(sim, seed: int, memory_bytes: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Adjoints of the actions and of x0 for ``make_problem(seed)`` (3 steps), and how many steps were kept."""
    sim.adjoint_memory_bytes = memory_bytes
    try:
        state0, actions, wx, wv = make_problem(seed)
        actions = torch.cat([actions, actions[:1]]).requires_grad_(True)
        x0 = torch.tensor(state0["x"], dtype=torch.float64, requires_grad=True)
        episode_loss(sim, state0, x0, actions, wx, wv).backward()
        kept = sum(r is not None for r in simulate_episode(sim, state0, actions.detach().numpy()).recorded)
    finally:
        sim.adjoint_memory_bytes = int(SIM.adjoint_memory_mb * 2**20)
    return actions.grad.numpy(), x0.grad.numpy(), kept


def test_kept_substeps_give_the_gradients_of_recomputed_ones(sim):
    """Restoring a step's recorded substep frames gives the adjoints of recomputing them: those of x0 bit
    for bit, those of the actions up to the float atomics of the grid update's adjoint (equal in practice)."""
    # A kept step's particles; its grids add less.
    particles = 4 * (SIM.substeps_per_step + 1) * N_PARTICLES * RECORD_CHANNELS
    recomputed_a, recomputed_x, none_kept = gradients(sim, 2, 0)
    for memory, expected_kept in ((3 * particles // 2, 1), (5 * particles // 2, 2), (1 << 30, 3)):
        kept_a, kept_x, kept = gradients(sim, 2, memory)
        assert (none_kept, kept) == (0, expected_kept)
        np.testing.assert_array_equal(kept_x, recomputed_x)
        np.testing.assert_allclose(kept_a, recomputed_a, rtol=1e-5, atol=1e-6 * np.abs(recomputed_a).max())


def test_every_recorded_grid_holds_the_whole_mass(sim):
    """P2G puts exactly n * p_vol * density on the grid in every substep of a pressing episode: the grids
    that record_step keeps for the adjoint pass (mass first of GRID_CHANNELS per node of the box)."""
    density = 1.7
    sim.set_material(MATERIAL.model_copy(update={"density": density}))
    try:
        state0, actions, _, _ = make_problem(0)
        sim.set_state(state0)
        expected = N_PARTICLES * sim.p_vol * density
        for step, action in enumerate(actions.numpy()):
            recorded = sim.record_step(action, step=step)
            sizes = recorded["grid_boxes"][:, 1] - recorded["grid_boxes"][:, 0] + 1
            for f, size in enumerate(sizes):
                mass = recorded["grid"][f, : GRID_CHANNELS * int(np.prod(size))][::GRID_CHANNELS].astype(np.float64)
                assert mass.min() >= 0.0
                assert mass.sum() == pytest.approx(expected, rel=1e-5), f"step {step}, substep {f}"
            sim.release_recorded_step(recorded)
            sim.copy_frame(sim.substeps, 0)
    finally:
        sim.set_material(MATERIAL)


def test_simulate_episode_keeps_one_checkpoint_per_step(sim):
    state0, actions, _, _ = make_problem(1)
    episode = simulate_episode(sim, state0, actions.numpy())
    assert len(episode.checkpoints) == len(actions) + 1
    np.testing.assert_array_equal(episode.checkpoints[0]["x"], state0["x"])
    np.testing.assert_array_equal(episode.x[-1], episode.checkpoints[-1]["x"])


def test_a_second_backward_pass_recomputes_the_steps_the_first_released(sim):
    """The first backward pass gives the kept steps' buffers back for reuse; a second one over the same
    episode recomputes those steps from their checkpoints and gets the same adjoints."""
    state0, actions, _, _ = make_problem(3)
    episode = simulate_episode(sim, state0, actions.numpy())
    assert all(r is not None for r in episode.recorded)
    seed = {"x": np.ones_like(episode.x)}
    first_actions, first_state = backpropagate_episode(sim, episode, seed)
    assert all(r is None for r in episode.recorded)
    second_actions, second_state = backpropagate_episode(sim, episode, seed)
    np.testing.assert_array_equal(first_state["x"], second_state["x"])
    np.testing.assert_allclose(first_actions, second_actions, rtol=1e-6)


def test_parallel_p2g_matches_the_serial_scatter():
    """The atomic (GPU) scatter differs from the serial one only by float summation order."""
    finals = {}
    for mode in ("serial", "parallel"):
        simulator = simulator_for(SIM.model_copy(update={"p2g": mode}), [PUSHER])
        simulator.set_material(MATERIAL)
        assert simulator.serial_p2g == (mode == "serial")
        state0, actions, _, _ = make_problem(0)
        simulator.set_state(state0)
        for t, action in enumerate(actions.numpy()):
            simulator.step(action.astype(np.float32), step=t)
        finals[mode] = simulator.get_state()["x"]
    assert np.abs(finals["parallel"] - finals["serial"]).max() < 1e-4
    assert np.abs(finals["serial"] - make_problem(0)[0]["x"]).max() > 1e-3  # the episode moved the dough
