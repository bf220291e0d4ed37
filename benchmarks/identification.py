"""Identification throughput on Train-R: evaluations per second and time outside the simulator.

Usage: ``python benchmarks/identification.py [--objective J2] [--seconds 20]``
(recordings from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso).

For population 20 and 720, CMA-ES generations run at a fixed population for about ``--seconds``
each, evaluated in process (all cores to the kernel) and by a pool of worker processes (one per
core). Printed per case: evaluations/s, trajectory-steps/s, and the fraction of wall time spent
outside the simulator kernel (pycma's ask/tell, moments-to-J algebra, transfer to workers,
bookkeeping). The goal is below 10 % at population 720.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import mmg.integrate as integrate
from mmg import bounds, efd_parameters
from sweep.data.datasets import load_split
from sweep.data.objective import Objective
from sweep.identification.cmaes import Box, Settings, optimise
from sweep.identification.workers import InProcess, ProcessPool, available_cores


class KernelTimer:
    """Wraps mmg.integrate.segment_moments to add up the time spent in the simulator."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self._inner = integrate.segment_moments

    def __enter__(self) -> KernelTimer:
        def timed(*args, **kwargs):  # type: ignore[no-untyped-def]
            t0 = time.perf_counter()
            out = self._inner(*args, **kwargs)
            self.seconds += time.perf_counter() - t0
            return out

        integrate.segment_moments = timed
        import sweep.data.objective as objective_module

        objective_module.segment_moments = timed  # the name the objective calls
        return self

    def __exit__(self, *exc: object) -> None:
        import sweep.data.objective as objective_module

        integrate.segment_moments = self._inner
        objective_module.segment_moments = self._inner


def run_case(obj: Objective, popsize: int, mode: str, seconds: float) -> dict[str, float]:
    lo, hi = bounds()
    box = Box(lo, hi)
    steps_per_eval = float(obj.data.segments.n_steps.sum())
    gens = max(2, int(seconds * 3.0e6 / (popsize * steps_per_eval)))
    settings = Settings(
        seed=0,
        max_evaluations=popsize * (gens + 1),
        popsize_start=popsize,
        popsize_max=popsize,
        sigma0=0.05,
        tolfun=0.0,
        tolx=0.0,
    )
    evaluator = InProcess(obj) if mode == "in-process" else ProcessPool(obj, available_cores())
    try:
        evaluator(np.tile(efd_parameters().vector(), (popsize, 1)))  # warm up (workers, caches)
        with KernelTimer() as timer:
            t0 = time.perf_counter()
            res = optimise(evaluator, box, efd_parameters().vector(), settings)
            wall = time.perf_counter() - t0
    finally:
        evaluator.close()
    evals = res.evaluations
    out = {"evals_per_s": evals / wall, "steps_per_s": evals * steps_per_eval / wall}
    # In the worker pool the kernel runs in other processes: the time inside it is not seen here.
    out["outside"] = 1.0 - timer.seconds / wall if mode == "in-process" else float("nan")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objective", default="J2")
    ap.add_argument("--seconds", type=float, default=20.0)
    args = ap.parse_args()
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    root = os.environ.get("MMG_DATA_DIR", str(default_root))
    train = load_split("R").load(root)
    obj = Objective(list(train.values()), args.objective)
    print(
        f"Train-R: {obj.n_segments} subsequences, {int(obj.data.segments.n_steps.sum())} "
        f"steps per evaluation; {available_cores()} cores"
    )
    print(f"{'pop':>5} {'mode':>11} {'evals/s':>9} {'traj-steps/s':>13} {'outside kernel':>15}")
    for popsize in (20, 720):
        for mode in ("in-process", "workers"):
            r = run_case(obj, popsize, mode, args.seconds)
            outside = "-" if np.isnan(r["outside"]) else f"{r['outside']:.1%}"
            print(
                f"{popsize:>5} {mode:>11} {r['evals_per_s']:>9.0f} {r['steps_per_s']:>13.3g} "
                f"{outside:>15}"
            )


if __name__ == "__main__":
    main()
