"""Simulator throughput: trajectory-steps per second of the batched kernel and of plain Python.

Usage: ``python benchmarks/throughput.py [--steps 1000] [--repeat 3] [--sizes 20 540 19440]``

Prints, for each batch size B, the median over repeats of B x steps / wall time of
:func:`mmg.simulate_batch` (random controls, wind and EFD-perturbed parameters, every lane its own
parameter vector); the same figure for one trajectory integrated by the very same source run as
plain Python (``NUMBA_DISABLE_JIT=1``, in a subprocess); their ratios; and the start-up time of a
fresh process whose kernel is already in the on-disk cache.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numba
import numpy as np

from mmg import bounds, efd_parameters, simulate_batch


def workload(B: int, K: int, seed: int = 0) -> tuple[np.ndarray, ...]:
    """x0 (B, 6), controls and wind (B, K, 2), parameters (B, 57): a population-like batch."""
    rng = np.random.default_rng(seed)
    x0 = np.zeros((B, 6))
    x0[:, 1] = rng.uniform(0.0, 0.3, B)
    x0[:, 4] = rng.uniform(-np.pi, np.pi, B)
    t = np.arange(K) * 0.1
    u = np.empty((B, K, 2))
    u[..., 0] = 0.6 * np.sin(2 * np.pi * t / rng.uniform(20, 60, (B, 1)))
    u[..., 1] = np.where(np.sin(2 * np.pi * t / rng.uniform(30, 90, (B, 1))) > -0.3, 10.0, -10.0)
    w = np.empty((B, K, 2))
    w[..., 0] = rng.uniform(0.0, 3.0, (B, 1))
    w[..., 1] = rng.uniform(-np.pi, np.pi, (B, 1))
    lo, hi = bounds()
    theta = np.clip(efd_parameters().vector() * rng.uniform(0.8, 1.2, (B, 57)), lo, hi)
    return x0, u, w, theta


def batched_rate(B: int, K: int, repeat: int) -> tuple[float, float]:
    """(median traj-steps/s, fraction of lanes that diverged)."""
    x0, u, w, theta = workload(B, K)
    simulate_batch(x0[:2], u[:2, :10], w[:2, :10], theta[:2])  # load / compile
    rates = []
    diverged = 0.0
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = simulate_batch(x0, u, w, theta)
        rates.append(B * K / (time.perf_counter() - t0))
        diverged = float(res.diverged.mean())
        del res
    return statistics.median(rates), diverged


_PYTHON_LOOP = """
import json, time, numpy as np
from benchmarks.throughput import workload
from mmg import simulate_batch
x0, u, w, theta = workload(1, {K})
t0 = time.perf_counter()
simulate_batch(x0, u, w, theta, chunk=1)
print(json.dumps({{"rate": {K} / (time.perf_counter() - t0)}}))
"""

_STARTUP = """
import time
t0 = time.perf_counter()
import numpy as np
from mmg import efd_parameters, simulate
simulate(np.zeros((1, 6)), np.zeros((1, 10, 2)), np.zeros((1, 10, 2)), efd_parameters())
print(time.perf_counter() - t0)
"""


def python_rate(K: int) -> float:
    """Trajectory-steps/s of one trajectory through the same source as plain Python."""
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run(
        [sys.executable, "-c", _PYTHON_LOOP.format(K=K)],
        env=env,
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(json.loads(out.stdout.strip().splitlines()[-1])["rate"])


def startup_seconds() -> float:
    out = subprocess.run(
        [sys.executable, "-c", _STARTUP], capture_output=True, text=True, check=True
    )
    return float(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 540, 19440])
    ap.add_argument("--python-steps", type=int, default=200)
    args = ap.parse_args(argv)

    print(f"threads: {numba.get_num_threads()}   steps per trajectory: {args.steps}")
    py = python_rate(args.python_steps)
    print(f"plain Python, one trajectory ({args.python_steps} steps): {py:.3g} traj-steps/s")
    print(f"{'B':>7} {'traj-steps/s':>14} {'x Python':>10} {'diverged':>9}")
    for B in args.sizes:
        rate, div = batched_rate(B, args.steps, args.repeat)
        print(f"{B:>7} {rate:>14.3g} {rate / py:>10.0f} {div:>9.1%}")
    print(f"fresh process, cached kernel: import + first simulate {startup_seconds():.2f} s")


if __name__ == "__main__":
    main()
