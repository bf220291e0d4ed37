"""Population evaluation, in this process or farmed out to local worker processes.

An evaluator is a callable ``thetas (C, n) -> f (C,)``. :class:`ProcessPool` splits the population
into one contiguous chunk per worker; each worker holds its own copy of the objective (its
recordings, split into subsequences once) and evaluates its chunk as one batched simulator call
(chunk x subsequences lanes). Lanes are independent, so the result does not depend on the number of
workers or the split (tested).

Failure is a value: a candidate whose simulation diverges already costs the objective's penalty;
a chunk whose evaluation raises (a crashed worker, an unexpected error) is evaluated again
candidate by candidate in this process, and a candidate that still fails gets
:attr:`sweep.data.objective.Objective.max_penalty`. A generation is never lost.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from mmg.orphans import exit_with_parent
from sweep.data.objective import Objective

FloatArray = NDArray[np.float64]
log = logging.getLogger(__name__)


def _max_threads() -> int:
    return int(getattr(numba.config, "NUMBA_NUM_THREADS", 1))


def available_cores() -> int:
    """CPU cores this process may use (affinity-aware)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def safe_evaluate(objective: Objective, thetas: FloatArray) -> FloatArray:
    """Evaluate, falling back to one candidate at a time and a penalty for any that raise."""
    try:
        return objective.evaluate(thetas)
    except Exception:  # failure is a value here, logged
        log.exception("population evaluation failed; retrying candidate by candidate")
    out = np.empty(len(thetas))
    for i, theta in enumerate(thetas):
        try:
            out[i] = objective.evaluate(theta[None])[0]
        except Exception:
            log.exception("candidate %d failed; it gets the maximum penalty", i)
            out[i] = objective.max_penalty
    return out


class InProcess:
    """Evaluate in this process; the kernel uses ``threads`` Numba threads (default: all)."""

    def __init__(self, objective: Objective, threads: int | None = None) -> None:
        self.objective = objective
        if threads is not None:
            numba.set_num_threads(max(1, min(threads, _max_threads())))

    def __call__(self, thetas: FloatArray) -> FloatArray:
        """Objective values (C,) of the candidates ``thetas`` (C, n)."""
        return safe_evaluate(self.objective, np.asarray(thetas, dtype=np.float64))

    @property
    def sim_seconds(self) -> float:
        """CPU time spent in the objective (simulator) so far, all of the kernel's threads."""
        return self.objective.cpu_seconds

    def close(self) -> None:
        """Nothing to release."""

    def __enter__(self) -> InProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_WORKER_OBJECTIVE: Objective | None = None


def _init_worker(objective: Objective, threads: int, parent: int) -> None:
    global _WORKER_OBJECTIVE
    exit_with_parent(parent)
    numba.set_num_threads(max(1, min(threads, _max_threads())))
    _WORKER_OBJECTIVE = objective


def _work(thetas: FloatArray) -> FloatArray:
    assert _WORKER_OBJECTIVE is not None, "worker not initialised"
    return safe_evaluate(_WORKER_OBJECTIVE, thetas)


class ProcessPool:
    """``workers`` local processes (spawned: no state leaks in), ``threads`` threads each."""

    def __init__(self, objective: Objective, workers: int | None = None, threads: int = 1) -> None:
        self.objective = objective
        self.workers = workers or available_cores()
        self.threads = threads
        self._pool = self._start()

    def _start(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=mp.get_context("spawn"),
            initializer=_init_worker,
            initargs=(self.objective, self.threads, os.getpid()),
        )

    def __call__(self, thetas: FloatArray) -> FloatArray:
        """Objective values (C,) of the candidates ``thetas`` (C, n), one chunk per worker.

        A chunk whose worker fails is evaluated again here and the pool is restarted.
        """
        X = np.asarray(thetas, dtype=np.float64)
        chunks = [c for c in np.array_split(X, min(self.workers, len(X))) if len(c)]
        futures = [self._pool.submit(_work, c) for c in chunks]
        results: list[FloatArray] = []
        broken = False
        for chunk, fut in zip(chunks, futures, strict=True):
            try:
                results.append(np.asarray(fut.result(), dtype=np.float64))
            except Exception:  # a dead worker must not lose the generation
                log.exception("worker failed on a chunk of %d candidates", len(chunk))
                broken = True
                results.append(safe_evaluate(self.objective, chunk))
        if broken:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._start()
        return np.concatenate(results)

    def close(self) -> None:
        """Stop the worker processes (waits for them; pending chunks are cancelled)."""
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ProcessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_evaluator(
    objective: Objective, workers: int | None = None, threads: int | None = None
) -> InProcess | ProcessPool:
    """``workers`` = 0: in this process (Numba threads = ``threads`` or all cores);
    ``workers`` = None: one worker process per available core; otherwise that many workers."""
    if workers == 0:
        return InProcess(objective, threads)
    return ProcessPool(objective, workers, threads or 1)


__all__: Sequence[Any] = ["InProcess", "ProcessPool", "available_cores", "make_evaluator"]
