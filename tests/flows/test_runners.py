"""The process pool's workers do not outlive the process that started them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

# A parent that starts a pool of one worker the way `task_runner` does, prints the worker's pid and waits.
PARENT = textwrap.dedent("""
    import os, sys, time
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing
    from flows.runners import share_cores

    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"), initializer=share_cores,
                               initargs=(1,))
    print("worker", pool.submit(os.getpid).result(), flush=True)
    time.sleep(600)
""")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:  # a zombie has exited; only its parent's reaping is left
        return stat.read().split()[2] != "Z"


def test_a_pool_worker_exits_when_its_parent_is_killed():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True,
                              cwd=os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    try:
        line = ""
        while not line.startswith("worker "):  # importing Taichi prints its banner first
            line = parent.stdout.readline()
            assert line, "the parent ended before its worker answered"
        worker = int(line.split()[1])
        assert _alive(worker)
        parent.send_signal(signal.SIGKILL)  # no chance to shut the pool down
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(worker), f"pool worker {worker} still runs after its parent was killed"
    finally:
        parent.kill()
