"""Shared setup for the physics tests: two compile-time layouts and small state helpers.

Taichi compiles the simulator's kernels once per compile-time layout (grid, particle
count, dt, substeps, tool kinds), which takes seconds. Every physics test therefore uses
one of two layouts that differ only in their tool: ``SIM`` with the box ``PUSHER`` and
``SIM`` with the ``KNIFE``. Material, gravity, softness and tool sizes are runtime values;
the fixtures reset them before each test, so a test may change them freely.
"""

from __future__ import annotations

import numpy as np
import pytest

from pasta.config.schema import MaterialConfig, SimConfig, ToolConfig
from pasta.sim.engine import MPMSimulator, expel_rates, simulator_for

SIM = SimConfig(
    n_grid=32,
    dt_s=2e-4,
    substeps_per_step=10,
    n_particles=2000,
    gravity_m_s2=(0.0, -600.0, 0.0),
    boundary_cells=3,
)
DX = 1.0 / SIM.n_grid
N = SIM.n_particles
STEP_S = SIM.dt_s * SIM.substeps_per_step  # simulated seconds per environment step

# Where a tool waits when a test wants no tool contact: well above any dough.
PARK = (0.5, 0.9, 0.5)

# A box of 0.1 per side: at dx = 1/32 it holds 3 grid nodes across, so that it really
# presses the dough through its interior nodes (a 0.06 box holds a single node column).
PUSHER_HALF = (0.05, 0.05, 0.05)
PUSHER = ToolConfig(
    name="pusher",
    kind="box",
    position=PARK,
    half_extents=PUSHER_HALF,
    action_scales=(0.01, 0.01, 0.01, 0.0, 0.0, 0.0),  # x, y, z per env step at action 1; no rotation
)
# The CutRearrange knife (conf/tasks/CutRearrange.yaml).
KNIFE = ToolConfig(
    name="knife",
    kind="knife",
    position=PARK,
    half_extents=(0.025, 0.075, 0.06),
    blade_depth=0.15,
    blade_angle_deg=60.0,
    action_scales=(0.015, 0.015, 0.0),
)

# Cutting needs the knife (0.05 thick) to span several grid cells: a 64 grid, as the paper's
# LiftSpread/GatherMove grid (CutRearrange used 80).
CUT_SIM = SIM.model_copy(update={"n_grid": 64, "dt_s": 1e-4, "substeps_per_step": 20, "n_particles": 8000})

MATERIAL = MaterialConfig(
    youngs_modulus_pa=5e3, poisson_ratio=0.15, yield_stress_pa=150.0, ground_friction=0.5
)

# The block every pressing / pushing test starts from: 0.2 x 0.1 x 0.2, centred in x and z,
# its bottom placed at the resting height of the floor band (about boundary_cells * dx).
BLOCK_LO = (0.4, 0.085, 0.4)
BLOCK_HI = (0.6, 0.185, 0.6)
SETTLE_STEPS = 60


def material(**changes: float) -> MaterialConfig:
    """``MATERIAL`` with some fields changed (validated)."""
    return MaterialConfig(**{**MATERIAL.model_dump(), **changes})


def uniform_block(rng: np.random.Generator, lo, hi, n: int = N) -> np.ndarray:
    """``n`` particle positions drawn uniformly in the axis-aligned box [lo, hi], float32 (n, 3)."""
    return rng.uniform(lo, hi, (n, 3)).astype(np.float32)


def tool_at(position) -> dict[str, np.ndarray]:
    """Tool entries of a state dict for one tool at ``position`` with the identity rotation."""
    return {
        "tool_pos": np.asarray([position], np.float32),
        "tool_rot": np.asarray([[1.0, 0.0, 0.0, 0.0]], np.float32),
        "tool_gap": np.zeros(1, np.float32),
    }


def park_tool(state: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A copy of ``state`` with its tool parked at ``PARK``, far from the dough."""
    return {**state, **tool_at(PARK)}


def with_tool(state: dict[str, np.ndarray], position) -> dict[str, np.ndarray]:
    """A copy of ``state`` with its tool moved to ``position``."""
    return {**state, **tool_at(position)}


def block_state(x: np.ndarray, tool_position=PARK) -> dict[str, np.ndarray]:
    """A state at rest: positions ``x``, zero v and C, identity F, one tool at ``tool_position``."""
    n = len(x)
    return {
        "x": np.asarray(x, np.float32),
        "v": np.zeros((n, 3), np.float32),
        "C": np.zeros((n, 3, 3), np.float32),
        "F": np.broadcast_to(np.eye(3, dtype=np.float32), (n, 3, 3)).copy(),
        **tool_at(tool_position),
    }


def run_steps(sim: MPMSimulator, action, n_steps: int, first_step: int = 0) -> int:
    """Step ``n_steps`` times under the same action; returns the next step index."""
    action = np.asarray(action, np.float32)
    for t in range(first_step, first_step + n_steps):
        sim.step(action, step=t)
    return first_step + n_steps


def simulator(tool: ToolConfig, layout: SimConfig = SIM) -> MPMSimulator:
    """The shared simulator of ``SIM`` with this one tool, every runtime value reset to the defaults.

    Resets what an earlier test may have changed: material, gravity, softness and tool sizes.
    """
    sim = simulator_for(layout, (tool,))
    sim.set_material(MATERIAL)
    sim.set_gravity(layout.gravity_m_s2)
    sim.set_softness(layout.contact_softness)
    sim.set_expel_rates(expel_rates(layout, (tool,)))
    sim.set_tools((tool,))
    return sim


@pytest.fixture
def pusher_sim() -> MPMSimulator:
    """The box-pusher simulator, runtime values reset."""
    return simulator(PUSHER)


@pytest.fixture
def knife_sim() -> MPMSimulator:
    """The knife simulator, runtime values reset."""
    return simulator(KNIFE)


@pytest.fixture(scope="session")
def resting_block() -> dict[str, np.ndarray]:
    """The ``BLOCK_LO``-``BLOCK_HI`` block after settling on the floor, tool parked (seed 0).

    Settled as an elastic solid (yield stress 1e6) so that the state is an elastic
    equilibrium whatever material a test then switches to (gravity alone loads the
    dough to about rho g h = 60 Pa, below the 150 Pa yield stress).
    """
    sim = simulator(PUSHER)
    sim.set_material(material(yield_stress_pa=1e6))
    sim.set_state(block_state(uniform_block(np.random.default_rng(0), BLOCK_LO, BLOCK_HI)))
    run_steps(sim, np.zeros(sim.action_dim), SETTLE_STEPS)
    state = sim.get_state()
    simulator(PUSHER)
    return state
