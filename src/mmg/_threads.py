"""Run a compiled kernel's share functions on several threads of this process.

The entry points of a generated kernel module split their work among ``n_threads`` threads:
``simulate_lanes`` and ``moments_lanes`` their chunks of lanes, ``rhs_rows`` and ``effect_rows``
their blocks of points; thread t takes chunks (blocks) t, t + n_threads, ... The share of one
thread is a compiled function that releases the GIL (``nogil``), called here from a pool of
Python threads. *Rejected*: a ``numba.prange`` loop over the threads, which made Numba type and
lower each entry point's body a second time for its parallel region (the base model's
``simulate`` and ``moments`` 27-28 s with it, 16-19 s without; the library's accelerations 48 s
with it, 22 s without) for the same work.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

_lock = threading.Lock()
_pool: ThreadPoolExecutor | None = None
_pool_pid = -1
_pool_size = 0


def _executor(workers: int) -> ThreadPoolExecutor:
    """This process's pool with at least ``workers`` threads (a forked child makes its own: the
    parent's threads do not survive a fork)."""
    global _pool, _pool_pid, _pool_size
    with _lock:
        if _pool is None or _pool_pid != os.getpid() or _pool_size < workers:
            old = _pool if _pool_pid == os.getpid() else None
            _pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="mmg-kernel")
            _pool_pid, _pool_size = os.getpid(), workers
            if old is not None:
                old.shutdown(wait=False)
        return _pool


def run_threads(share: Callable[..., Any], n_threads: int, args: tuple[Any, ...]) -> None:
    """Call ``share(t, *args)`` for t = 0 .. n_threads - 1 at once: t = 0 in the calling thread,
    the others in the pool; returns when all have ended, re-raising a share's error (a pool
    thread's, in the order of t, before the calling thread's own)."""
    if n_threads <= 1:
        share(0, *args)
        return
    pool = _executor(n_threads - 1)
    futures = [pool.submit(share, t, *args) for t in range(1, n_threads)]
    try:
        share(0, *args)
    finally:
        for f in futures:
            f.result()
