"""Worker processes that end with the process that started them.

A spawned worker of a ``ProcessPoolExecutor`` waits on its call queue; when the process that
started it is killed (``kill``, an out-of-memory kill, a lost terminal), nothing tells it, and it
stays, idle, holding its memory (a diagnosis killed while its kernels compiled left four
workers of 430 MB each for hours). :func:`exit_with_parent`, a pool's initializer, starts a
thread in the worker that ends it once its parent is gone.
"""

from __future__ import annotations

import os
import threading
import time

#: how often a worker looks for its parent [s]
PERIOD = 1.0


def exit_with_parent(parent: int, period: float = PERIOD) -> None:
    """Start a daemon thread that ends this process (exit status 1) once ``parent``, the pid
    of the process that started it, is no longer its parent (the orphan was handed to another
    process, usually init)."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
