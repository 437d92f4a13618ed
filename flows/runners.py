"""Where a flow's simulator tasks run: a process pool on this machine or a Dask cluster.

Taichi keeps one runtime per process and must own the process's main thread, so simulator work never
runs in Prefect's thread pool. A process pool's workers run each task in their main thread. A Dask
worker runs tasks in a thread, so there a task hands its work to a child ``python -m <module>`` process
(:func:`run_in_child_process`) and reads the result back from a file.

A command runs against one Prefect server (:func:`one_prefect_server`): the pool workers report their task
runs to it instead of each starting a temporary server of its own.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cloudpickle
from prefect.settings import PREFECT_API_URL, temporary_settings
from prefect.task_runners import ProcessPoolTaskRunner, TaskRunner

from pasta.sim.runtime import THREADS_ENV

__all__ = [
    "check_workers", "exit_with_parent", "in_main_thread", "one_prefect_server", "run_in_child_process",
    "share_cores", "task_runner", "write_child_result",
]


PARENT_POLL_S = 1.0  # how often a pool worker checks that the process that started it is still alive


def exit_with_parent(parent: int, poll_s: float = PARENT_POLL_S) -> None:
    """Exit this process (status 1) as soon as its parent is no longer ``parent``; never returns otherwise.

    A pool worker's parent that is killed (Ctrl-C twice, SIGKILL, a session's end) cannot shut its pool down,
    and its workers would go on simulating demonstrations for nobody, holding the cores.
    """
    while True:
        time.sleep(poll_s)
        if os.getppid() != parent:
            os._exit(1)


def share_cores(threads: int) -> None:
    """Process-pool initialiser: each worker gets its share of the cores (Taichi and torch), and exits when the
    process that started it dies (:func:`exit_with_parent`, in a daemon thread)."""
    os.environ[THREADS_ENV] = str(threads)
    threading.Thread(target=exit_with_parent, args=(os.getppid(),), daemon=True, name="exit-with-parent").start()
    import torch

    torch.set_num_threads(threads)


@contextlib.contextmanager
def one_prefect_server(enabled: bool = True) -> Iterator[str | None]:
    """Run the enclosed flows against one Prefect server, whose API URL the pool workers inherit.

    With ``PREFECT_API_URL`` set (a running server, or the tests' harness) nothing changes. Otherwise the
    temporary server Prefect would start on first use is started now and its URL set for this process; a
    process pool passes the settings on, so its workers report to it (their task runs appear under the
    flow run) instead of each starting a server. ``enabled=False`` (a Dask cluster, whose workers may not
    reach this machine's server) leaves Prefect's own choice. Yields the API URL in use (``None``: none yet).
    """
    if not enabled or PREFECT_API_URL.value():
        yield PREFECT_API_URL.value()
        return
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()  # Prefect's own default server: stopped when the process exits
    server.start()
    with temporary_settings(updates={PREFECT_API_URL: server.api_url}):
        yield server.api_url


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
