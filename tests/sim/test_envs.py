"""Task environments at the smoke profile: reset, step, observations, state round trips, errors,
distractors, and the scripted demo.

One environment per task is built per module (``envs`` fixture); each test resets it itself.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from sklearn.cluster import DBSCAN

from pasta.config import load
from pasta.config.schema import TASK_NAMES
from pasta.sim.engine import ActionError, stopped_knife
from pasta.sim.envs import DoughConfiguration, DoughEnv, ToolPose, default_configuration, make_env
from pasta.sim.tool_points import world_sdf

STATE_KEYS = ("x", "v", "C", "F", "tool_pos", "tool_rot", "tool_gap")


@pytest.fixture(scope="module")
def envs() -> dict[str, DoughEnv]:
    return {task: make_env(load(task, "smoke")) for task in TASK_NAMES}


def reset(env: DoughEnv, seed: int = 0):
    return env.reset(env.default_configuration(np.random.default_rng(seed)))


def first_tool_action(env: DoughEnv, seed: int = 1) -> np.ndarray:
    """A random action of the first skill's tool, in [-1, 1]."""
    tool = env.skills[0].tool
    s = env.tool_action_slice(tool)
    return env.action_for(tool, np.random.default_rng(seed).uniform(-1, 1, s.stop - s.start))


def n_clusters(points: np.ndarray) -> int:
    labels = DBSCAN(eps=0.03, min_samples=6).fit(points).labels_
    return len(set(labels.tolist()) - {-1})


@pytest.mark.parametrize("task", TASK_NAMES)
def test_reset_and_step_give_observations_of_the_right_shapes(envs, task):
    env = envs[task]
    cfg = env.cfg
    obs = reset(env)
    assert obs.step == 0
    assert obs.dough_points.shape == (cfg.sim.observation_points, 3) == (1000, 3)
    assert set(obs.tool_points) == {t.name for t in cfg.tools}
    assert all(p.shape == (cfg.sim.tool_points, 3) == (100, 3) for p in obs.tool_points.values())
    assert obs.tool_states.shape == (len(cfg.tools), 8)
    assert obs.tool_states.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(obs.tool_states[:, 3:7], axis=1), 1.0, atol=1e-5)
    x0 = env.particles()
    np.testing.assert_array_equal(obs.dough_points, x0[: cfg.sim.observation_points])  # the first particles

    for _ in range(2):
        obs = env.step(first_tool_action(env))
    assert obs.step == env.step_count == 2
    x = env.particles()
    assert np.isfinite(x).all()
    assert obs.dough_points.shape == (1000, 3)
    np.testing.assert_array_equal(obs.dough_points, x[:1000])  # same fixed index set after stepping
    with pytest.raises(ValueError):
        obs.dough_points[0, 0] = 1.0  # observations are read-only
    assert env.horizon == cfg.horizon
    assert env.skills == cfg.skills


def test_crs_twice_is_crs_with_horizon_six(envs):
    assert envs["CRS-Twice"].horizon == 6 and envs["CRS"].horizon == 3
    assert type(envs["CRS-Twice"]) is type(envs["CRS"])
    assert [s.name for s in envs["CRS-Twice"].skills] == ["cut", "push", "spread"]


@pytest.mark.parametrize("task", ["CutRearrange", "GatherMove"])
def test_state_round_trip_is_exact_and_replays_bit_for_bit(envs, task):
    env = envs[task]
    reset(env)
    env.step(first_tool_action(env, seed=3))
    saved = env.get_state()
    assert saved["step"] == 1
    action = first_tool_action(env, seed=4)
    env.step(action)
    after = env.get_state()

    env.set_state(saved)
    restored = env.get_state()
    for key in STATE_KEYS:
        np.testing.assert_array_equal(restored[key], saved[key], err_msg=key)
    assert restored["step"] == 1 == env.step_count
    env.step(action)
    replay = env.get_state()
    for key in STATE_KEYS:
        assert np.array_equal(replay[key], after[key]), f"{key} differs after replaying from a restored state"
    assert replay["step"] == after["step"] == 2


def test_environments_sharing_a_simulator_keep_their_own_states(envs):
    crs, twice = envs["CRS"], envs["CRS-Twice"]
    assert crs._simulator is twice._simulator  # same compile-time layout
    reset(crs, seed=0)
    action = first_tool_action(crs, seed=5)
    crs.step(action)
    start = crs.get_state()
    crs.step(action)
    alone = crs.get_state()

    crs.set_state(start)
    reset(twice, seed=1)
    twice.step(first_tool_action(twice, seed=6))
    crs.step(action)  # must continue from its own state, not from CRS-Twice's
    interleaved = crs.get_state()
    for key in STATE_KEYS:
        assert np.array_equal(interleaved[key], alone[key]), key
    assert twice.step_count == 1
    assert not np.array_equal(twice.particles(), crs.particles())


@pytest.mark.parametrize(("value", "shown"), [(float("nan"), "nan"), (1.5, "1.5"), (-7.0, "-7.0")])
def test_bad_action_values_name_the_step_and_the_value(envs, value, shown):
    env = envs["CutRearrange"]
    reset(env)
    env.step(np.zeros(env.action_dim))
    env.step(np.zeros(env.action_dim))
    action = np.zeros(env.action_dim)
    action[1] = value
    before = env.get_state()
    with pytest.raises(ActionError) as info:
        env.step(action)
    message = str(info.value)
    assert "step 2" in message and shown in message and "knife" in message
    assert env.step_count == 2
    np.testing.assert_array_equal(env.get_state()["x"], before["x"])  # nothing was simulated


def test_wrong_action_size_and_use_before_reset_are_refused():
    env = make_env(load("CutRearrange", "smoke"))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(env.action_dim))
    reset(env)
    with pytest.raises(ActionError, match="expected 10"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="particles"):
        env.reset(DoughConfiguration(particles=np.full((10, 3), 0.5)))


def test_action_slices_follow_the_tool_order(envs):
    env = envs["CutRearrange"]
    assert env.tool_action_slice("knife") == slice(0, 3)
    assert env.tool_action_slice("gripper") == slice(3, 10)
    a = env.action_for("gripper", [0, 0, 0, 0, 0, 0, 1])
    assert a.shape == (10,) and a[9] == 1 and a[:9].sum() == 0
    with pytest.raises(KeyError, match="unknown tool"):
        env.tool_action_slice("spoon")


def test_teleport_settle_and_tool_states(envs):
    env = envs["CutRearrange"]
    reset(env)
    obs = env.teleport_tool("knife", (0.3, 0.4, 0.5))
    np.testing.assert_allclose(obs.tool_states[0, :3], (0.3, 0.4, 0.5), atol=1e-6)
    assert obs.step == 0  # teleporting is not a step
    obs = env.teleport_tool("gripper", (0.5, 0.2, 0.5), gap=0.5)  # clipped to max_gap 0.2
    assert obs.tool_states[1, 7] == pytest.approx(0.2)
    knife = env.tool("knife")
    d = world_sdf(knife, obs.tool_points["knife"], (0.3, 0.4, 0.5), (1, 0, 0, 0))
    assert np.abs(d).max() < 1e-4
    obs = env.settle(2)
    assert obs.step == 2
    np.testing.assert_allclose(obs.tool_states[0, :3], (0.3, 0.4, 0.5), atol=1e-6)  # zero actions
    assert env.back_pose("gripper") == ToolPose(pos=(0.5, 0.1, 0.5), rot=(0.707, 0.0, 0.707, 0.0), gap=0.18)


@pytest.mark.parametrize("task", TASK_NAMES)
def test_tool_points_lie_on_the_tool_surfaces(envs, task):
    env = envs[task]
    obs = reset(env)
    for k, tool in enumerate(env.tools):
        pos, rot, gap = obs.tool_states[k, :3], obs.tool_states[k, 3:7], obs.tool_states[k, 7]
        d = world_sdf(tool, obs.tool_points[tool.name], pos, rot, gap)
        # Mesh chords of the capsule lie up to ~1e-4 inside the exact surface.
        assert np.abs(d).max() < 5e-4, (tool.name, np.abs(d).max())


@pytest.mark.parametrize("task", TASK_NAMES)
def test_default_configurations_start_clear_of_the_tools(task):
    cfg = load(task, "smoke")
    conf = default_configuration(cfg, np.random.default_rng(0))
    assert conf.particles.shape == (cfg.sim.n_particles, 3)
    assert conf.particles.dtype == np.float32
    lo, hi = 1.0 / cfg.sim.n_grid, 1.0 - 3.0 / cfg.sim.n_grid
    assert conf.particles.min() >= lo and conf.particles.max() <= hi
    for tool in cfg.tools:
        pose = conf.tool_poses[tool.name]
        d = world_sdf(tool, conf.particles, pose.pos, pose.rot, pose.gap)
        assert (d > 0).all(), f"{tool.name} starts inside the dough"
    again = default_configuration(cfg, np.random.default_rng(0))
    np.testing.assert_array_equal(conf.particles, again.particles)  # seeded


def test_cut_rearrange_dough_rests_on_the_floor():
    cfg = load("CutRearrange", "smoke")
    x = default_configuration(cfg, np.random.default_rng(0)).particles
    floor = cfg.sim.boundary_cells / cfg.sim.n_grid
    assert x[:, 1].min() == pytest.approx(floor, abs=2e-3)
    assert x[:, 1].max() == pytest.approx(floor + 0.08, abs=2e-3)
    np.testing.assert_allclose(x.mean(axis=0)[[0, 2]], (0.5, 0.5), atol=0.01)
    assert n_clusters(x) == 1


@pytest.mark.parametrize("task", ["CutRearrange", "CRS", "LiftSpread"])
def test_distractors_add_separate_pieces(task):
    cfg = load(task, "smoke", {"distractors": 2})
    conf = default_configuration(cfg, np.random.default_rng(0))
    assert conf.particles.shape == (cfg.sim.n_particles, 3)
    assert n_clusters(conf.particles) == 3
    labels = conf.piece_labels
    assert sorted(set(labels.tolist())) == [0, 1, 2]
    counts = np.bincount(labels)
    assert counts[0] > counts[1] and counts[0] > counts[2]  # distractors are small
    # The first observation points sample every piece (particles are shuffled).
    assert len(set(labels[: cfg.sim.observation_points].tolist())) == 3
    for tool in cfg.tools:
        pose = conf.tool_poses[tool.name]
        assert (world_sdf(tool, conf.particles, pose.pos, pose.rot, pose.gap) > 0).all()


def test_gather_move_distractors_stay_clear_of_the_scatter():
    cfg = load("GatherMove", "smoke", {"distractors": 2})
    conf = default_configuration(cfg, np.random.default_rng(3))
    labels = conf.piece_labels
    main = conf.particles[labels == 0]
    for piece in (1, 2):
        other = conf.particles[labels == piece]
        gap = np.linalg.norm(main[:, None, [0, 2]] - other[None, :, [0, 2]], axis=-1).min()
        assert gap > 0.04


def test_environment_with_distractors_steps():
    env = make_env(load("CutRearrange", "smoke", {"distractors": 2}))
    obs = reset(env)
    obs = env.settle(2)
    assert obs.dough_points.shape == (1000, 3)
    assert n_clusters(env.particles()) == 3


def test_demo_runs_for_cut_rearrange_at_smoke(tmp_path, capsys):
    from pasta.sim import demo

    png = demo.main(task="CutRearrange", profile="smoke", out=tmp_path)
    assert png == tmp_path / "CutRearrange_smoke.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "CutRearrange_smoke.gif").read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    out = capsys.readouterr().out
    assert str(png) in out

    # The same demo's physics at its own size (grid 32), from the same seed-0 configuration.
    cfg = load("CutRearrange", "smoke")
    env = make_env(cfg)
    env.reset(env.default_configuration(np.random.default_rng(0)))
    before, start = env.particles(), env.tool_poses()["knife"]
    frames = demo.run_demo(env)
    after, end = env.particles(), env.tool_poses()["knife"]
    pieces = demo.count_pieces(after, cfg.data.dbscan_eps, cfg.data.dbscan_min_samples)
    assert f"CutRearrange (smoke): {env.step_count} steps, {pieces} dough piece(s)" in out
    with Image.open(tmp_path / "CutRearrange_smoke.gif") as gif:
        assert gif.n_frames == len(frames) >= 3
    # the knife went down over the dough's centre, slid 0.09 to -x and came back up to its height
    centre = before.mean(axis=0)
    np.testing.assert_allclose(end.pos, (centre[0] - 0.09, start.pos[1], centre[2]), atol=2e-4)
    # and it pressed through the dough: the top came down and the dough spread along the slide
    assert np.isfinite(after).all() and after.min() >= 0.0 and after.max() <= 1.0
    assert after[:, 1].max() < before[:, 1].max() - 0.005
    assert after[:, 1].mean() < before[:, 1].mean() - 0.01
    assert np.ptp(after[:, 0]) > np.ptp(before[:, 0]) + 0.05


@pytest.mark.slow
def test_demo_cut_makes_two_pieces_at_the_paper_grid(tmp_path):
    """At grid 80 the scripted cut (down, slide the left piece, up) leaves two DBSCAN pieces."""
    from pasta.sim import demo

    env = make_env(load("CutRearrange", "paper"))
    demo.run_demo(env)
    assert n_clusters(env.particles()) == 2


def test_a_knife_stops_its_edge_knife_floor_depth_below_the_floor(envs):
    """``sim.knife_floor_depth``: driven straight down, the knife's edge stops that far below the floor (its y
    lower bound, ``stopped_knife``); without it the knife goes on down. Other tools keep their bounds."""
    stopped = make_env(load("CutRearrange", "smoke", {"sim.knife_floor_depth": 0.02}))
    knife = stopped.tool("knife")
    lowest = stopped.floor_y + knife.blade_depth - 0.02
    assert stopped_knife(stopped.cfg.sim, stopped.tool("gripper")) == stopped.tool("gripper")
    assert stopped_knife(stopped.cfg.sim, knife).lower_bound[1] == pytest.approx(lowest)
    finals = []
    for env in (stopped, envs["CutRearrange"]):
        reset(env)
        env.teleport_tool("knife", (0.12, lowest + 0.05, 0.5))  # clear of the dough
        down = env.action_for("knife", np.array([0.0, -1.0, 0.0]))
        for _ in range(15):
            obs = env.step(down)
        finals.append(float(obs.tool_states[0, 1]))
    assert finals[0] == pytest.approx(lowest, abs=1e-5)
    assert finals[1] < lowest - 0.01
