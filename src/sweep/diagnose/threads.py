"""Independent pieces of a diagnosis's work on the threads of this process.

The null distributions are computed on noise-only copies of the windows, one copy after
another; each copy's work (the kernels' right-hand sides, the Savitzky-Golay derivatives, the
least squares) releases the GIL for most of its time but runs on one core: linear algebra is
held to one BLAS thread (:func:`sweep.diagnose.run.diagnose`). :func:`map_threads` runs such
copies side by side, one per core. Each copy is computed exactly as alone (its random draws
are made before, in order), so the results do not depend on the number of threads. Where a
copy's figures come out of one matrix product with others' (the columns of a held-out fit),
the copies are split into a fixed number of parts (:data:`PARTS`), not one per core.

Nothing run here may call a function compiled with Numba's ``parallel=True`` (the residual
rows of :func:`sweep.identification.polish.residual_vectors`): where neither OpenMP nor TBB is
installed, Numba's workqueue layer aborts the process on a second concurrent call. The kernels'
own threads (:mod:`mmg._threads`) are plain Python threads and may be shared.

*Rejected*: sharing :mod:`mmg._threads`'s pool, whose threads run the kernels' shares: a copy
that waits there for its own kernel's share could hold the thread that share needs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from sweep.identification.workers import available_cores

#: the parts that copies whose figures depend, to rounding, on the copies computed with them
#: (the columns of one matrix product) are split into, whatever the number of cores: the
#: same figures on any machine
PARTS = 2

T = TypeVar("T")
R = TypeVar("R")


def column_parts(count: int) -> list[NDArray[np.int64]]:
    """The indices 0 .. count - 1 in :data:`PARTS` consecutive parts (none empty)."""
    return [p for p in np.array_split(np.arange(count), PARTS) if p.size]


def map_threads(func: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> list[R]:
    """[func(item) for item in items], up to ``threads`` (default: this process's cores) at a
    time, in the order of ``items``; an error of ``func`` is raised here (the first item's
    that failed, after the others have ended)."""
    work = list(items)
    n = min(len(work), threads if threads is not None else available_cores())
    if n <= 1:
        return [func(item) for item in work]
    with ThreadPoolExecutor(max_workers=n, thread_name_prefix="diagnose") as pool:
        return list(pool.map(func, work))


__all__ = ["PARTS", "column_parts", "map_threads"]
