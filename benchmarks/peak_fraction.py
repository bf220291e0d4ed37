"""Simulator throughput as a fraction of the machine's measured multiply-add rate.

Usage: ``PYTHONPATH=. python benchmarks/peak_fraction.py [--steps 1000] [--repeat 3]
[--sizes 540 19440] [--fma-peak PATH]``

Prints, in one process: the yardstick, ``measure()`` of ``../shared/tools/fma_peak.py`` (the
double-precision multiply-add rate on all of Numba's threads, flop/s); and for each batch size B
the trajectory-steps per second of the kernels users wait on, counted at
:data:`FLOPS_PER_STEP` useful flops per RK4 step of the model, as a fraction of it:

- ``simulate``: :func:`mmg.simulate_batch`, full trajectories (B, K + 1, 6) written into a
  fresh array, as a plain call does (at B = 19,440 that array is 0.9 GB, and the operating
  system's page faults as it is first written cost a share of the time);
- ``simulate, out=``: the same into one array allocated and written once before (``out=``),
  the kernel's own rate;
- ``moments``: :func:`mmg.integrate.segment_moments`, the objective's kernel (no trajectories:
  moments of the observables accumulated per lane), B lanes = 20 candidates x B / 20 segments.

The fraction compares across machines (one with AVX-512, one without) where an absolute rate
alone does not. The yardstick is measured before and after the kernels; both are printed, and
the larger one is used (a busy machine lowers both).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType

import numba
import numpy as np

from benchmarks.machine import cpu_name, has_avx512
from benchmarks.throughput import workload
from mmg import efd_parameters, simulate_batch
from mmg.integrate import Segments, segment_moments

#: useful floating-point operations per RK4 step of one trajectory (four right-hand sides of
#: the paper's equations, about 950-1,000 in an operation count)
FLOPS_PER_STEP = 1000.0
#: candidates per population in the moments workload
CANDIDATES = 20


def load_fma_peak(path: str | None) -> ModuleType:
    """The shared yardstick module: ``--fma-peak``, ``$MMG_FMA_PEAK`` or ../shared/tools."""
    candidates = [path, os.environ.get("MMG_FMA_PEAK")]
    here = Path(__file__).resolve().parents[1]
    candidates += [str(here.parent / "shared" / "tools" / "fma_peak.py")]
    for c in candidates:
        if c and Path(c).is_file():
            spec = importlib.util.spec_from_file_location("fma_peak", c)
            assert spec is not None and spec.loader is not None
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module
    sys.exit(
        "error: fma_peak.py not found (looked at --fma-peak, $MMG_FMA_PEAK and "
        f"{candidates[-1]}); pass --fma-peak PATH"
    )


def simulate_rate(B: int, K: int, repeat: int, reuse: bool = False) -> float:
    """Median trajectory-steps/s of simulate_batch over ``repeat`` runs: each into a fresh
    states array, or (``reuse``) all into one array written once beforehand."""
    x0, u, w, theta = workload(B, K)
    simulate_batch(x0[:2], u[:2, :10], w[:2, :10], theta[:2])  # load / compile
    out = None
    if reuse:
        out = np.empty((B, K + 1, 6))
        out.fill(0.0)  # its pages are in memory before the first timed run
    rates = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = simulate_batch(x0, u, w, theta, out=out)
        rates.append(B * K / (time.perf_counter() - t0))
        del res
    return statistics.median(rates)


def moments_workload(B: int, K: int) -> tuple[Segments, np.ndarray]:
    """The moments benchmark's segments (B / CANDIDATES of K steps) and CANDIDATES parameter
    vectors (also timed part by part in ``kernel_parts.py``)."""
    S = max(1, B // CANDIDATES)
    x0, u, w, theta = workload(max(S, CANDIDATES), K, seed=1)
    ref = np.zeros((S, K + 1, 7))
    seg = Segments(x0[:S], u[:S], w[:S], np.full(S, K), ref, np.zeros((S, 7)))
    return seg, theta[:CANDIDATES]


def moments_rate(B: int, K: int, repeat: int) -> float:
    """Median trajectory-steps/s of segment_moments: CANDIDATES x (B / CANDIDATES) lanes."""
    seg, cand = moments_workload(B, K)
    S = seg.x0.shape[0]
    x0, u, w, ref = seg.x0, seg.u, seg.w, seg.ref
    small = Segments(x0[:1], u[:1, :10], w[:1, :10], np.array([10]), ref[:1, :11], np.zeros((1, 7)))
    segment_moments(small, cand[:2])  # load / compile
    rates = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        segment_moments(seg, cand)
        rates.append(CANDIDATES * S * K / (time.perf_counter() - t0))
    return statistics.median(rates)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sizes", type=int, nargs="+", default=[540, 19440])
    ap.add_argument("--fma-peak", default=None, help="path of fma_peak.py")
    args = ap.parse_args(argv)

    fma = load_fma_peak(args.fma_peak)
    threads = numba.get_num_threads()
    avx = "with" if has_avx512() else "without"
    print(f"{cpu_name()} ({avx} AVX-512), {threads} Numba threads, {args.steps} steps")
    peak_before = float(fma.measure())
    efd_parameters()
    rows = []
    for B in args.sizes:
        rates = {
            "simulate": simulate_rate(B, args.steps, args.repeat),
            "simulate, out=": simulate_rate(B, args.steps, args.repeat, reuse=True),
            "moments": moments_rate(B, args.steps, args.repeat),
        }
        rows.append((B, rates))
    peak_after = float(fma.measure())
    peak = max(peak_before, peak_after)
    print(
        f"yardstick (fma_peak.measure): {peak_before / 1e9:.1f} GFLOP/s before, "
        f"{peak_after / 1e9:.1f} after; used {peak / 1e9:.1f}"
    )
    print(f"{'B':>7} {'kernel':>15} {'traj-steps/s':>13} {'GFLOP/s':>8} {'of peak':>8}")
    for B, rates in rows:
        for name, rate in rates.items():
            flops = rate * FLOPS_PER_STEP
            print(f"{B:>7} {name:>15} {rate:>13.3g} {flops / 1e9:>8.2f} {flops / peak:>8.3f}")


if __name__ == "__main__":
    main()
