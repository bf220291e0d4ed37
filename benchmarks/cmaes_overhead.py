"""pycma's overhead per generation, and the population-20 phase of an identification.

Usage: ``PYTHONPATH=. python benchmarks/cmaes_overhead.py [--evaluations 1000] [--train R]``

Prints, in one process:

- pycma's ask/tell per generation at population 20 in 57 dimensions on a cheap quadratic (no
  simulator), with BLAS on its default threads and on one thread (``threadpoolctl``), and
  :func:`sweep.identification.cmaes.optimise`'s (which takes one thread);
- the evaluations per second of :func:`sweep.identify.identify` at population 20 (the first
  restart, in this process, Numba's threads as set by ``NUMBA_NUM_THREADS``).

The covariance decomposition of a 57 x 57 matrix is too small for BLAS threads; with the cores
busy (another job, the kernel's threads) waking them costs far more than the work. Run it with
other load on the cores to see the difference; on idle cores the two are close.
"""

from __future__ import annotations

import argparse
import time
import warnings

import cma
import numpy as np
from threadpoolctl import threadpool_limits

from mmg import bounds, efd_parameters
from sweep.data.datasets import data_root, load_split
from sweep.identification.cmaes import Box, Settings, optimise
from sweep.identify import identify

GENERATIONS = 300


def _raw_ms_per_generation(generations: int = GENERATIONS) -> float:
    es = cma.CMAEvolutionStrategy(
        np.full(57, 0.5), 0.03, {"popsize": 20, "seed": 1, "verbose": -9, "bounds": [0, 1]}
    )
    t = time.perf_counter()
    for _ in range(generations):
        Y = np.asarray(es.ask())
        es.tell(list(Y), ((Y - 0.4) ** 2).sum(1).tolist())
    return 1000.0 * (time.perf_counter() - t) / generations


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--evaluations", type=int, default=1000)
    ap.add_argument("--train", default="R", help="training split of the identification")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")

    default = _raw_ms_per_generation()
    with threadpool_limits(limits=1, user_api="blas"):
        one = _raw_ms_per_generation()
    lo, hi = bounds()
    x0 = efd_parameters().vector()
    t = time.perf_counter()
    res = optimise(
        lambda th: ((th - x0) ** 2).sum(1),
        Box(lo, hi),
        x0,
        Settings(seed=0, max_evaluations=20 * GENERATIONS, max_restarts=1),
    )
    ours = 1000.0 * (time.perf_counter() - t) / max(1, res.evaluations // 20)
    print("pycma ask/tell per generation, population 20, 57 dimensions (cheap objective):")
    print(f"  BLAS default threads {default:7.2f} ms")
    print(f"  BLAS one thread      {one:7.2f} ms   ({default / one:.1f} x less)")
    print(f"  optimise (one)       {ours:7.2f} ms")

    recs = list(load_split(args.train).load(data_root()).values())
    identify(recs, settings=Settings(seed=0, max_evaluations=40, max_restarts=1), workers=0)
    t = time.perf_counter()
    r, _ = identify(
        recs,
        settings=Settings(seed=0, max_evaluations=args.evaluations, max_restarts=1),
        workers=0,
    )
    dt = time.perf_counter() - t
    print(
        f"identification on Train-{args.train}, population 20: {r.evaluations} evaluations in "
        f"{dt:.2f} s = {r.evaluations / dt:.0f} evaluations/s (best J {r.f:.2f})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
