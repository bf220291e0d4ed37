"""Calibration of the parameter intervals: do the 90 % intervals cover known parameters?

Usage::

    python benchmarks/interval_coverage.py [--cases 12] [--families known,planted] [--objective J2]
                                  [--train R] [--level 0.9] [--json OUT]

Each case draws "true" parameters, simulates the training runs' 100-s windows with them (from
each window's recorded first state, with its recorded rudder, propeller and true wind), adds
coloured measurement noise with the levels and correlation times of the real recordings
(:data:`REAL_NOISE`, an AR(1) process per state channel, the first state included), identifies
the model on the noisy windows and computes its intervals
(:func:`sweep.identification.uncertainty.uncertainty_at`). Two families of truths:

- ``known``: as ``benchmarks/known_truth.py``, each EFD parameter times U(0.7, 1.3);
- ``planted``: as the diagnosis's planted cases (``benchmarks/planted.py``), each EFD parameter
  times exp(N(0, 0.15)), with, in turn, no effect, a propeller walk, a current and a rudder
  offset (catalog forms, identified with the 57 parameters: their intervals count too).

Identification: Levenberg-Marquardt (:func:`sweep.identification.polish.polish`) from the truth
to convergence. It finds the local optimum of the noisy data next to the truth, which is what the
intervals describe; a full CMA-ES search per case would take minutes and stop short of the
optimum by more than the intervals' width.

Printed per case: the number of parameters per status, the coverage of the determined ones and
the seconds of the fit and of the intervals; then the coverage pooled over cases (with its
binomial 95 % range), also for the weakly determined parameters, and the mean time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.known_truth import draw_truth
from benchmarks.planted import PlantedSpec, perturbed_ship, true_model
from mmg import Effect, Parameters, simulate_batch
from sweep.data.datasets import load_split
from sweep.data.objective import Objective
from sweep.data.recordings import Recording
from sweep.diagnose.floor import NoiseModel
from sweep.diagnose.windows import cut_windows
from sweep.identification.polish import PolishSettings, polish
from sweep.identification.uncertainty import (
    AT_BOUND,
    DETERMINED,
    WEAK,
    UncertaintySettings,
    model_names,
    uncertainty_at,
)
from sweep.identification.vector import full_vector, joint_box

#: AR(1) measurement noise of the real recordings per state channel (sigma in the channel's unit,
#: phi the lag-1 correlation at 10 Hz): the diagnosis's calibrated estimate on Train-R with the
#: shipped model (docs/diagnosis-real/report.json, ``noise_model``)
REAL_NOISE = NoiseModel(
    sigma={
        "x0": 0.00664,
        "u": 0.00210,
        "y0": 0.00531,
        "v_m": 0.00162,
        "psi": 0.00222,
        "r": 0.000322,
    },
    phi={"x0": 0.8138, "u": 0.9512, "y0": 0.8138, "v_m": 0.9512, "psi": 0.7527, "r": 0.9512},
)

#: the planted family's effects, case after case
PLANTED = (
    PlantedSpec("none"),
    PlantedSpec("propeller_walk", {"C_Yw": 2e-4, "C_Nw": -1e-4}),
    PlantedSpec("current", {"V_c": 0.015, "beta_c": 2.0}),
    PlantedSpec("rudder_offset", {"delta_0": 0.035}),
)


def truth_of(family: str, seed: int) -> tuple[Parameters, tuple[Effect, ...], str]:
    """The true parameters, the effects they carry and a label of case ``seed`` of ``family``."""
    if family == "known":
        return draw_truth(seed, 0.3), (), "EFD x U(0.7, 1.3)"
    spec = PLANTED[seed % len(PLANTED)]
    ship = perturbed_ship(np.random.default_rng(seed), 0.15)
    params, effects = true_model(ship, spec)
    return params, tuple(effects), f"EFD x exp(N(0, 0.15)) + {spec.form}"


def synthetic_windows(
    windows: list[Recording],
    truth: Parameters,
    effects: tuple[Effect, ...],
    noise: NoiseModel,
    rng: np.random.Generator,
) -> list[Recording]:
    """The windows' states simulated with ``truth`` (from each recorded first state, with its
    recorded controls and wind) plus ``noise`` (the first sample too); controls as recorded."""
    x0 = np.stack([w.x[0] for w in windows])
    K = max(w.n_samples for w in windows) - 1
    u = np.zeros((len(windows), K, 2))
    wind = np.zeros((len(windows), K, 2))
    for i, w in enumerate(windows):
        n = w.n_samples - 1
        u[i, :n], wind[i, :n] = w.u[:-1], w.w[:-1]
        u[i, n:], wind[i, n:] = w.u[-2], w.w[-2]
    t0 = np.array([float(w.t[0]) for w in windows])
    sim = simulate_batch(x0, u, wind, truth, effects=effects, t0=t0).states
    errors = noise.draw_many(rng, [w.n_samples for w in windows])
    return [
        Recording(w.name, None, w.t, sim[i, : w.n_samples] + errors[i], w.u, w.w)
        for i, w in enumerate(windows)
    ]


def run_case(
    family: str, seed: int, windows: list[Recording], objective: str, level: float
) -> dict[str, Any]:
    """Identify one case and judge its intervals against the truth."""
    truth, effects, label = truth_of(family, seed)
    recs = synthetic_windows(
        windows, truth, effects, REAL_NOISE, np.random.default_rng(10_000 + seed)
    )
    obj = Objective(recs, objective, effects=effects, ship=truth.ship)
    box = joint_box(effects)
    theta_true = full_vector(truth, effects)
    t0 = time.perf_counter()
    fit = polish(obj, box, theta_true, PolishSettings(max_iterations=100, rtol=1e-9))
    fit_seconds = time.perf_counter() - t0
    u = uncertainty_at(obj, box, fit.theta, model_names(effects), UncertaintySettings(level=level))
    inside = u.covers(theta_true)
    status = np.array(u.status)
    return {
        "family": family,
        "seed": seed,
        "truth": label,
        "parameters": len(u.names),
        "f": fit.f,
        "fit_seconds": fit_seconds,
        "seconds": u.seconds,
        "counts": u.counts,
        "covered": {s: int(inside[status == s].sum()) for s in (DETERMINED, WEAK, AT_BOUND)},
        "trade_offs": [d.sentence() for d in u.flat],
    }


def binomial_range(k: int, n: int) -> tuple[float, float]:
    """Wilson 95 % range of a proportion k / n."""
    if n == 0:
        return (math.nan, math.nan)
    z = 1.96
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def summary(results: list[dict[str, Any]], level: float) -> list[str]:
    """The pooled lines: coverage per status, parameters per status, mean seconds."""
    lines = []
    for s in (DETERMINED, WEAK):
        n = sum(r["counts"][s] for r in results)
        k = sum(r["covered"][s] for r in results)
        lo, hi = binomial_range(k, n)
        lines.append(
            f"{s}: {k} of {n} {round(100 * level)} % intervals cover the truth, "
            f"{k / max(n, 1):.3f} (95 % range {lo:.3f}-{hi:.3f})"
        )
    total = sum(r["parameters"] for r in results)
    counts = {s: sum(r["counts"][s] for r in results) for s in (DETERMINED, WEAK, AT_BOUND)}
    lines.append(
        f"parameters: {total} in {len(results)} cases: "
        + ", ".join(f"{v} {k}" for k, v in counts.items())
    )
    lines.append(
        f"seconds per case: intervals {np.mean([r['seconds'] for r in results]):.1f}, "
        f"fit {np.mean([r['fit_seconds'] for r in results]):.1f}"
    )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=12, help="cases per family")
    ap.add_argument("--families", default="known,planted")
    ap.add_argument("--objective", default="J2", choices=["J1", "J2", "J3"])
    ap.add_argument("--train", default="R", help="training set whose windows are simulated")
    ap.add_argument("--level", type=float, default=0.90)
    ap.add_argument("--json", dest="json_out", default=None)
    args = ap.parse_args(argv)
    default_root = Path(__file__).resolve().parents[2] / "shared/data/frt-ds-esso"
    root = os.environ.get("MMG_DATA_DIR", str(default_root))
    windows = cut_windows(list(load_split(args.train).load(root).values()))
    print(
        f"{len(windows)} windows of Train-{args.train}, objective {args.objective}, "
        f"{round(100 * args.level)} % intervals",
        flush=True,
    )
    results = []
    for family in args.families.split(","):
        for seed in range(args.cases):
            r = run_case(family, seed, windows, args.objective, args.level)
            results.append(r)
            c, k = r["counts"], r["covered"]
            print(
                f"{family} {seed:2d} ({r['truth']}): {c[DETERMINED]} determined, "
                f"{k[DETERMINED]} covered; {c[WEAK]} weak, {c[AT_BOUND]} at a bound; "
                f"fit {r['fit_seconds']:.0f} s, intervals {r['seconds']:.1f} s",
                flush=True,
            )
    for family in args.families.split(","):
        print(f"-- {family}")
        print("\n".join(summary([r for r in results if r["family"] == family], args.level)))
    print("-- all")
    print("\n".join(summary(results, args.level)))
    if args.json_out:
        Path(args.json_out).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
