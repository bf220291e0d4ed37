"""What the selection of shape groups costs on a training split, and what a shape effect costs
the simulator.

Usage: ``PYTHONPATH=. python benchmarks/shapes_cost.py [--train R] [--params
results/best_params.json] [--null-draws 10] [--throughput-only | --selection-only]``
(recordings from $MMG_DATA_DIR, else ../shared/data/frt-ds-esso).

Prints (1) the simulator's rate (trajectory-steps/s of :func:`mmg.simulate_batch`, the
workload of ``benchmarks/throughput.py``, 540 lanes of 1,000 steps) for the base model, a
shape effect of three groups of eight basis functions, the candidate effect of the
selection (every default candidate group) and its probe (what the selection simulates),
alternating them over several rounds; (2) on the
training windows: the base's linearised fold fits (:class:`sweep.diagnose.linearised.Linearised`),
the columns of every candidate basis function (:class:`sweep.diagnose.shapes.ShapeColumns`:
simulation, then the fold matrices), their memory, one selection on the base's residuals with
what it chose, and the null statistic per noise-only draw. Kernels not in the cache are
compiled first (the candidate effect's take minutes), and that time is printed apart.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks.throughput import workload
from mmg import Effect, Parameters, get_effect, simulate_batch
from mmg.shapes import probe_effect, shape_effect
from sweep.data.datasets import load_split
from sweep.data.parameters import load_parameters
from sweep.diagnose.discover import null_sets
from sweep.diagnose.floor import calibrated_noise
from sweep.diagnose.linearised import Linearised
from sweep.diagnose.scoring import n_effective
from sweep.diagnose.settings import PRIOR_WEIGHT
from sweep.diagnose.shapes import ShapeColumns, candidate_groups
from sweep.diagnose.windows import cut_windows, split_windows

#: a shape effect of the size a joint fit carries: three groups of eight basis functions
SMALL = "shape:Y~beta[-0.5:0.5]/8+N~rp[-0.8:0.8]/8+X~U[0:1.2]/8"


def throughput(effects: dict[str, tuple[Effect, ...]], rounds: int = 7) -> None:
    """Median rate of each effect set and its slowdown against the base, alternating."""
    B, K = 540, 1000
    x0, u, w, theta = workload(B, K)
    rng = np.random.default_rng(1)
    cases = []
    for label, effs in effects.items():
        k = sum(len(e.params) for e in effs)
        th = np.hstack([theta, rng.normal(0.0, 1e-3, (B, k))])
        t0 = time.perf_counter()
        simulate_batch(x0[:2], u[:2, :10], w[:2, :10], th[:2], effects=effs)
        print(f"load/compile {label}: {time.perf_counter() - t0:.1f} s", flush=True)
        cases.append((label, effs, th))
    rates: dict[str, list[float]] = {label: [] for label in effects}
    for _ in range(rounds):
        for label, effs, th in cases:
            t0 = time.perf_counter()
            simulate_batch(x0, u, w, th, effects=effs)
            rates[label].append(B * K / (time.perf_counter() - t0))
    base = rates[cases[0][0]]
    for label, _, _ in cases:
        r = rates[label]
        slow = statistics.median(a / b for a, b in zip(base, r, strict=True))
        print(f"{statistics.median(r):10.3g} traj-steps/s  x{slow:5.2f} slower  {label}")


def selection(params: Parameters, train: str, draws: int) -> None:
    """The costs of the selection on the training split's windows."""
    windows = cut_windows(list(load_split(train).load().values()))
    fit_w, held_w = split_windows(windows)
    pos = {id(w): i for i, w in enumerate(windows)}
    folds = ([pos[id(w)] for w in fit_w], [pos[id(w)] for w in held_w])
    n_eff = n_effective(windows, "J2")
    t0 = time.perf_counter()
    lin = Linearised(params, windows, folds, (), prior_weight=PRIOR_WEIGHT)
    print(f"{len(windows)} windows; base Jacobian and folds: {time.perf_counter() - t0:.1f} s")
    groups = candidate_groups(windows, params)
    cols = ShapeColumns(lin, groups)
    S, M, T = cols.lib.shape
    print(
        f"columns: {T} ({len(cols.units)} units) x {S} windows x {M} residuals, "
        f"{cols.lib.nbytes / 2**30:.2f} GB; simulation {cols.simulation_seconds:.1f} s, "
        f"all {cols.seconds:.1f} s"
    )
    t0 = time.perf_counter()
    sel = cols.select(lin.residuals(windows), n_eff)
    print(f"selection: {time.perf_counter() - t0:.1f} s; dBIC {sel.dbic:.1f}")
    for g, gain, edf, kap in zip(sel.groups, sel.heldout_gain, sel.edf, sel.kappas, strict=True):
        print(f"  {g.text}: held-out gain {gain:.3f}, edf {edf:.1f}, kappa {kap:g}")
    if draws > 0:
        rng = np.random.default_rng(11)
        noise = calibrated_noise(windows, params, np.random.default_rng(7))
        t0 = time.perf_counter()
        R = np.stack([lin.residuals(r) for r in null_sets(params, windows, noise, rng, draws)], -1)
        t1 = time.perf_counter()
        null = cols.null_dbic(R, n_eff)
        t2 = time.perf_counter()
        print(
            f"null: {draws} draws simulated in {t1 - t0:.1f} s, statistic {(t2 - t1) / draws:.2f}"
            f" s per draw; dBIC min {null.min():.1f}, median {np.median(null):.1f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--train", default="R")
    ap.add_argument("--params", default="results/best_params.json")
    ap.add_argument("--null-draws", type=int, default=10)
    ap.add_argument("--throughput-only", action="store_true")
    ap.add_argument("--selection-only", action="store_true")
    args = ap.parse_args()
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    os.environ.setdefault("MMG_DATA_DIR", str(default_root))
    params = load_parameters(args.params)
    windows = cut_windows(list(load_split(args.train).load().values()))
    candidates = shape_effect(candidate_groups(windows, params))
    k = len(candidates.params)
    if not args.selection_only:
        throughput(
            {
                "base model": (),
                SMALL: (get_effect(SMALL),),
                f"the candidates ({k} coefficients)": (candidates,),
                "their probe (one basis function per lane)": (probe_effect(candidates.name),),
            }
        )
    if not args.throughput_only:
        selection(params, args.train, args.null_draws)


if __name__ == "__main__":
    main()
