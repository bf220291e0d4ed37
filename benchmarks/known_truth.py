"""Identification against a known truth.

Usage: ``python benchmarks/known_truth.py [--budget 10000] [--seed 0] [--spread 0.3]``

A "true" parameter vector is drawn around EFD (each parameter times U(1 - spread, 1 + spread),
clipped to the paper's domain). Synthetic recordings are simulated with it, driven by the real
controls and wind of the test runs (Test-R, Test-T, Test-Z, Test-B-S, Test-B-P), from their
recorded initial states. The job then starts from EFD, as on real data, and identifies the
parameters with J2 within the budget. Printed: J2 of EFD, of the identified vector and of the
truth (zero) on the synthetic data, the evaluations and wall time, and the relative parameter
errors of the identified vector (median and the share within 10 %).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from mmg import Parameters, bounds, efd_parameters, simulate
from sweep.data.datasets import load_split
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.identification.cmaes import Settings
from sweep.identify import identify


def synthetic_recordings(truth: Parameters, root: str) -> list[Recording]:
    """The test runs' inputs, states simulated with ``truth`` (whole runs, open loop)."""
    out = []
    for label, rec in load_split("paper").load(root).items():
        traj = simulate(rec.x[None, 0], rec.u[None, :-1], rec.w[None, :-1], truth)[0]
        out.append(Recording(f"synthetic_{label}", None, rec.t, traj, rec.u, rec.w))
    return out


def draw_truth(seed: int, spread: float) -> Parameters:
    rng = np.random.default_rng(seed)
    lo, hi = bounds()
    efd = efd_parameters().vector()
    theta = np.clip(efd * rng.uniform(1 - spread, 1 + spread, efd.size), lo, hi)
    return Parameters.from_vector(theta)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spread", type=float, default=0.3)
    ap.add_argument("--sigma0", type=float, default=0.03)
    args = ap.parse_args()
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    root = os.environ.get("MMG_DATA_DIR", str(default_root))
    truth = draw_truth(args.seed, args.spread)
    recs = synthetic_recordings(truth, root)
    obj = Objective(recs, "J2")
    J_efd, J_truth = obj.evaluate(np.stack([efd_parameters().vector(), truth.vector()]))
    t0 = time.perf_counter()
    settings = Settings(seed=args.seed, max_evaluations=args.budget, sigma0=args.sigma0)
    result, best = identify(recs, "J2", settings)
    wall = time.perf_counter() - t0
    rel = np.abs(best.vector() - truth.vector()) / np.abs(truth.vector())
    print(f"truth: EFD x U({1 - args.spread:.1f}, {1 + args.spread:.1f}), seed {args.seed}")
    print(f"J2 on the synthetic test runs: EFD {J_efd:.1f}   truth {J_truth:.2g}")
    print(
        f"identified: J2 {result.f:.1f} ({result.f / J_efd:.1%} of EFD) after "
        f"{result.evaluations} evaluations, {len(result.restarts)} restarts, {wall:.0f} s"
    )
    print(
        f"parameter error |theta - truth| / |truth|: median {np.median(rel):.1%}, "
        f"{np.mean(rel < 0.1):.0%} of the 57 within 10 %"
    )


if __name__ == "__main__":
    main()
