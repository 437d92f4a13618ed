"""Where a flow's simulator tasks run: a process pool on this machine or a Dask cluster.

Taichi keeps one runtime per process and must own the process's main thread, so simulator work never
runs in Prefect's thread pool. A process pool's workers run each task in their main thread. A Dask
worker runs tasks in a thread, so there a task hands its work to a child ``python -m <module>`` process
(:func:`run_in_child_process`) and reads the result back from a file.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import cloudpickle
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner

from pasta.sim.runtime import THREADS_ENV

__all__ = [
    "check_workers", "in_main_thread", "run_in_child_process", "share_cores", "task_runner", "write_child_result",
]


def share_cores(threads: int) -> None:
    """Process-pool initialiser: each worker gets its share of the cores (Taichi and torch)."""
    os.environ[THREADS_ENV] = str(threads)
    import torch

    torch.set_num_threads(threads)


def check_workers(workers: int) -> None:
    """Refuse a worker count below 1, naming it."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an integer of at least 1, got {workers!r}")


def task_runner(workers: int, dask_address: str | None = None) -> TaskRunner:
    """A process pool of ``workers`` on this machine, or a Dask cluster at ``dask_address``."""
    if dask_address:
        from prefect_dask import DaskTaskRunner

        return DaskTaskRunner(address=dask_address)
    check_workers(workers)
    threads = max(1, (os.cpu_count() or 1) // workers)
    return ProcessPoolTaskRunner(max_workers=workers, initializer=share_cores, initargs=(threads,))


def in_main_thread() -> bool:
    """Whether this code may start Taichi here (it may not in a Dask worker's task thread)."""
    return threading.current_thread() is threading.main_thread()


def run_in_child_process(module: str, arguments: list[Any]) -> Any:
    """Run ``python -m module '<arguments as JSON>' <result file>`` and return what it pickled there.

    The child's ``__main__`` computes the result in its own main thread and calls
    :func:`write_child_result`. A child that fails raises ``subprocess.CalledProcessError`` here.
    """
    with tempfile.TemporaryDirectory(prefix="pasta-child-") as folder:
        result_path = Path(folder) / "result.pkl"
        subprocess.run([sys.executable, "-m", module, json.dumps(arguments), str(result_path)], check=True)
        if not result_path.is_file():
            raise RuntimeError(f"the child process `python -m {module}` wrote no result to {result_path}")
        with result_path.open("rb") as handle:
            return cloudpickle.load(handle)


def write_child_result(result: Any, path: str) -> None:
    """The child side of :func:`run_in_child_process`: pickle ``result`` to ``path`` atomically."""
    target = Path(path)
    partial = target.with_suffix(".partial")
    with partial.open("wb") as handle:
        cloudpickle.dump(result, handle)
    partial.replace(target)
