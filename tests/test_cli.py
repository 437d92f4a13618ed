"""The `pasta` command line."""

from __future__ import annotations

import sys
import types

import pytest
import yaml

from pasta.cli import main


def test_config_prints_resolved_yaml(capsys):
    assert main(["config", "--task", "CRS", "--profile", "small", "--set", "sim.n_grid=40"]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    assert (cfg["task"], cfg["profile"]) == ("CRS", "small")
    assert cfg["sim"]["n_grid"] == 40
    assert cfg["sim"]["n_particles"] == 5000
    assert cfg["plan"]["samples"] == 1000


def test_config_error_goes_to_stderr(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["config", "--task", "CRS", "--set", "sim.n_gird=40"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "sim.n_gird" in err and "n_grid" in err


# (arguments, what the error line must name: the bad value and the allowed ones)
BAD_VALUES = [
    (["config", "--task", "Pasta"], ["'Pasta'", "CutRearrange"]),
    (["config", "--task", "CRS", "--profile", "huge"], ["'huge'", "smoke", "paper"]),
    (["config", "--task", "CRS", "--set", "sim.n_grid=abc", "--set", "sim.dt_s=-1"], ["'abc'", "-1", "> 0"]),
    (["sim-demo", "--task", "crs"], ["'crs'", "CRS-Twice"]),
    (["data", "--task", "CRS", "--method", "random"], ["'random'", "gbto", "scripted"]),
    (["data", "--task", "CRS", "--workers", "0"], ["'0'", "at least 1"]),
    (["data", "--task", "CRS", "--workers", "two"], ["'two'", "integer"]),
    (["data", "--task", "CRS", "--seed", "-1"], ["'-1'", "at least 0"]),
    (["data", "--task", "CRS", "--set", "sim.n_gird=40"], ["sim.n_gird", "n_grid"]),
    (["train", "--task", "CRS", "--variant", "foo"], ["'foo'", "pasta", "flat3d"]),
    (["train", "--task", "CRS", "--method", "random"], ["'random'", "gbto", "scripted"]),
    (["train", "--task", "CRS", "--device", "gpu"], ["'gpu'", "cpu", "cuda"]),
    (["train", "--task", "CRS", "--seed", "x"], ["'x'", "integer"]),
    (["train", "--task", "CRS", "--set", "train.nope=1"], ["train.nope", "valid keys"]),
    (["report", "--task", "Pasta"], ["'Pasta'", "CutRearrange"]),
    (["status", "--task", "Pasta"], ["'Pasta'", "CutRearrange"]),
    (["status", "--task", "CRS", "--profile", "huge"], ["'huge'", "smoke", "paper"]),
    (["status", "--profile", "smoke"], ["--task"]),
    (["evaluate", "--task", "CRS", "--variant", "foo"], ["'foo'", "pasta", "flat3d"]),
    (["evaluate", "--task", "CRS", "--plan", "random"], ["'random'", "learned", "oracle"]),
    (["evaluate", "--task", "CRS", "--executor", "human"], ["'human'", "policy", "scripted"]),
    (["evaluate", "--task", "CRS", "--seeds", "0", "-2"], ["'-2'", "at least 0"]),
    (["evaluate", "--task", "CRS", "--workers", "-1"], ["'-1'", "at least 1"]),
    (["evaluate", "--task", "CRS", "--set", "plan.samples=0"], ["plan.samples", "0"]),
    (["run", "--task", "CRS", "--workers", "0"], ["'0'", "at least 1"]),
    (["run", "--task", "CRS", "--variant", "foo"], ["'foo'", "pasta", "flat3d"]),
    (["run", "--task", "CRS", "--method", "random"], ["'random'", "gbto", "scripted"]),
    (["run", "--task", "CRS", "--executor", "human"], ["'human'", "policy", "scripted"]),
    (["run", "--profile", "smoke"], ["--task", "--all"]),
    (["run", "--task", "CRS", "--all"], ["--task", "--all"]),
    (["run", "--all", "--set", "tools.knife.friction=0.5"], ["knife", "rolling_pin"]),
    (["ablations", "--variants", "pasta", "foo"], ["'foo'", "flat3d"]),
    (["ablations", "--workers", "0"], ["'0'", "at least 1"]),
    (["ablations", "--set", "sim.n_gird=40"], ["sim.n_gird", "n_grid"]),
    (["sweeps", "--only", "time"], ["'time'", "samples", "horizon", "distractors"]),
    (["sweeps", "--workers", "0"], ["'0'", "at least 1"]),
    (["sweeps", "--seeds", "-1"], ["'-1'"]),
    (["sweeps", "--set", "sim.n_gird=40"], ["sim.n_gird", "n_grid"]),
]


@pytest.fixture
def no_flows(monkeypatch):
    """Flow and demo modules that fail when used: a bad value must be refused before any of them runs."""
    for name in ("flows.data", "flows.train", "flows.evaluate", "flows.pipeline", "flows.ablations",
                 "flows.sweeps", "flows.report", "pasta.sim.demo"):
        monkeypatch.setitem(sys.modules, name, types.ModuleType(name))


@pytest.mark.parametrize(("argv", "named"), BAD_VALUES, ids=[" ".join(argv) for argv, _ in BAD_VALUES])
def test_bad_value_ends_in_one_error_line(argv, named, no_flows, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    last = err.rstrip("\n").splitlines()[-1]
    assert last.startswith(f"pasta {argv[0]}: error: ")
    assert err.count("error:") == 1 and "Traceback" not in err
    for fragment in named:
        assert fragment in last


def test_sim_demo_calls_the_demo_lazily(monkeypatch):
    calls = []
    fake = types.ModuleType("pasta.sim.demo")
    fake.main = lambda **kwargs: calls.append(kwargs)
    monkeypatch.setitem(sys.modules, "pasta.sim.demo", fake)
    assert main(["sim-demo", "--task", "CutRearrange"]) == 0
    assert calls == [{"task": "CutRearrange", "profile": "smoke", "out": None}]


def test_sweep_overrides_are_checked_against_every_task_the_sweeps_run():
    from flows.sweeps import SWEEPS, sweep_points
    from pasta.cli import SWEEP_TASKS

    assert set(SWEEP_TASKS) == {task for sweep in SWEEPS for task, _, _ in sweep_points(sweep, "smoke")}
