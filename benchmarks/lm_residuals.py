"""What a Levenberg-Marquardt Jacobian batch costs beside its simulations.

Usage: ``PYTHONPATH=. python benchmarks/lm_residuals.py [--train R] [--candidates 58]
[--repeat 3] [--params results/best_params.json]`` (recordings from $MMG_DATA_DIR, else
../shared/data/frt-ds-esso).

Times :func:`sweep.identification.polish.residual_vectors` (simulation of every candidate on
every 100-s window of the training recordings, then the standardised residuals) and
:func:`mmg.integrate.simulate_batch` alone on the same lanes, and prints both and their ratio:
the share of a refinement's time that is not the simulator. The diagnosis spends most of its
time in such batches (one per Jacobian, one per damping trial).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mmg import Parameters
from sweep.data.datasets import load_split
from sweep.data.objective import Objective
from sweep.diagnose.windows import cut_windows
from sweep.identification.polish import MAX_LANES, residual_vectors, simulate_subsequences


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", default="R")
    ap.add_argument("--candidates", type=int, default=58, help="57 probes + the point")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--params", default="results/best_params.json")
    args = ap.parse_args()
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    os.environ.setdefault("MMG_DATA_DIR", str(default_root))
    windows = cut_windows(list(load_split(args.train).load().values()))
    obj = Objective(windows, "J2")
    p = Parameters.load_json(args.params).vector()
    rng = np.random.default_rng(0)
    thetas = p[None] * (1.0 + 1e-3 * rng.standard_normal((args.candidates, p.size)))
    per = max(1, MAX_LANES // obj.data.segments.u.shape[0])

    def simulate_only() -> None:  # the same batches residual_vectors simulates
        for lo in range(0, len(thetas), per):
            simulate_subsequences(obj, thetas[lo : lo + per])

    def best(f: Callable[[], object]) -> float:
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            f()
            times.append(time.perf_counter() - t0)
        return min(times)

    residual_vectors(obj, thetas[:2])  # compile / load from the cache
    simulate_only()
    t_res = best(lambda: residual_vectors(obj, thetas))
    t_sim = best(simulate_only)
    steps = int(obj.data.segments.n_steps.sum()) * len(thetas)
    n = len(windows)
    print(f"Train-{args.train}: {n} windows, {args.candidates} candidates, {steps:,} steps")
    print(f"residual_vectors {t_res:.3f} s; simulate_batch alone {t_sim:.3f} s")
    print(f"ratio {t_res / t_sim:.2f} (1.00: nothing but the simulator)")


if __name__ == "__main__":
    main()
