"""Wall time of the intervals of one identified model, per training set and objective.

Usage::

    NUMBA_NUM_THREADS=1 python benchmarks/uncertainty_cost.py [--params results/best_params.json]
        [--sets R,TR,TZR] [--objectives J1,J2]

For each training set and objective: the seconds of
:func:`sweep.identification.uncertainty.parameter_uncertainty` (the Jacobian's 2 n + 1
simulations of every subsequence, then the covariance), the subsequences and the share of the
parameters called determined. Each is run twice and the second time printed (the first also
loads the kernels from the cache). ``NUMBA_NUM_THREADS=1`` measures one core (the budget is 30 s
on one core for Train-R).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from sweep.data.datasets import load_split
from sweep.data.parameters import load_parameters
from sweep.evaluate import effects_of
from sweep.identification.uncertainty import parameter_uncertainty


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--params", default="results/best_params.json")
    ap.add_argument("--sets", default="R,TR,TZR")
    ap.add_argument("--objectives", default="J1,J2")
    args = ap.parse_args(argv)
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    root = os.environ.get("MMG_DATA_DIR", str(default_root))
    params = load_parameters(args.params)
    threads = os.environ.get("NUMBA_NUM_THREADS", "all")
    print(f"{args.params}, numba threads: {threads}")
    for name in args.sets.split(","):
        recs = list(load_split(name).load(root).values())
        for J in args.objectives.split(","):
            seconds = []
            for _ in range(2):
                t0 = time.perf_counter()
                u = parameter_uncertainty(params, recs, J, effects_of(params))
                seconds.append(time.perf_counter() - t0)
            print(
                f"Train-{name} {J}: {seconds[-1]:.1f} s (first call {seconds[0]:.1f} s), "
                f"{u.meta['subsequences']} subsequences, {u.counts['determined']} of "
                f"{len(u.names)} determined",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
