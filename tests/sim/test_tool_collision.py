"""Tool-tool collision: a tool that ``collides_with`` a static box cannot pass through it."""

import numpy as np

from pasta.config import load
from pasta.sim.engine import simulator_for


def test_spatula_stops_at_the_cutting_board():
    cfg = load("LiftSpread", "smoke")
    tools = {t.name: t for t in cfg.tools}
    sim = simulator_for(cfg.sim, cfg.tools)
    sim.set_material(cfg.material)
    rng = np.random.default_rng(0)
    state = {
        "x": rng.uniform([0.75, 0.1, 0.45], [0.85, 0.15, 0.55], (cfg.sim.n_particles, 3)).astype(np.float32),
        "tool_pos": np.array([t.position for t in cfg.tools], np.float32),
        "tool_rot": np.array([t.rotation for t in cfg.tools], np.float32),
        "tool_gap": np.array([t.gap for t in cfg.tools], np.float32),
    }
    sim.set_state(state)
    spatula = [t.name for t in cfg.tools].index("spatula")
    action = np.zeros(sim.action_dim, np.float32)
    action[sim.action_offsets[spatula]] = -1.0  # slide towards the board (-x)
    for step in range(30):
        sim.step(action, step=step)
    board = tools["board"]
    spatula_x = float(sim.read_tools(0)["pos"][spatula, 0])
    board_right_face = board.position[0] + board.half_extents[0]
    assert abs(spatula_x - tools["spatula"].half_extents[0] - board_right_face) < 1e-4
    np.testing.assert_allclose(sim.read_tools(0)["pos"][[t.name for t in cfg.tools].index("board")], board.position,
                               atol=1e-6)


def test_static_tools_take_no_action_dimensions():
    cfg = load("LiftSpread", "smoke")
    sim = simulator_for(cfg.sim, cfg.tools)
    assert sim.action_dim == 12  # rolling pin 6 + spatula 6; the board is static (env_spec 2.1)
