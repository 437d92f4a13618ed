"""Physics of the MLS-MPM dough simulator (env_spec.md section 1), checked on small scenes.

All tests share the layouts of ``conftest.py`` (grid 32, 2000 particles, dt 2e-4, 10
substeps per env step): dx = 1/32 = 0.03125 and one env step is 2 ms of simulated time.
Bounds are stated in grid cells (dx) where they concern positions.
"""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from pasta.sim.engine import ActionError, SimulationError
from tests.sim.conftest import (
    BLOCK_HI,
    BLOCK_LO,
    CUT_SIM,
    DX,
    KNIFE,
    PUSHER_HALF,
    SIM,
    STEP_S,
    N,
    block_state,
    material,
    park_tool,
    run_steps,
    simulator,
    uniform_block,
    with_tool,
)

UP = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0], np.float32)
DOWN = -UP
RIGHT = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0], np.float32)
STAY = np.zeros(6, np.float32)
CENTRE_X = 0.5 * (BLOCK_LO[0] + BLOCK_HI[0])
CENTRE_Z = 0.5 * (BLOCK_LO[2] + BLOCK_HI[2])


def block_top(state) -> float:
    return float(np.max(state["x"][:, 1]))


def pusher_above(state, clearance: float = 0.005) -> tuple[float, float, float]:
    """Pusher centre over the block's centre, its bottom face ``clearance`` above the dough."""
    return (CENTRE_X, block_top(state) + PUSHER_HALF[1] + clearance, CENTRE_Z)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def box_sdf(points: np.ndarray, centre, rotation, half) -> np.ndarray:
    """Signed distance (negative inside) of world ``points`` (n, 3) to a posed box."""
    local = (np.asarray(points, np.float64) - np.asarray(centre, np.float64)) @ quat_to_matrix(rotation)
    q = np.abs(local) - np.asarray(half, np.float64)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def big_clusters(points: np.ndarray) -> list[int]:
    """Sizes of the DBSCAN(eps 0.03, min_samples 6) clusters of more than 10 points, largest first."""
    labels = DBSCAN(eps=0.03, min_samples=6).fit_predict(points)
    sizes = np.bincount(labels[labels >= 0]) if (labels >= 0).any() else np.zeros(0, int)
    return sorted((int(s) for s in sizes if s > 10), reverse=True)


# --------------------------------------------------------------------------- free fall


def test_free_fall_follows_parabola(pusher_sim):
    """Without contact, the mean height follows y0 - g t^2 / 2 and the block does not deform."""
    g, n_steps = 300.0, 20
    sim = pusher_sim
    sim.set_gravity((0.0, -g, 0.0))
    sim.set_material(material(yield_stress_pa=1e6))
    x0 = uniform_block(np.random.default_rng(1), (0.425, 0.65, 0.425), (0.575, 0.75, 0.575))
    sim.set_state(block_state(x0))  # tool parked at y 0.9, above the block's top at 0.75
    y0 = x0[:, 1].astype(np.float64).mean()
    drop = 0.5 * g * (n_steps * STEP_S) ** 2  # 0.24: the block's bottom ends near 0.41
    for step in range(1, n_steps + 1):
        sim.step(STAY, step=step)
        p = sim.read_particles(0)
        t = step * STEP_S
        y = p["x"][:, 1].astype(np.float64).mean()
        assert abs(y - (y0 - 0.5 * g * t * t)) <= 0.02 * drop, f"step {step}: mean y {y:.6f}"
        # Symplectic Euler on the grid: after k substeps v = -g k dt and the drop is g dt^2 k (k + 1) / 2.
        k = step * SIM.substeps_per_step
        assert y == pytest.approx(y0 - 0.5 * g * SIM.dt_s**2 * k * (k + 1), abs=1e-5)
        assert p["v"][:, 1].astype(np.float64).mean() == pytest.approx(-g * SIM.dt_s * k, rel=1e-5)
        v_expected = np.broadcast_to([0.0, -g * SIM.dt_s * k, 0.0], p["v"].shape)
        np.testing.assert_allclose(p["v"], v_expected, atol=1e-3)  # float32 noise rings the block a little
    # Rigid translation: x and z untouched, no stretch in y, F still the identity.
    np.testing.assert_allclose(p["x"][:, [0, 2]], x0[:, [0, 2]], atol=1e-5)
    np.testing.assert_allclose(p["x"][:, 1] - p["x"][:, 1].mean(), x0[:, 1] - x0[:, 1].mean(), atol=1e-5)
    np.testing.assert_allclose(p["F"], np.broadcast_to(np.eye(3), p["F"].shape), atol=1e-4)
    assert p["x"][:, 1].min() > 0.3, "the block landed: the test no longer measures free fall"


# ------------------------------------------------------------------------ resting state


def test_block_rests_on_floor_band(resting_block):
    """A settled block sits on the 3-cell floor band (bottom about boundary_cells * dx) and is at rest."""
    x, v = resting_block["x"], resting_block["v"]
    bottom = float(x[:, 1].min())
    assert 2.5 * DX < bottom < 3.2 * DX, f"bottom {bottom / DX:.2f} dx"
    assert np.linalg.norm(v, axis=1).mean() < 0.1
    # The footprint barely spreads under gravity alone.
    assert x[:, 0].min() > BLOCK_LO[0] - DX and x[:, 0].max() < BLOCK_HI[0] + DX


# ---------------------------------------------------------------------- robustness


def test_full_press_for_1000_substeps_loses_nothing(pusher_sim, resting_block):
    """100 env steps of pressing down at full action: every particle stays finite and in the box."""
    sim = pusher_sim
    sim.set_state(with_tool(resting_block, pusher_above(resting_block)))
    for step in range(100):
        sim.step(DOWN, step=step)
        p = sim.read_particles(0)
        assert p["x"].shape == (N, 3)
        for key in ("x", "v", "C", "F"):
            assert np.isfinite(p[key]).all(), f"non-finite {key} at step {step}"
        assert (p["x"] >= 0.0).all() and (p["x"] <= 1.0).all(), f"particle left the unit cube at step {step}"
    # Inside the particle clamp, not merely inside the cube.
    assert p["x"].min() >= DX * (1 - 1e-6) and p["x"].max() <= (1 - 3 * DX) * (1 + 1e-6)
    assert sim.read_tools(0)["pos"][0, 1] == pytest.approx(0.0, abs=1e-6)  # pressed down to its lower bound


# ---------------------------------------------------------------------- constitutive


def _press_release_dent(sim, start, yield_stress: float) -> float:
    """Press 5 cm into the block, lift the tool off, settle; return the lasting dent under the tool.

    The surface height is the 90th percentile of y over the particles in a 0.06 x 0.06 column
    under the tool, averaged over the last 10 of 40 settling steps (the elastic block still rings).
    """

    def surface(x):
        column = (np.abs(x[:, 0] - CENTRE_X) < 0.03) & (np.abs(x[:, 2] - CENTRE_Z) < 0.03)
        return float(np.percentile(x[column, 1], 90))

    sim.set_material(material(yield_stress_pa=yield_stress))
    sim.set_state(with_tool(start, pusher_above(start)))
    before = surface(start["x"])
    step = run_steps(sim, DOWN, 6)  # tool bottom from 0.005 above the top to 0.055 below it
    step = run_steps(sim, UP, 10, step)  # 0.045 clear of the original top
    step = run_steps(sim, STAY, 30, step)
    heights = []
    for _ in range(10):
        step = run_steps(sim, STAY, 1, step)
        heights.append(surface(sim.read_particles(0)["x"]))
    return before - float(np.mean(heights))


def test_press_leaves_dent_only_when_plastic(pusher_sim, resting_block):
    """Yield stress 150 keeps a dent of more than half a cell; 1e6 springs back to within 0.2 cell."""
    plastic = _press_release_dent(pusher_sim, resting_block, 150.0)
    elastic = _press_release_dent(pusher_sim, resting_block, 1e6)
    assert plastic > 0.5 * DX, f"plastic dent {plastic / DX:.2f} dx"
    assert abs(elastic) < 0.2 * DX, f"elastic dent {elastic / DX:.2f} dx"


# --------------------------------------------------------------------------- friction


def test_ground_friction_resists_sliding(pusher_sim, resting_block):
    """Dragging the pusher along x through the block moves it further on a frictionless floor."""
    sim = pusher_sim
    start = with_tool(resting_block, (BLOCK_LO[0] - PUSHER_HALF[0] - 0.005, 0.13, CENTRE_Z))
    shift = {}
    for mu in (0.0, 1.5):
        sim.set_material(material(ground_friction=mu))
        sim.set_state(start)
        run_steps(sim, RIGHT, 15)  # the tool travels 0.15 along +x
        shift[mu] = float(sim.read_particles(0)["x"][:, 0].mean() - start["x"][:, 0].mean())
    assert shift[1.5] > 0.02, "the tool did not push the block"
    assert shift[0.0] > shift[1.5] + 0.02, f"centre-of-mass shifts: {shift}"


# ---------------------------------------------------------------------------- contact


def test_pressing_tool_keeps_dough_within_one_cell(pusher_sim, resting_block):
    """While the pusher presses into the block, no particle is ever more than dx inside it.

    Grid-node contact lets particles sink up to about a cell into a tool; this checks every
    substep of a press halfway into the 0.1-tall block (default dough, yield stress 150).
    """
    sim = pusher_sim
    sim.set_state(with_tool(resting_block, pusher_above(resting_block)))
    deepest = 0.0
    for step in range(6):
        sim.step(DOWN, step=step)
        for frame in range(1, SIM.substeps_per_step + 1):
            tools = sim.read_tools(frame)
            sdf = box_sdf(sim.read_particles(frame)["x"], tools["pos"][0], tools["rot"][0], PUSHER_HALF)
            deepest = max(deepest, -float(sdf.min()))
    assert deepest > 0.0, "the tool never touched the dough"
    assert deepest <= DX, f"a particle sank {deepest / DX:.2f} dx into the tool"


# ---------------------------------------------------------------------------- cutting

CUT_DX = 1.0 / CUT_SIM.n_grid
CUT_FLOOR = CUT_SIM.boundary_cells * CUT_DX
CUT_BLOCK_LO = (0.4, CUT_FLOOR, 0.46)
CUT_BLOCK_HI = (0.6, CUT_FLOOR + 0.06, 0.54)


@pytest.fixture(scope="module")
def cut() -> dict[str, np.ndarray]:
    """Cut a 0.2 x 0.06 x 0.08 block on the floor with the knife: down through it and back out."""
    sim = simulator(KNIFE, CUT_SIM)
    rng = np.random.default_rng(2)
    sim.set_state(block_state(uniform_block(rng, CUT_BLOCK_LO, CUT_BLOCK_HI, CUT_SIM.n_particles)))
    stay, down, up = np.zeros(3), np.array([0.0, -1.0, 0.0]), np.array([0.0, 1.0, 0.0])
    step = run_steps(sim, stay, 10)  # settle
    rest = sim.get_state()
    tip_start = block_top(rest) + 0.005
    sim.set_state(with_tool(rest, (CENTRE_X, tip_start + KNIFE.blade_depth, CENTRE_Z)))
    n_down = int(np.ceil(tip_start / KNIFE.action_scales[1]))  # the edge ends at or below y = 0
    step = run_steps(sim, down, n_down, step)
    tip_low = float(sim.read_tools(0)["pos"][0, 1]) - KNIFE.blade_depth
    step = run_steps(sim, up, n_down, step)
    step = run_steps(sim, stay, 5, step)
    return {"rest": rest["x"], "after": sim.get_state()["x"], "tip_low": tip_low}


def test_knife_cuts_block_in_two(cut):
    """The block ends in two DBSCAN clusters (eps 0.03, min_samples 6, more than 10 points), one each side."""
    assert cut["tip_low"] < cut["rest"][:, 1].min(), "the knife's edge did not reach below the dough"
    assert len(big_clusters(cut["rest"])) == 1
    sizes = big_clusters(cut["after"])
    assert len(sizes) == 2, f"clusters after the cut: {sizes}"
    assert min(sizes) > 0.2 * CUT_SIM.n_particles, f"one piece is a sliver: {sizes}"


# ------------------------------------------------------------------------ determinism


def test_stepping_is_deterministic_and_restorable(pusher_sim, resting_block):
    """Same state and actions give bit-identical states; set_state(get_state()) is exact and resumable."""
    sim = pusher_sim
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.0, 1.0, (6, 6)).astype(np.float32)
    actions[:, 1] = -1.0  # keep pressing into the dough so that contact is part of what is checked
    actions[:, 3:] = 0.0
    start = with_tool(resting_block, pusher_above(resting_block))

    def rollout(state, acts):
        sim.set_state(state)
        for t, a in enumerate(acts):
            sim.step(a, step=t)
        return sim.get_state()

    def assert_identical(a, b):
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key, strict=True)

    full = rollout(start, actions)
    assert_identical(full, rollout(start, actions))

    middle = rollout(start, actions[:3])
    sim.set_state(middle)
    assert_identical(middle, sim.get_state())

    rollout(park_tool(resting_block), -actions)  # scramble every frame of the simulator
    assert_identical(full, rollout(middle, actions[3:]))


# ------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("action", "shown"),
    [
        ([np.nan, 0, 0, 0, 0, 0], "nan"),
        ([0, 1.5, 0, 0, 0, 0], "1.5"),
        ([0, 0, 0, 0, 0, -2.0], "-2.0"),
        ([0, 0, np.inf, 0, 0, 0], "inf"),
    ],
)
def test_bad_action_raises_action_error(pusher_sim, resting_block, action, shown):
    sim = pusher_sim
    sim.set_state(resting_block)
    with pytest.raises(ActionError, match=rf"step 4\b.*{shown}"):
        sim.step(np.array(action, np.float32), step=4)
    np.testing.assert_array_equal(sim.get_state()["x"], resting_block["x"])  # nothing was simulated


def test_wrong_action_size_raises_action_error(pusher_sim, resting_block):
    pusher_sim.set_state(resting_block)
    with pytest.raises(ActionError, match=r"step 2\b.*5 values"):
        pusher_sim.step(np.zeros(5), step=2)


def test_huge_velocity_raises_simulation_error(pusher_sim, resting_block):
    sim = pusher_sim
    v = np.zeros_like(resting_block["v"])
    v[:10] = 1e5
    sim.set_state({**resting_block, "v": v})
    with pytest.raises(SimulationError, match=r"step 7\b"):
        sim.step(STAY, step=7)


def test_stiff_material_blow_up_raises_simulation_error(pusher_sim, resting_block):
    sim = pusher_sim
    sim.set_material(material(youngs_modulus_pa=1e12))  # far beyond the explicit time step's stability limit
    sim.set_state(resting_block)
    with pytest.raises(SimulationError, match=r"step 11\b"):
        sim.step(STAY, step=11)
