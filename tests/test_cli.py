"""The `pasta` command line."""

from __future__ import annotations

import sys
import types

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
    assert main(["config", "--task", "CRS", "--set", "sim.n_gird=40"]) == 2
    err = capsys.readouterr().err
    assert "sim.n_gird" in err and "n_grid" in err


def test_sim_demo_calls_the_demo_lazily(monkeypatch):
    calls = []
    fake = types.ModuleType("pasta.sim.demo")
    fake.main = lambda **kwargs: calls.append(kwargs)
    monkeypatch.setitem(sys.modules, "pasta.sim.demo", fake)
    assert main(["sim-demo", "--task", "CutRearrange"]) == 0
    assert calls == [{"task": "CutRearrange", "profile": "smoke", "out": None}]
