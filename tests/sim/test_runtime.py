"""The per-process Taichi runtime: its kernel cache setting and a clean start."""

from __future__ import annotations

import os
import subprocess
import sys

from pasta.sim.runtime import CACHE_ENV, cache_argument, kernel_cache_dir


def test_the_cache_path_is_an_init_argument_only_without_the_environment_variable(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_ENV, raising=False)
    assert cache_argument() == {"offline_cache_file_path": str(kernel_cache_dir())}
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    assert cache_argument() == {}  # Taichi reads the variable itself
    assert kernel_cache_dir() == tmp_path


def test_taichi_starts_without_warnings_when_the_cache_variable_is_set(tmp_path):
    code = "from pasta.sim.runtime import ensure_taichi; ensure_taichi('cpu')"
    env = {**os.environ, CACHE_ENV: str(tmp_path / "ticache")}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300,
                          check=True)
    output = done.stdout + done.stderr
    assert "overridden" not in output and "WARN" not in output, output
