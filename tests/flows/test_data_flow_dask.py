"""The data flow on a local Dask cluster of 2 worker processes (``DaskTaskRunner(address=...)``)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.flow

# The smallest dataset: one train and one test trajectory.
TINY = ("data.n_train_trajectories=1", "data.n_test_trajectories=1")


def test_data_flow_runs_its_demos_on_dask_workers(prefect_server, isolated_store):
    from distributed import Client, LocalCluster, get_task_stream

    from flows import data
    from pasta.config import load
    from pasta.data.configurations import skill_schedule
    from pasta.data.storage import read_trajectory

    tmp_path, _ = isolated_store
    with (LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
          Client(cluster) as client, get_task_stream(client) as stream):
        summary = data.run("CutRearrange", "smoke", method="scripted", overrides=TINY,
                           dask_address=cluster.scheduler_address)
        worker_pids = set(client.run(lambda: __import__("os").getpid()).values())
    assert len(worker_pids) == 2
    assert len(stream.data) >= 2, "the demos did not run on the Dask cluster"
    assert summary["demos"] == summary["made"] == 2 and summary["train"] == summary["test"] == 1

    files = sorted((tmp_path / "home" / "data" / "CutRearrange" / "smoke" / "scripted").glob("trajectory_*.npz"))
    assert [f.name for f in files] == ["trajectory_000000.npz", "trajectory_000001.npz"]
    skills = []
    for path in files:
        arrays, meta = read_trajectory(path)
        frames = arrays["dough_points"]
        assert frames.ndim == 3 and frames.shape[2] == 3 and np.isfinite(frames).all()
        assert arrays["actions"].shape[0] == frames.shape[0] - 1
        assert (meta["task"], meta["profile"], meta["method"]) == ("CutRearrange", "smoke", "scripted")
        assert np.isfinite(meta["normalised_performance"])
        skills.append(meta["skill"])
    assert tuple(skills) == skill_schedule(load("CutRearrange", "smoke", list(TINY)))
