"""One Taichi runtime per process, initialised on first use.

Taichi keeps a single global runtime: it cannot be re-initialised once fields
exist, and it is not thread-safe. Every simulator goes through ``ensure_taichi``
so that the architecture is chosen once (CPU by default, CUDA when asked for or
when ``auto`` finds it) and the offline kernel cache is always on.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import taichi as ti

_lock = threading.Lock()
_arch_in_use: str | None = None

CACHE_ENV = "TI_OFFLINE_CACHE_FILE_PATH"


def kernel_cache_dir() -> Path:
    """Where compiled kernels are cached across processes (``$TI_OFFLINE_CACHE_FILE_PATH``)."""
    default = Path.home() / ".cache" / "pasta" / "ticache"
    return Path(os.environ.get(CACHE_ENV) or default)


def cache_argument() -> dict[str, str]:
    """``ti.init``'s ``offline_cache_file_path``, unless ``$TI_OFFLINE_CACHE_FILE_PATH`` names it already.

    Taichi reads that variable itself and warns when an init argument overrides it.
    """
    return {} if os.environ.get(CACHE_ENV) else {"offline_cache_file_path": str(kernel_cache_dir())}


THREADS_ENV = "PASTA_TAICHI_THREADS"


def cpu_threads() -> int:
    """Taichi's CPU threads: ``$PASTA_TAICHI_THREADS`` (set by process pools), else every core."""
    value = os.environ.get(THREADS_ENV)
    if value is None:
        return os.cpu_count() or 1
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f"{THREADS_ENV} must be a positive integer, got {value!r}")
    return int(value)


def _cuda_available() -> bool:
    try:
        import torch

        return torch.cuda.is_available()
    except ImportError:  # pragma: no cover - torch is a dependency
        return False


def ensure_taichi(arch: str = "cpu") -> str:
    """Initialise Taichi once for this process and return the architecture in use.

    ``arch`` is ``"cpu"``, ``"cuda"`` or ``"auto"`` (CUDA when torch sees a GPU).
    A later call asking for a different architecture raises, since Taichi cannot
    switch runtimes while fields are alive.
    """
    global _arch_in_use
    if arch not in ("cpu", "cuda", "auto"):
        raise ValueError(f"arch must be 'cpu', 'cuda' or 'auto', got {arch!r}")
    wanted = ("cuda" if _cuda_available() else "cpu") if arch == "auto" else arch
    with _lock:
        if _arch_in_use is not None:
            if wanted != _arch_in_use and arch != "auto":
                raise RuntimeError(f"Taichi already runs on {_arch_in_use!r}; cannot switch to {wanted!r}")
            return _arch_in_use
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError(
                "Taichi must be initialised in a process's main thread; run simulation work in the "
                "main thread or a process pool, not a thread pool"
            )
        cache = kernel_cache_dir()
        cache.mkdir(parents=True, exist_ok=True)
        ti.init(
            arch=ti.cuda if wanted == "cuda" else ti.cpu,
            default_fp=ti.f32,
            default_ip=ti.i32,
            offline_cache=True,
            **cache_argument(),
            cpu_max_num_threads=cpu_threads(),
            log_level=ti.ERROR,
        )
        _arch_in_use = wanted
        return wanted
